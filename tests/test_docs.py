"""The manual builds: ``mkdocs build --strict`` fails on a broken page link, a missing page in the nav, or
an API page whose module moved."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_the_manual_builds_strictly_with_its_api_pages(tmp_path: Path) -> None:
    site = tmp_path / "site"
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-f", str(REPO / "mkdocs.yml"), "-d", str(site)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    api = (site / "api" / "index.html").read_text()
    assert "friction_slope" in api and "GaitConfig" in api  # rendered from the docstrings
    assert "soft_velocity" in (site / "soft" / "index.html").read_text()


def test_the_readme_is_a_quickstart_and_every_manual_page_is_in_the_nav() -> None:
    import yaml

    readme = (REPO / "README.md").read_text().splitlines()
    first = readme.index("```bash")  # the README opens with the two commands: the main job, then the tests
    assert len(readme) <= 60 and first < 12
    assert readme[first + 1].startswith("make run") and readme[first + 2].startswith("make test")
    nav = yaml.safe_load((REPO / "mkdocs.yml").read_text())["nav"]

    def pages(entries: list) -> set[str]:  # a section's entries are a list of their own
        out: set[str] = set()
        for entry in entries:
            value = next(iter(entry.values()))
            out |= pages(value) if isinstance(value, list) else {value}
        return out

    docs = REPO / "docs"
    files = docs / "results" / "files"  # a link to results/, whose figures the results pages embed
    written = {p.relative_to(docs).as_posix() for p in docs.rglob("*.md") if files not in p.parents}
    assert pages(nav) == written
