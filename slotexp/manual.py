"""The results manual's tables, rendered from the files ``make results`` writes (``slot manual``).

A page of ``docs/results/`` holds its tables as blocks: an HTML comment with the table's
spec (YAML), the rendered table, and an end marker::

    <!-- table
    name: Table I on the soft plant, walking
    file: perturb_cosserat/metrics.json
    key: table1
    columns:
      - [scenario, Scenario]
      - [max_cost, Max cost, .4g]
    -->
    | Scenario | Max cost |
    ...
    <!-- end table -->

Why: the pages quote numbers that ``make results`` regenerates, and a number typed into
prose by hand drifts from its file without anyone noticing. Here every table is made by
this module from the file it names, with a line under it naming that file and the command
that made it, and ``slot manual --check`` (``make results-check``, part of ``make test``)
fails, naming the page and the table, wherever a committed page differs from its files.

Kinds of block (the spec's keys):

- ``file`` + ``key`` (optional) + ``columns``: one row per record of a JSON/YAML list (or
  mapping, each entry a row named ``name``) or per row of a CSV; ``where`` keeps the rows
  whose fields equal the given values, ``exclude`` drops them. ``command`` names the command
  that made the file where ``make results`` did not (a measurement on another machine).
- ``runs`` (``[label, result dir]`` pairs) + ``file`` + ``columns``: one row per result
  directory, each column a field of that directory's ``file``.
- ``claims``: the summary of the paper's claims: per row the claim, the paper's number,
  ours (a field of a file, or with ``key`` that field of each record, counted or its
  ``aggregate``: ``max``, ``min``, ``maxabs``), and a verdict that follows from the number (``within``: the
  range, in the shown units, inside which ours reproduces the paper's; otherwise ``why``);
  ``words`` renames the column and the verdicts (``{column: Target, agrees: met, differs: missed}``).

A column is ``[field, header]``, ``[field, header, format]`` or ``[field, header, format,
scale]``: ``field`` a dotted path (``gaits.forward.distance``; ``table1.*.settle_s``: that
field of every entry of a list or mapping), ``format`` a Python format spec (``.1f``, ``+.1%``) or an aggregate of a
``*`` field (``count``: how many entries have a value; ``sum``, ``max``, ``min``, ``maxabs``; ``maxabs:.0f``
formats the aggregate),
``scale`` a factor applied first (1000: metres to millimetres).
"""

from __future__ import annotations

import csv
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from .atomic import write_text
from .errors import UserError

BLOCK = re.compile(r"<!-- table\n(?P<spec>.*?)\n-->\n(?P<body>.*?)<!-- end table -->", re.S)
TIMING = "timing.json"  # make results' record of each result's command (scripts/make_results.py)


@dataclass(frozen=True)
class Rendered:
    page: Path
    name: str
    committed: str
    rendered: str


def _load(path: Path) -> Any:
    """A result file's content: JSON, YAML or CSV (a list of rows, numbers as numbers)."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise UserError(f"{path}: cannot read ({exc.strerror or exc}): run `make results` to make it") from exc
    if path.suffix == ".csv":
        return [{k: _number(v) for k, v in row.items()} for row in csv.DictReader(text.splitlines())]
    try:
        return json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except (ValueError, yaml.YAMLError) as exc:
        raise UserError(f"{path}: not readable as {path.suffix[1:].upper()} ({exc.__class__.__name__})") from exc


def _number(text: str) -> Any:
    """A CSV cell as the number or truth value it spells (pandas writes booleans as True/False), else as text."""
    if text in ("True", "False"):
        return text == "True"
    try:
        return int(text)
    except ValueError:
        try:
            return float(text)
        except ValueError:
            return text


def _field(data: Any, path: str, where: str) -> Any:
    """``data``'s value at the dotted ``path``; a missing one names ``where`` it was looked for."""
    if isinstance(data, dict) and path in data:  # a key with dots of its own (a sweep's "gait.velocity")
        return data[path]
    value = data
    parts = str(path).split(".")
    for i, part in enumerate(parts):
        if part == "*" and isinstance(value, (list, dict)):  # every entry's rest of the path: a list
            rest = ".".join(parts[i + 1 :])
            entries = value.values() if isinstance(value, dict) else value
            return [_field(v, rest, where) if rest else v for v in entries]
        if isinstance(value, dict) and part in value:
            value = value[part]
        elif isinstance(value, list) and part.lstrip("-").isdigit() and -len(value) <= int(part) < len(value):
            value = value[int(part)]
        else:
            raise UserError(f"{where}: has no field {path!r}: fix the page's table spec or regenerate the file")
    return value


AGGREGATES = {
    "count": len,
    "sum": sum,
    "max": lambda v: max(v, default=float("nan")),
    "min": lambda v: min(v, default=float("nan")),
    "maxabs": lambda v: max((abs(x) for x in v), default=float("nan")),  # the worst of signed errors
}


def _aggregate(values: list, how: str) -> Any:
    """``how`` (a key of :data:`AGGREGATES`) of the entries of a ``*`` field that have a value (not None or NaN)."""
    return AGGREGATES[how]([v for v in values if v is not None and v == v])


def _cell(value: Any, fmt: str = "", scale: float = 1.0) -> str:
    how, _, then = fmt.partition(":")
    if how in AGGREGATES:  # a list field (a path with *), aggregated: how many entries have a value, their sum, ...
        return _cell(_aggregate(value, how), then) if isinstance(value, list) else "—"
    if value is None or (isinstance(value, float) and value != value):
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, list):  # a list of names (a fit's variables): one cell
        return ", ".join(_cell(v) for v in value)
    if isinstance(value, (int, float)):
        value = value * scale if scale != 1.0 else value
        try:
            return format(value, fmt) if fmt else (f"{value:.4g}" if isinstance(value, float) else str(value))
        except ValueError:
            raise UserError(f"a column's format {fmt!r} does not fit {value!r}: fix the page's table spec") from None
    return str(value)


def _columns(spec: dict, where: str) -> list[tuple[str, str, str, float]]:
    out = []
    for col in spec.get("columns") or []:
        if not isinstance(col, list) or not 2 <= len(col) <= 4:
            raise UserError(f"{where}: a column is [field, header, format, scale] (the last two optional), not {col!r}")
        field, header, fmt, scale = [*col, None, None][:4]
        scale = 1.0 if scale is None else scale
        out.append((str(field), str(header), str(fmt or ""), float(scale)))
    if not out:
        raise UserError(f"{where}: the table has no columns: list them as [field, header, format]")
    return out


def _markdown(headers: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join("---" for _ in headers) + "|"]
    lines += ["| " + " | ".join(cell.replace("|", "\\|") for cell in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def _timing(results: Path) -> dict:
    """make results' record of each result's command (empty where there is none)."""
    return _load(results / TIMING) if (results / TIMING).is_file() else {}


def _made_by(timing: dict, dirs: list[str]) -> str:
    """The command(s) that made these result directories, from make results' ``timing`` record."""
    names = list(dict.fromkeys(dirs))
    if len(names) == 1 and names[0] in timing:
        entry = timing[names[0]]
        command = " ".join([entry.get("command", "slot run"), *(str(a) for a in entry["args"])])
        return f"`{command}` (`python scripts/make_results.py {names[0]}`)"
    return f"`python scripts/make_results.py {' '.join(names)}`"


def _records(data: Any, spec: dict, where: str) -> list[dict]:
    if "key" in spec:
        data = _field(data, spec["key"], where)
    if isinstance(data, dict):
        data = [{"name": k, **v} if isinstance(v, dict) else {"name": k, "value": v} for k, v in data.items()]
    if not isinstance(data, list):
        raise UserError(f"{where}: expected a list of records, found a {type(data).__name__}: give the spec a key")
    for k, v in (spec.get("where") or {}).items():
        data = [r for r in data if isinstance(r, dict) and r.get(k) == v]
    for k, v in (spec.get("exclude") or {}).items():
        data = [r for r in data if not (isinstance(r, dict) and r.get(k) == v)]
    return data


def render_table(spec: dict, results: Path, where: str, timing: dict) -> str:
    """One block's table and its source line, from the result files under ``results`` (``timing``: their
    commands, :func:`_timing`)."""
    if "claims" in spec:
        return _claims(spec, results, where)
    if "file" not in spec:
        raise UserError(f"{where}: the table spec names no file: give file: <result dir>/<file>")
    columns = _columns(spec, where)
    headers = [c[1] for c in columns]
    if "runs" in spec:
        runs = spec["runs"]
        if not isinstance(runs, list) or any(not isinstance(r, list) or len(r) != 2 for r in runs):
            raise UserError(f"{where}: runs is a list of [label, result dir] pairs (quote a label with a comma)")
        dirs = [str(run[1]) for run in runs]
        rows = []
        for label, d in runs:
            path = results / d / spec["file"]
            data = _load(path)
            rows.append([str(label)] + [_cell(_field(data, f, str(path)), fmt, s) for f, _, fmt, s in columns])
        headers = [str(spec.get("label", "Run")), *headers]
        where_from = f"{{{','.join(dirs)}}}" if len(dirs) > 1 else dirs[0]
        files = f"`results/{where_from}/{spec['file']}`"
    else:
        path = results / spec["file"]
        records = _records(_load(path), spec, f"{where} ({path})")
        rows = [[_cell(_field(r, f, str(path)), fmt, s) for f, _, fmt, s in columns] for r in records]
        dirs = [Path(spec["file"]).parts[0]]
        files = f"`results/{spec['file']}`"
    made_by = f"`{spec['command']}`" if "command" in spec else _made_by(timing, dirs)
    return _markdown(headers, rows) + f"\n*From {files}; made by {made_by}.*\n"


def _claims(spec: dict, results: Path, where: str) -> str:
    rows, dirs = [], []
    # the column the claims' numbers stand in and the verdict's words: the paper's claims by default, or targets
    words = {"column": "Paper", "agrees": "reproduced", "differs": "differs", **(spec.get("words") or {})}
    if not isinstance(spec["claims"], list) or not all(isinstance(c, dict) for c in spec["claims"]):
        raise UserError(f"{where}: claims is a list of mappings (claim, paper, file, field, within, why, page)")
    for c in spec["claims"]:
        missing = [k for k in ("claim", "paper", "file", "field", "within", "why", "page") if k not in c]
        if missing:
            raise UserError(f"{where}: a claim has no {', '.join(missing)}: give each claim all of them")
        path = results / c["file"]
        data = _load(path)
        if "key" in c:  # a field of each record (key, where, exclude as a table's): aggregated below
            value = [_field(r, c["field"], str(path)) for r in _records(data, c, f"{where} ({path})")]
        else:
            value = _field(data, c["field"], str(path))
        fmt = c.get("format", "")
        if isinstance(value, list):  # a * field: how many entries have a value, or the largest, ...
            how = c.get("aggregate", "count")
            if how not in AGGREGATES:
                raise UserError(f"{where}: claim {c['claim']!r}: aggregate is one of {', '.join(AGGREGATES)}")
            value = _aggregate(value, how)
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise UserError(f"{where}: claim {c['claim']!r}: {path} field {c['field']!r} is not a number")
        shown = value * float(c.get("scale", 1.0))
        bounds = c["within"]
        if not (isinstance(bounds, list) and len(bounds) == 2 and all(isinstance(b, (int, float)) for b in bounds)):
            raise UserError(f"{where}: claim {c['claim']!r}: within is [lo, hi], two numbers, not {bounds!r}")
        lo, hi = bounds
        verdict = words["agrees"] if lo <= shown <= hi else f"{words['differs']}: {c['why']}"
        ours = _cell(value, fmt, float(c.get("scale", 1.0))) + (f" {c['unit']}" if c.get("unit") else "")
        rows.append([c["claim"], str(c["paper"]), ours, verdict, f"[{c['page']}]({c['page']})"])
        dirs.append(Path(c["file"]).parts[0])
    table = _markdown(["Claim", words["column"], "Ours", "Verdict", "Page"], rows)
    return table + f"\n*Ours from `results/` ({', '.join(sorted(set(dirs)))}); made by `make results`.*\n"


def render_page(page: Path, results: Path) -> list[Rendered]:
    """Every table block of ``page``, as committed and as its files render it now."""
    text = page.read_text()
    timing = _timing(results)
    out = []
    for m in BLOCK.finditer(text):
        try:
            spec = yaml.safe_load(m["spec"])
        except yaml.YAMLError as exc:
            raise UserError(f"{page}: a table spec is not YAML ({exc.__class__.__name__}): fix the comment") from exc
        if not isinstance(spec, dict) or "name" not in spec:
            raise UserError(f"{page}: a table spec has no name: give each block a name: line")
        where = f"{page}: table {spec['name']!r}"
        if "<!-- table\n" in m["body"]:  # its end marker is missing: the body ran on over the prose to the next one
            raise UserError(f"{where} has no '<!-- end table -->' before the next table: add it after the spec")
        out.append(Rendered(page, str(spec["name"]), m["body"], render_table(spec, results, where, timing)))
    if text.count("<!-- table\n") != len(out):
        raise UserError(f"{page}: its last table has no '<!-- end table -->': add it after the spec")
    return out


def pages(pages_dir: Path, results: Path) -> list[Path]:
    """The manual's pages, once both directories are there."""
    if not pages_dir.is_dir():
        raise UserError(f"{pages_dir}: no such directory: give the results manual's pages (docs/results)")
    if not results.is_dir():
        raise UserError(f"{results}: no such directory: give the result files' directory (results)")
    return sorted(pages_dir.glob("*.md"))


def check(pages_dir: Path, results: Path) -> list[Rendered]:
    """The tables whose committed text differs from what their files render now (empty: all agree)."""
    return [r for page in pages(pages_dir, results) for r in render_page(page, results) if r.committed != r.rendered]


def write(pages_dir: Path, results: Path) -> list[Path]:
    """Render every page's tables in place; return the pages that changed."""
    changed = []
    for page in pages(pages_dir, results):
        text = page.read_text()
        rendered = iter(render_page(page, results))

        def block(m: re.Match, r=rendered) -> str:
            return f"<!-- table\n{m['spec']}\n-->\n{next(r).rendered}<!-- end table -->"

        new = BLOCK.sub(block, text)
        if new != text:
            write_text(page, new)
            changed.append(page)
    return changed
