"""The results manual's tables are rendered from the result files, and the check catches a page that drifted."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from slotexp import manual
from slotexp.errors import UserError

REPO = Path(__file__).resolve().parents[1]
PAGES = REPO / "docs" / "results"
RESULTS = REPO / "results"


def test_every_committed_table_agrees_with_the_committed_result_files() -> None:
    stale = manual.check(PAGES, RESULTS)
    assert not stale, [f"{r.page.name}: {r.name}" for r in stale]
    assert sum(len(manual.render_page(p, RESULTS)) for p in manual.pages(PAGES, RESULTS)) >= 20


def _specs(page: Path) -> list[dict]:
    return [yaml.safe_load(m["spec"]) for m in manual.BLOCK.finditer(page.read_text())]


@pytest.fixture
def table1(tmp_path: Path) -> tuple[Path, Path]:
    """The Table I page and the result files it reads, copied."""
    pages, results = tmp_path / "pages", tmp_path / "results"
    pages.mkdir()
    shutil.copy(PAGES / "table1.md", pages)
    results.mkdir()
    shutil.copy(RESULTS / manual.TIMING, results)
    for d in {m["file"].split("/")[0] for m in _specs(PAGES / "table1.md")}:
        (results / d).mkdir()
        shutil.copy(RESULTS / d / "metrics.json", results / d)
    return pages, results


def test_one_changed_number_fails_the_check_naming_page_and_table_and_restoring_it_passes(table1) -> None:
    pages, results = table1
    assert manual.check(pages, results) == []
    path = results / "perturb_cosserat" / "metrics.json"
    original = path.read_text()
    data = json.loads(original)
    data["table1"][0]["max_cost"] *= 1.5
    path.write_text(json.dumps(data))
    proc = subprocess.run(
        [sys.executable, "-m", "slotexp.cli", "manual", "--check", "--pages", str(pages), "--results", str(results)],
        capture_output=True,
        text=True,
    )
    assert proc.returncode != 0
    assert "table1.md: table 'Table I, soft plant, walking' differs" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert [r.name for r in manual.check(pages, results)] == ["Table I, soft plant, walking"]
    path.write_text(original)
    assert manual.check(pages, results) == []


def test_rendering_fills_a_block_from_its_file_and_a_second_render_changes_nothing(table1) -> None:
    pages, results = table1
    page = pages / "table1.md"
    page.write_text(manual.BLOCK.sub(lambda m: f"<!-- table\n{m['spec']}\n-->\n<!-- end table -->", page.read_text()))
    assert len(manual.check(pages, results)) == len(_specs(page))  # every block is empty now
    assert manual.write(pages, results) == [page]
    assert page.read_text() == (PAGES / "table1.md").read_text()
    assert manual.write(pages, results) == []
    baseline = json.loads((results / "perturb" / "metrics.json").read_text())["table1"][0]
    assert f"| baseline | {baseline['max_cost']:.4g} |" in page.read_text()
    assert "*From `results/perturb/metrics.json`; made by `slot run experiment=perturb" in page.read_text()


def test_the_source_line_names_the_command_each_result_was_made_by(tmp_path: Path) -> None:
    """A benchmark's line says `slot bench`, a sweep's `slot run -m`; a file made elsewhere names its command."""
    results = tmp_path / "results"
    for d in ("bench", "sweep", "node"):
        (results / d).mkdir(parents=True)
        (results / d / "rows.json").write_text(json.dumps([{"b": 1}]))
    (results / manual.TIMING).write_text(
        json.dumps(
            {
                "bench": {"args": ["leg"], "command": "slot bench"},
                "sweep": {"args": ["gait=walk"], "command": "slot run -m"},
            }
        )
    )
    specs = {d: {"name": d, "file": f"{d}/rows.json", "columns": [["b", "B"]]} for d in ("bench", "sweep", "node")}
    specs["node"]["command"] = "python scripts/batch_throughput.py run cfg.pkl"
    timing = manual._timing(results)
    lines = {d: manual.render_table(spec, results, d, timing).splitlines()[-1] for d, spec in specs.items()}
    assert "made by `slot bench leg` (`python scripts/make_results.py bench`)" in lines["bench"]
    assert "made by `slot run -m gait=walk`" in lines["sweep"]
    assert lines["node"].endswith("made by `python scripts/batch_throughput.py run cfg.pkl`.*")


def test_a_star_field_aggregates_the_entries_of_a_mapping_and_can_be_formatted(tmp_path: Path) -> None:
    """``*.heading_error_deg`` over a replay's gaits (a mapping): the worst signed error, formatted."""
    results = tmp_path / "results"
    (results / "replay").mkdir(parents=True)
    gaits = {"forward": {"heading_error_deg": -0.4}, "backward": {"heading_error_deg": -21.56}, "turn": {}}
    gaits["turn"]["heading_error_deg"] = None
    (results / "replay" / "metrics.json").write_text(json.dumps(gaits))
    spec = {"name": "t", "runs": [["default", "replay"]], "file": "metrics.json"}
    spec["columns"] = [["*.heading_error_deg", "Worst", "maxabs:.0f"], ["*.heading_error_deg", "Raw", "maxabs"]]
    table = manual.render_table(spec, results, "t", {})
    assert "| default | 22 | 21.56 |" in table


def _page(tmp_path: Path, spec: str) -> Path:
    pages = tmp_path / "pages"
    pages.mkdir(exist_ok=True)
    (pages / "p.md").write_text(f"# p\n\n<!-- table\n{spec}\n-->\n<!-- end table -->\n")
    return pages


def test_a_claims_verdict_follows_its_number(tmp_path: Path) -> None:
    results = tmp_path / "results"
    (results / "run").mkdir(parents=True)
    (results / "run" / "metrics.json").write_text(json.dumps({"path_rmse_m": 0.0066}))
    spec = (
        "name: claims\nclaims:\n  - {claim: path, paper: '35', file: run/metrics.json, field: path_rmse_m,"
        " scale: 1000, format: .1f, unit: mm, within: [0, 35], why: it slides, page: walking.md}"
    )
    pages = _page(tmp_path, spec)
    manual.write(pages, results)
    assert "| path | 35 | 6.6 mm | reproduced |" in (pages / "p.md").read_text()
    (results / "run" / "metrics.json").write_text(json.dumps({"path_rmse_m": 0.077}))
    assert [r.name for r in manual.check(pages, results)] == ["claims"]
    manual.write(pages, results)
    assert "| path | 35 | 77.0 mm | differs: it slides |" in (pages / "p.md").read_text()
    # as targets: the column and the verdicts named so
    (pages / "p.md").write_text(
        (pages / "p.md")
        .read_text()
        .replace("claims:", "words: {column: Target, agrees: met, differs: missed}\nclaims:", 1)
    )
    manual.write(pages, results)
    assert "| Claim | Target | Ours |" in (pages / "p.md").read_text()
    assert "| path | 35 | 77.0 mm | missed: it slides |" in (pages / "p.md").read_text()


@pytest.mark.parametrize(
    ("spec", "says"),
    [
        ("name: t\nfile: nowhere/metrics.json\ncolumns: [[a, A]]", "cannot read"),
        ("name: t\nfile: run/metrics.json\ncolumns: [[nope, A]]", "has no field 'nope'"),
        ("name: t\nfile: run/metrics.json", "has no columns"),
        ("file: run/metrics.json\ncolumns: [[a, A]]", "has no name"),
        ("name: t\nruns: [[a, b, c]]\nfile: metrics.json\ncolumns: [[a, A]]", "[label, result dir] pairs"),
        ("name: t\nfile: run/metrics.json\ncolumns: [[a, A, .2q]]", "format '.2q' does not fit"),
        (
            "name: t\nclaims: [{claim: c, paper: p, file: run/metrics.json, field: 0.a, within: 3, why: w, page: p}]",
            "within is [lo, hi]",
        ),
        ("name: t\nclaims: 3", "claims is a list"),
    ],
)
def test_a_bad_table_spec_is_one_line_that_names_what_to_fix(tmp_path: Path, spec: str, says: str) -> None:
    results = tmp_path / "results"
    (results / "run").mkdir(parents=True)
    (results / "run" / "metrics.json").write_text(json.dumps([{"a": 1}]))
    with pytest.raises(UserError, match=None) as err:
        manual.check(_page(tmp_path, spec), results)
    assert says in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("last", [False, True])
def test_a_table_without_its_end_marker_is_refused_before_it_swallows_the_prose_after_it(
    tmp_path: Path, last: bool
) -> None:
    results = tmp_path / "results"
    (results / "run").mkdir(parents=True)
    (results / "run" / "metrics.json").write_text(json.dumps([{"a": 1}]))
    spec = "name: t\nfile: run/metrics.json\ncolumns: [[a, A]]"
    ended = f"<!-- table\n{spec}\n-->\n<!-- end table -->\n"
    open_ = f"<!-- table\n{spec}\n-->\n"
    body = f"# p\n\n{ended}Prose.\n\n{open_}" if last else f"# p\n\n{open_}Prose to keep.\n\n{ended}"
    pages = tmp_path / "pages"
    pages.mkdir()
    (pages / "p.md").write_text(body)
    with pytest.raises(UserError, match="end table") as err:
        manual.write(pages, results)
    assert "\n" not in str(err.value)
    assert (pages / "p.md").read_text() == body  # nothing rewritten
