"""Trajectory comparison for the ``validate`` experiment: RMSE, MAE and NRMSE per marker and axis.

The paper's authors validated their simulator against ArUco marker tracks. This module
does the same comparison between a *reference* (a hardware marker-track CSV, or another
run's log) and a *candidate* (usually a simulation), for every marker both share (the
torso CoM ``com`` and, on the soft-leg plant, leg nodes such as ``FL_n0`` ... ``FL_n30``)
and every axis x/y/z. It is numerics only (numpy, pandas, stdlib) so it can be tested and
reused without plotting or the rest of the package.

Marker-track CSV format
-----------------------
A plain-text UTF-8 file, comma-separated, with exactly one header row. Lines whose first
non-blank character is ``#`` are comments and blank lines are ignored, both before and
after the header. The first column must be named ``t``: time in seconds, with any origin,
never empty, and strictly increasing from one data row to the next. Every further column
is named ``<marker>_x``, ``<marker>_y`` or ``<marker>_z``, where ``<marker>`` matches
``[A-Za-z0-9_]+`` (for example ``com`` or ``FL_n30``); every marker must have all three
of its columns (in any order). Values are positions in metres in the world frame (z up).
An empty cell means the marker was not tracked in that frame and is read as NaN (the text
``nan`` is accepted too); any other non-numeric value, or an infinite one, is an error.
At least two data rows are required. Errors name the file and, where relevant, the
1-based line number in the file (comment lines counted) and the column. Example::

    # session 2024-05-02, ArUco, 30 fps
    t,com_x,com_y,com_z,FL_n30_x,FL_n30_y,FL_n30_z
    12.000,0.0010,0.0000,0.1500,0.1200,0.0800,0.0100
    12.033,0.0031,0.0001,0.1502,,,
    12.067,0.0052,0.0001,0.1499,0.1231,0.0801,0.0090

Time alignment and resampling
-----------------------------
Hardware and simulation clocks have different origins, so :class:`Alignment` says how the
two time axes are put on one base before anything is compared:

* ``mode="start"`` (default): both trajectories are shifted so their first sample is at
  t = 0; ``mode="absolute"``: times are used as they are.
* ``offset_s`` is then *added to the candidate's time* (after the mode shift), to correct a
  known latency: a candidate whose timestamps are 0.1 s late is corrected with
  ``offset_s=-0.1``.

The evaluation times are the reference's own samples (after the shift) that fall inside
the closed overlap ``[max(start_ref, start_cand), min(end_ref, end_cand)]``, widened by
1e-9 s on each side so a sample that lies on an overlap end up to floating-point rounding
of the shifted times is kept (the candidate is then held at its end value for that
sliver); the reference is therefore never resampled. The candidate is linearly interpolated onto those times per
axis with :func:`numpy.interp`. Candidate NaNs (lost tracking) propagate: an evaluation
sample is NaN when any candidate sample with a non-zero interpolation weight is NaN, i.e.
when one of the two bracketing candidate samples is NaN; a time that coincides exactly
with a valid candidate sample takes that sample's value (so identical time grids never
lose a valid sample to a NaN neighbour). Fewer than 2 reference samples in the overlap is
an error.

Metrics
-------
For each (marker, axis), samples where the reference or the interpolated candidate is
NaN are dropped; ``n_samples`` counts the samples used. With error e = candidate -
reference: RMSE = sqrt(mean(e^2)), MAE = mean(|e|), NRMSE = RMSE / (max - min of the
reference on that axis over the used samples). NRMSE is NaN when that range is below
1e-9 m, because normalising by a zero range is undefined (a marker that does not move
on that axis). A (marker, axis) with no usable sample reports NaN metrics and
``n_samples = 0`` rather than failing, since losing one marker is a result to report.
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from .errors import TrajectoryError

__all__ = [
    "TrajectoryError",
    "Trajectory",
    "Alignment",
    "AXES",
    "MARKER_NAME_RE",
    "NRMSE_MIN_RANGE_M",
    "OVERLAP_TOL_S",
    "load_marker_csv",
    "trajectory_from_frame",
    "align",
    "compare",
]

AXES: tuple[str, str, str] = ("x", "y", "z")
"""Axis names, in column order of every (n, 3) marker array."""

MARKER_NAME_RE = re.compile(r"[A-Za-z0-9_]+")
"""Allowed marker names in a marker-track CSV."""

NRMSE_MIN_RANGE_M = 1e-9
"""Below this reference range (m) NRMSE is undefined and reported as NaN."""

OVERLAP_TOL_S = 1e-9
"""Rounding tolerance (s) on the overlap ends when picking evaluation times."""

_CSV_COLUMN_RE = re.compile(r"^([A-Za-z0-9_]+)_([xyz])$")
_METRIC_COLUMNS = ["marker", "axis", "rmse_m", "mae_m", "nrmse", "n_samples"]


def _fmt_range(t0: float, t1: float) -> str:
    return f"[{t0:.6g}, {t1:.6g}] s"


# --------------------------------------------------------------------------- Trajectory


@dataclass(frozen=True)
class Trajectory:
    """Marker positions over time, the common currency of every comparison.

    ``t`` is (n,) seconds, finite and strictly increasing with n >= 2 (interpolation needs
    a bracket). ``markers`` maps a name to an (n, 3) array of x, y, z positions in metres;
    NaN marks lost tracking, infinities are rejected. Arrays are copied to float64 and made
    read-only so a Trajectory cannot change after it was validated.
    """

    t: np.ndarray
    markers: dict[str, np.ndarray]

    def __post_init__(self) -> None:
        try:
            t = np.array(self.t, dtype=float)
        except (TypeError, ValueError) as exc:
            raise TrajectoryError(f"trajectory time t is not numeric ({exc})") from None
        if t.ndim != 1:
            raise TrajectoryError(f"trajectory time t must be 1-D, got shape {t.shape}")
        n = t.shape[0]
        if n < 2:
            raise TrajectoryError(f"trajectory has {n} sample(s); at least 2 are needed to interpolate")
        bad = np.flatnonzero(~np.isfinite(t))
        if bad.size:
            raise TrajectoryError(f"trajectory time t is not finite at index {int(bad[0])} (value {float(t[bad[0]])})")
        steps = np.diff(t)
        bad = np.flatnonzero(steps <= 0)
        if bad.size:
            i = int(bad[0]) + 1
            raise TrajectoryError(
                f"trajectory time t is not strictly increasing at index {i} "
                f"(t[{i - 1}]={float(t[i - 1])!r}, t[{i}]={float(t[i])!r}); sort the samples and drop duplicates"
            )
        if not isinstance(self.markers, dict):
            raise TrajectoryError(
                f"trajectory markers must be a dict name -> (n, 3) array, got {type(self.markers).__name__}"
            )
        if not self.markers:
            raise TrajectoryError("trajectory has no markers; give at least one (n, 3) position array")
        markers: dict[str, np.ndarray] = {}
        for name, arr in self.markers.items():
            if not isinstance(name, str) or not name:
                raise TrajectoryError(f"marker name {name!r} must be a non-empty string")
            try:
                a = np.array(arr, dtype=float)
            except (TypeError, ValueError) as exc:
                raise TrajectoryError(f"marker {name!r} positions are not numeric ({exc})") from None
            if a.shape != (n, 3):
                raise TrajectoryError(
                    f"marker {name!r} has shape {a.shape}; expected ({n}, 3) to match the {n} time samples"
                )
            if np.isinf(a).any():
                r, c = np.argwhere(np.isinf(a))[0]
                raise TrajectoryError(
                    f"marker {name!r} has an infinite {AXES[c]} position at index {int(r)}; use NaN for lost tracking"
                )
            a.setflags(write=False)
            markers[name] = a
        t.setflags(write=False)
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "markers", markers)

    @property
    def n_samples(self) -> int:
        """Number of time samples."""
        return int(self.t.shape[0])

    @property
    def time_range(self) -> tuple[float, float]:
        """(first, last) sample time in seconds."""
        return float(self.t[0]), float(self.t[-1])


# --------------------------------------------------------------------------- loading


def load_marker_csv(path: str | Path) -> Trajectory:
    """Read a hardware marker-track CSV (format in the module docstring).

    Parsed by hand rather than with pandas so every problem is reported with the file,
    line and column the user has to fix.
    """
    p = Path(path)
    where = f"marker CSV {str(p)!r}"
    if not p.exists():
        raise TrajectoryError(f"{where} does not exist; check the reference path")
    if p.is_dir():
        raise TrajectoryError(f"{where} is a directory; give the path of a .csv file")
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise TrajectoryError(f"{where} is not UTF-8 text; export the marker tracks as a plain UTF-8 CSV") from None
    except OSError as exc:
        raise TrajectoryError(f"{where} cannot be read ({exc.strerror or exc}); check its permissions") from None

    # (1-based line number, fields) of every non-comment, non-blank line.
    rows: list[tuple[int, list[str]]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        try:
            fields = next(csv.reader([line]))
        except csv.Error as exc:
            raise TrajectoryError(f"{where}, line {lineno}: malformed CSV ({exc})") from None
        rows.append((lineno, [f.strip() for f in fields]))
    if not rows:
        raise TrajectoryError(
            f"{where} is empty (no header row); it needs a header 't,<marker>_x,<marker>_y,<marker>_z,...' "
            "and data rows"
        )

    header_line, header = rows[0]
    if "t" not in header:
        raise TrajectoryError(
            f"{where}, line {header_line}: no 't' column in header {','.join(header)!r}; "
            "the first column must be 't' (seconds)"
        )
    if header[0] != "t":
        raise TrajectoryError(
            f"{where}, line {header_line}: 't' is column {header.index('t') + 1}; move it to the first column"
        )
    seen: set[str] = set()
    columns: dict[str, dict[str, int]] = {}  # marker -> axis -> column index
    for j, name in enumerate(header[1:], start=1):
        if name in seen or name == "t":
            raise TrajectoryError(f"{where}, line {header_line}: column {name!r} appears twice; keep one")
        seen.add(name)
        m = _CSV_COLUMN_RE.match(name)
        if m is None:
            raise TrajectoryError(
                f"{where}, line {header_line}: column {j + 1} {name!r} is not '<marker>_x|_y|_z' "
                f"with <marker> in [A-Za-z0-9_]+; rename or remove it"
            )
        columns.setdefault(m.group(1), {})[m.group(2)] = j
    if not columns:
        raise TrajectoryError(
            f"{where}, line {header_line}: no marker columns; add '<marker>_x,<marker>_y,<marker>_z' columns"
        )
    for marker, axes in columns.items():
        missing = [f"{marker}_{a}" for a in AXES if a not in axes]
        if missing:
            raise TrajectoryError(
                f"{where}, line {header_line}: marker {marker!r} is missing column(s) {', '.join(missing)}; "
                f"every marker needs _x, _y and _z"
            )

    data = rows[1:]
    if len(data) < 2:
        raise TrajectoryError(f"{where} has {len(data)} data row(s); at least 2 are needed")
    ncol = len(header)
    t = np.empty(len(data))
    pos = {marker: np.empty((len(data), 3)) for marker in columns}
    prev_line = header_line
    for i, (lineno, fields) in enumerate(data):
        if len(fields) != ncol:
            raise TrajectoryError(
                f"{where}, line {lineno}: {len(fields)} fields but the header has {ncol}; fix the row"
            )
        tv = _parse_cell(fields[0], where, lineno, "t", allow_empty=False)
        if i and tv <= t[i - 1]:
            raise TrajectoryError(
                f"{where}, line {lineno}: t={tv!r} is not greater than t={float(t[i - 1])!r} on line {prev_line}; "
                f"rows must have strictly increasing time"
            )
        t[i] = tv
        for marker, axes in columns.items():
            for k, a in enumerate(AXES):
                pos[marker][i, k] = _parse_cell(fields[axes[a]], where, lineno, header[axes[a]], allow_empty=True)
        prev_line = lineno
    _check_plausible(where, t, pos)
    return Trajectory(t=t, markers=pos)


ROOM_M = 20.0  # m: no marker of a tabletop robot's run is farther than this from the origin
DAY_S = 86400.0  # s: no run lasts longer


def _check_plausible(where: str, t: np.ndarray, pos: dict[str, np.ndarray]) -> None:
    """A track is in metres and seconds and tracked at all: what a CSV in millimetres or milliseconds, or an
    export with every cell empty, would otherwise turn silently into wrong numbers (an RMSE of 40 m)."""
    for marker, xyz in pos.items():
        tracked = np.isfinite(xyz).all(axis=1)
        if not tracked.any():
            raise TrajectoryError(
                f"{where}: marker {marker!r} has no tracked sample (every row has an empty or nan cell): "
                "check the export, or drop its columns"
            )
        largest = float(np.nanmax(np.abs(xyz)))
        if largest > ROOM_M:
            raise TrajectoryError(
                f"{where}: marker {marker!r} reaches {largest:.4g} from the origin, beyond a room ({ROOM_M:g} m): "
                "positions are in metres (a CSV in millimetres needs dividing by 1000)"
            )
    if t[-1] - t[0] > DAY_S:
        raise TrajectoryError(
            f"{where}: t spans {t[-1] - t[0]:.4g}, more than a day: times are in seconds (a CSV in milliseconds "
            "needs dividing by 1000)"
        )


def _parse_cell(cell: str, where: str, lineno: int, column: str, *, allow_empty: bool) -> float:
    """One CSV value: empty -> NaN (markers only), otherwise a finite float."""
    if cell == "":
        if allow_empty:
            return math.nan
        raise TrajectoryError(f"{where}, line {lineno}, column {column!r}: empty value; every row needs a time")
    try:
        v = float(cell)
    except ValueError:
        raise TrajectoryError(
            f"{where}, line {lineno}, column {column!r}: {cell[:40]!r} is not a number; "
            f"use a decimal value{' or leave the cell empty for lost tracking' if allow_empty else ''}"
        ) from None
    if math.isinf(v) or (math.isnan(v) and not allow_empty):
        raise TrajectoryError(f"{where}, line {lineno}, column {column!r}: {cell!r} is not a finite number")
    return v


def trajectory_from_frame(df: pd.DataFrame) -> Trajectory:
    """Build a Trajectory from a logged DataFrame (column ``t`` plus ``<marker>.0/.1/.2``).

    That is how the project's MCAP reader flattens a message like
    ``{"com": [x, y, z], "FL_n30": [x, y, z]}``. Columns that are not part of a complete
    ``.0/.1/.2`` triple are ignored, so other logged fields may share the frame.
    """
    if not isinstance(df, pd.DataFrame):
        raise TrajectoryError(f"expected a pandas DataFrame of logged markers, got {type(df).__name__}")
    if "t" not in df.columns:
        raise TrajectoryError(
            f"logged frame has no 't' column (columns: {', '.join(map(str, df.columns[:12]))}); log the time as 't'"
        )
    found: dict[str, dict[int, str]] = {}
    for col in df.columns:
        if not isinstance(col, str) or "." not in col:
            continue
        name, _, idx = col.rpartition(".")
        if name and idx in ("0", "1", "2"):
            found.setdefault(name, {})[int(idx)] = col
    complete = {name: cols for name, cols in found.items() if len(cols) == 3}
    if not complete:
        raise TrajectoryError(
            "logged frame has no complete marker (need '<marker>.0', '<marker>.1', '<marker>.2' columns); "
            f"columns: {', '.join(map(str, df.columns[:12]))}"
        )

    def numeric(col: str) -> np.ndarray:
        try:
            return pd.to_numeric(df[col], errors="raise").to_numpy(dtype=float, na_value=np.nan)
        except (TypeError, ValueError):
            raise TrajectoryError(
                f"logged column {col!r} is not numeric; it cannot be a marker coordinate or time"
            ) from None

    t = numeric("t")
    markers = {name: np.column_stack([numeric(cols[k]) for k in range(3)]) for name, cols in complete.items()}
    return Trajectory(t=t, markers=markers)


# --------------------------------------------------------------------------- alignment


@dataclass(frozen=True)
class Alignment:
    """How the candidate's time axis is mapped onto the reference's.

    ``mode="start"`` shifts both trajectories to start at t = 0 (hardware and simulation
    clocks have different origins); ``"absolute"`` uses the times as they are.
    ``offset_s`` is added to the candidate's time after that shift, to correct a known
    latency.
    """

    mode: str = "start"
    offset_s: float = 0.0

    def __post_init__(self) -> None:
        if self.mode not in ("start", "absolute"):
            raise TrajectoryError(f"alignment mode {self.mode!r} is unknown; use 'start' or 'absolute'")
        try:
            off = float(self.offset_s)
        except (TypeError, ValueError):
            raise TrajectoryError(f"alignment offset_s {self.offset_s!r} is not a number of seconds") from None
        if not math.isfinite(off):
            raise TrajectoryError(f"alignment offset_s {self.offset_s!r} must be finite (seconds)")
        object.__setattr__(self, "offset_s", off)


def _shifted_times(reference: Trajectory, candidate: Trajectory, alignment: Alignment) -> tuple[np.ndarray, np.ndarray]:
    if alignment.mode == "start":
        t_ref = reference.t - reference.t[0]
        t_cand = candidate.t - candidate.t[0]
    else:
        t_ref = reference.t.copy()
        t_cand = candidate.t.copy()
    return t_ref, t_cand + alignment.offset_s


def _interp_nan(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """numpy.interp that returns NaN wherever a sample with non-zero weight is NaN.

    Plain numpy.interp would let NaN leak or not depending on which neighbour is NaN; the
    rule here is symmetric: interpolate the NaN indicator too and mask any positive weight.
    """
    nan = np.isnan(fp)
    if not nan.any():
        return np.interp(x, xp, fp)
    out = np.interp(x, xp, np.where(nan, 0.0, fp))
    out[np.interp(x, xp, nan.astype(float)) > 0.0] = np.nan
    return out


def align(
    reference: Trajectory, candidate: Trajectory, alignment: Alignment
) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Put both trajectories on one time base: the reference's samples inside the overlap.

    Returns ``(times, ref_markers, cand_markers)``: ``times`` are the shifted reference
    times (s) inside ``[max(starts), min(ends)]`` (+-1e-9 s for rounding); each dict
    holds, for every marker in both trajectories (in the reference's order), an (m, 3)
    array on ``times``. The candidate is linearly interpolated; see the module docstring
    for the NaN rule.
    """
    shared = [name for name in reference.markers if name in candidate.markers]
    if not shared:
        raise TrajectoryError(
            f"reference and candidate share no marker: reference has {sorted(reference.markers)}, "
            f"candidate has {sorted(candidate.markers)}; compare trajectories of the same markers"
        )
    t_ref, t_cand = _shifted_times(reference, candidate, alignment)
    lo = max(t_ref[0], t_cand[0])
    hi = min(t_ref[-1], t_cand[-1])
    keep = (t_ref >= lo - OVERLAP_TOL_S) & (t_ref <= hi + OVERLAP_TOL_S)
    if int(keep.sum()) < 2:
        raise TrajectoryError(
            f"no usable time overlap: reference spans {_fmt_range(t_ref[0], t_ref[-1])} and candidate spans "
            f"{_fmt_range(t_cand[0], t_cand[-1])} after alignment mode={alignment.mode!r}, "
            f"offset_s={alignment.offset_s:g} (need at least 2 reference samples in the overlap); "
            f"use mode 'start' or fix offset_s"
        )
    times = t_ref[keep]
    ref_out = {name: reference.markers[name][keep].copy() for name in shared}
    cand_out = {
        name: np.column_stack([_interp_nan(times, t_cand, candidate.markers[name][:, k]) for k in range(3)])
        for name in shared
    }
    return times, ref_out, cand_out


# --------------------------------------------------------------------------- metrics


def compare(
    reference: Trajectory,
    candidate: Trajectory,
    alignment: Alignment = Alignment(),
    markers: Sequence[str] | None = None,
) -> pd.DataFrame:
    """RMSE, MAE and NRMSE of candidate vs reference, one row per (marker, axis).

    Columns: ``marker, axis, rmse_m, mae_m, nrmse, n_samples``. ``markers`` restricts
    and orders the comparison; by default every shared marker in the reference's order.
    """
    if markers is not None:
        if isinstance(markers, str):
            markers = [markers]
        markers = list(markers)
        missing = [m for m in markers if m not in reference.markers or m not in candidate.markers]
        if missing:
            raise TrajectoryError(
                f"marker(s) {missing} not in both trajectories: reference has {sorted(reference.markers)}, "
                f"candidate has {sorted(candidate.markers)}; pick markers present in both"
            )
        if not markers:
            raise TrajectoryError("the marker list is empty; name at least one marker or leave it unset")
    times, ref, cand = align(reference, candidate, alignment)
    names = markers if markers is not None else list(ref)

    records: list[dict[str, object]] = []
    for name in names:
        for k, axis in enumerate(AXES):
            r = ref[name][:, k]
            c = cand[name][:, k]
            used = ~(np.isnan(r) | np.isnan(c))
            n = int(used.sum())
            if n == 0:
                rmse = mae = nrmse = math.nan
            else:
                err = c[used] - r[used]
                rmse = float(np.sqrt(np.mean(err * err)))
                mae = float(np.mean(np.abs(err)))
                span = float(np.max(r[used]) - np.min(r[used]))
                nrmse = rmse / span if span >= NRMSE_MIN_RANGE_M else math.nan
            records.append({"marker": name, "axis": axis, "rmse_m": rmse, "mae_m": mae, "nrmse": nrmse, "n_samples": n})
    out = pd.DataFrame.from_records(records, columns=_METRIC_COLUMNS)
    return out.astype({"rmse_m": float, "mae_m": float, "nrmse": float, "n_samples": int})
