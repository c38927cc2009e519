"""Trajectory comparison: analytic metric cases, alignment, resampling, CSV I/O, overlay figure."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from slotexp.compare import (
    Alignment,
    Trajectory,
    TrajectoryError,
    align,
    compare,
    load_marker_csv,
    trajectory_from_frame,
)


def _traj(t: np.ndarray, **markers: np.ndarray) -> Trajectory:
    return Trajectory(t=np.asarray(t, dtype=float), markers={k: np.asarray(v, dtype=float) for k, v in markers.items()})


def _row(df: pd.DataFrame, marker: str, axis: str) -> pd.Series:
    sel = df[(df.marker == marker) & (df.axis == axis)]
    assert len(sel) == 1
    return sel.iloc[0]


def _one_line_naming(exc: pytest.ExceptionInfo, path: Path) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    assert path.name in msg
    return msg


# --------------------------------------------------------------------------- metrics


def test_constant_offset_gives_exact_rmse_and_mae_on_that_axis_only() -> None:
    t = np.arange(16) * 0.125  # dyadic values: every operation below is exact in binary
    ref = np.column_stack([t * 0.5, -t, np.full_like(t, 0.25) + t])
    d = 0.5
    cand = ref + np.array([0.0, d, 0.0])
    df = compare(_traj(t, com=ref), _traj(t, com=cand))
    assert list(df.columns) == ["marker", "axis", "rmse_m", "mae_m", "nrmse", "n_samples"]
    assert list(df.axis) == ["x", "y", "z"]
    y = _row(df, "com", "y")
    assert y.rmse_m == d and y.mae_m == d
    assert y.n_samples == len(t)
    assert y.nrmse == pytest.approx(d / (t[-1] - t[0]))
    for axis in ("x", "z"):
        r = _row(df, "com", axis)
        assert r.rmse_m == 0.0 and r.mae_m == 0.0 and r.nrmse == 0.0


def test_sine_error_gives_amplitude_over_sqrt2() -> None:
    t = np.linspace(0.0, 20.0, 20001)  # 20 periods of a 1 Hz sine
    amp = 0.003
    ref = np.column_stack([0.1 * t, np.zeros_like(t), 0.15 + 0.01 * np.cos(t)])
    cand = ref.copy()
    cand[:, 0] += amp * np.sin(2 * np.pi * t)
    df = compare(_traj(t, com=ref), _traj(t, com=cand))
    x = _row(df, "com", "x")
    assert x.rmse_m == pytest.approx(amp / math.sqrt(2), rel=1e-3)
    assert x.mae_m == pytest.approx(2 * amp / math.pi, rel=1e-3)  # mean |sin| = 2/pi
    assert _row(df, "com", "z").rmse_m == 0.0


def test_linear_interpolation_is_exact_for_linear_candidate_on_coarser_grid() -> None:
    t_ref = np.linspace(0.0, 2.0, 201)
    t_cand = np.array([0.0, 0.13, 0.5, 0.77, 1.2, 1.21, 1.9, 2.0])  # coarse and irregular

    def f(t: np.ndarray) -> np.ndarray:
        return np.column_stack([0.1 + 0.3 * t, -0.2 * t, 0.15 - 0.05 * t])

    times, ref, cand = align(_traj(t_ref, com=f(t_ref)), _traj(t_cand, com=f(t_cand)), Alignment())
    np.testing.assert_array_equal(times, t_ref)
    np.testing.assert_allclose(cand["com"], f(t_ref), rtol=0, atol=1e-14)
    df = compare(_traj(t_ref, com=f(t_ref)), _traj(t_cand, com=f(t_cand)))
    assert (df.rmse_m < 1e-14).all()
    assert (df.n_samples == len(t_ref)).all()


def test_evaluation_times_are_reference_samples_inside_overlap() -> None:
    t_ref = np.arange(0.0, 10.01, 0.5)
    t_cand = np.linspace(2.2, 7.9, 50)
    ref = _traj(t_ref, com=np.zeros((len(t_ref), 3)))
    cand = _traj(t_cand, com=np.zeros((len(t_cand), 3)))
    times, _, _ = align(ref, cand, Alignment(mode="absolute"))
    np.testing.assert_array_equal(times, np.arange(2.5, 7.51, 0.5))


# --------------------------------------------------------------------------- alignment


def _ramp(t: np.ndarray) -> np.ndarray:
    """Position equal to time on x, so a time error shows directly as a position error."""
    return np.column_stack([t, 2 * t, np.full_like(t, 0.15)])


def test_start_alignment_removes_clock_offset() -> None:
    rel = np.linspace(0.0, 5.0, 101)
    ref = _traj(1000.0 + rel, com=_ramp(rel))  # hardware clock
    cand = _traj(3.0 + rel[::2], com=_ramp(rel[::2]))  # simulation clock, coarser
    df = compare(ref, cand, Alignment(mode="start"))
    assert (df.rmse_m < 1e-12).all()
    times, _, _ = align(ref, cand, Alignment(mode="start"))
    assert times[0] == 0.0 and times[-1] == pytest.approx(5.0)


def test_absolute_alignment_without_overlap_names_both_ranges() -> None:
    rel = np.linspace(0.0, 5.0, 11)
    ref = _traj(1000.0 + rel, com=_ramp(rel))
    cand = _traj(rel, com=_ramp(rel))
    with pytest.raises(TrajectoryError) as exc:
        compare(ref, cand, Alignment(mode="absolute"))
    msg = str(exc.value)
    assert "\n" not in msg
    assert "[1000, 1005] s" in msg and "[0, 5] s" in msg


def test_offset_is_added_to_candidate_time() -> None:
    t = np.linspace(0.0, 10.0, 1001)
    latency = 0.3
    ref = _traj(t, com=_ramp(t))
    # The candidate's timestamps are `latency` late: at stamp s it reports the position of time s - latency.
    cand = _traj(t, com=_ramp(t - latency))
    late = compare(ref, cand, Alignment(mode="absolute"))
    assert _row(late, "com", "x").rmse_m == pytest.approx(latency)
    assert _row(late, "com", "y").mae_m == pytest.approx(2 * latency)
    fixed = compare(ref, cand, Alignment(mode="absolute", offset_s=-latency))
    assert (fixed.rmse_m < 1e-12).all()
    # Only the overlap [0, 9.7] of the shifted candidate is evaluated.
    times, _, _ = align(ref, cand, Alignment(mode="absolute", offset_s=-latency))
    assert times[0] == 0.0 and times[-1] == pytest.approx(10.0 - latency)
    assert _row(fixed, "com", "x").n_samples == len(times) == 971


def test_offset_applies_after_start_shift() -> None:
    t = np.linspace(0.0, 4.0, 41)
    ref = _traj(50.0 + t, com=_ramp(t))
    cand = _traj(7.0 + t, com=_ramp(t))
    times, _, _ = align(ref, cand, Alignment(mode="start", offset_s=0.5))
    assert times[0] == pytest.approx(0.5) and times[-1] == pytest.approx(4.0)


def test_alignment_rejects_unknown_mode() -> None:
    with pytest.raises(TrajectoryError, match="start"):
        Alignment(mode="xcorr")


# --------------------------------------------------------------------------- NaN and markers


def test_nan_samples_are_dropped_and_counted() -> None:
    t = np.arange(20) * 0.1
    ref = _ramp(t)
    cand = ref + np.array([0.01, 0.0, 0.0])
    ref[[2, 3, 4], 0] = np.nan  # reference lost tracking
    cand[[10, 15], 0] = np.nan  # candidate lost tracking (exact time hits: only these samples)
    df = compare(_traj(t, com=ref), _traj(t, com=cand))
    x = _row(df, "com", "x")
    assert x.n_samples == 20 - 5
    assert x.rmse_m == pytest.approx(0.01) and x.mae_m == pytest.approx(0.01)
    assert _row(df, "com", "y").n_samples == 20


def test_candidate_nan_propagates_to_bracketed_samples() -> None:
    t_ref = np.arange(0, 41) * 0.05  # 0 .. 2 s
    t_cand = np.arange(0, 5) * 0.5  # 0, 0.5, 1, 1.5, 2
    cand = _ramp(t_cand)
    cand[2, 0] = np.nan  # at t = 1.0: poisons (0.5, 1.5) exclusive
    _, _, c = align(_traj(t_ref, com=_ramp(t_ref)), _traj(t_cand, com=cand), Alignment())
    nan_times = t_ref[np.isnan(c["com"][:, 0])]
    np.testing.assert_allclose(nan_times, t_ref[(t_ref > 0.5 + 1e-9) & (t_ref < 1.5 - 1e-9)])
    assert not np.isnan(c["com"][:, 1]).any()


def test_flat_reference_axis_gives_nan_nrmse() -> None:
    t = np.linspace(0.0, 1.0, 11)
    ref = _ramp(t)  # z is constant 0.15
    cand = ref + 0.002
    df = compare(_traj(t, com=ref), _traj(t, com=cand))
    z = _row(df, "com", "z")
    assert math.isnan(z.nrmse)
    assert z.rmse_m == pytest.approx(0.002)
    assert _row(df, "com", "x").nrmse == pytest.approx(0.002 / 1.0)


def test_marker_selection_and_shared_markers() -> None:
    t = np.linspace(0.0, 1.0, 11)
    ref = _traj(t, com=_ramp(t), FL_n30=_ramp(t), RR_n0=_ramp(t))
    cand = _traj(t, com=_ramp(t), FL_n30=_ramp(t) + 0.001)
    df = compare(ref, cand)
    assert list(dict.fromkeys(df.marker)) == ["com", "FL_n30"]
    assert len(compare(ref, cand, markers=["FL_n30"])) == 3
    with pytest.raises(TrajectoryError, match="RR_n0"):
        compare(ref, cand, markers=["RR_n0"])
    with pytest.raises(TrajectoryError, match="share no marker"):
        compare(ref, _traj(t, other=_ramp(t)))


def test_trajectory_validates_shapes_and_time() -> None:
    t = np.linspace(0.0, 1.0, 5)
    with pytest.raises(TrajectoryError, match="shape"):
        Trajectory(t=t, markers={"com": np.zeros((5, 2))})
    with pytest.raises(TrajectoryError, match="strictly increasing"):
        Trajectory(t=np.array([0.0, 1.0, 1.0]), markers={"com": np.zeros((3, 3))})
    with pytest.raises(TrajectoryError, match="finite"):
        Trajectory(t=np.array([0.0, np.nan, 2.0]), markers={"com": np.zeros((3, 3))})


# --------------------------------------------------------------------------- CSV


def test_csv_round_trip_with_comments_and_empty_cells(tmp_path: Path) -> None:
    t = 12.0 + np.arange(6) / 30.0
    com = np.column_stack([0.001 * np.arange(6), np.zeros(6), 0.15 + 0.0001 * np.arange(6)])
    leg = np.column_stack([0.12 + 0.001 * np.arange(6), 0.08 * np.ones(6), 0.01 * np.ones(6)])
    leg[2] = np.nan
    lines = ["# session 2024-05-02, ArUco, 30 fps", "", "t,com_x,com_y,com_z,FL_n30_x,FL_n30_y,FL_n30_z"]
    for i in range(6):
        cells = [repr(float(t[i]))] + [repr(float(v)) for v in com[i]]
        cells += ["" if np.isnan(v) else repr(float(v)) for v in leg[i]]
        lines.append(",".join(cells))
        if i == 3:
            lines.append("# tracking glitch below")
    path = tmp_path / "tracks.csv"
    path.write_text("\n".join(lines) + "\n")

    traj = load_marker_csv(path)
    np.testing.assert_array_equal(traj.t, t)
    assert list(traj.markers) == ["com", "FL_n30"]
    np.testing.assert_array_equal(traj.markers["com"], com)
    np.testing.assert_array_equal(traj.markers["FL_n30"], leg)  # NaNs compare equal here

    df = compare(traj, traj)
    assert _row(df, "FL_n30", "x").n_samples == 5
    assert (df.rmse_m == 0.0).all()


_HEADER = "t,com_x,com_y,com_z"


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        ("", "empty"),
        ("# only a comment\n\n", "empty"),
        ("time,com_x,com_y,com_z\n0,0,0,0\n1,0,0,0\n", "'t'"),
        ("t,com_x,com_y\n0,0,0\n1,0,0\n", "com_z"),
        (f"{_HEADER}\n0,0,0,0\n0.1,0,abc,0\n", "line 3, column 'com_y'"),
        (f"# c\n{_HEADER}\n0,0,0,0\n0.2,0,0,0\n0.1,0,0,0\n", "line 5"),
        (f"{_HEADER}\n0,0,0,0\n0,0,0,0\n", "strictly increasing"),
        (f"{_HEADER}\n0,0,0,0\n", "1 data row"),
        (f"{_HEADER}\n", "0 data row"),
        (f"{_HEADER}\n0,0,0,0\n,0,0,0\n", "line 3, column 't'"),
        (f"{_HEADER}\n0,0,0,0\n1,0,0\n", "line 3"),
        ("t,com_x,com_y,com_z,bad-name\n0,0,0,0,0\n1,0,0,0,0\n", "bad-name"),
        (f"{_HEADER}\n0,,,\n1,nan,nan,nan\n", "no tracked sample"),  # an export with nothing tracked
        (f"{_HEADER}\n0,100,-30,40\n1,250,-30,40\n", "millimetres"),  # positions in mm: 0.25 m read as 250 m
        (f"{_HEADER}\n0,0,0,0\n100000,0,0,0\n", "milliseconds"),  # times in ms: 100 s read as 28 hours
    ],
    ids=[
        "empty",
        "comments-only",
        "no-t",
        "missing-axis",
        "non-numeric",
        "decreasing-t",
        "repeated-t",
        "one-row",
        "no-rows",
        "empty-t",
        "short-row",
        "bad-column",
        "nothing-tracked",
        "millimetres",
        "milliseconds",
    ],
)
def test_csv_errors_are_one_line_and_name_the_file(tmp_path: Path, content: str, expected: str) -> None:
    path = tmp_path / "bad_tracks.csv"
    path.write_text(content)
    with pytest.raises(TrajectoryError) as exc:
        load_marker_csv(path)
    assert expected in _one_line_naming(exc, path)


def test_csv_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nowhere.csv"
    with pytest.raises(TrajectoryError) as exc:
        load_marker_csv(path)
    assert "does not exist" in _one_line_naming(exc, path)


# --------------------------------------------------------------------------- logged frames


def test_trajectory_from_frame() -> None:
    t = np.linspace(0.0, 1.0, 4)
    df = pd.DataFrame(
        {
            "t": t,
            "com.0": t,
            "com.1": 2 * t,
            "com.2": [0.15, 0.15, np.nan, 0.15],
            "FL_n30.0": t,
            "FL_n30.1": t,  # incomplete: ignored
            "mode": ["stand"] * 4,  # unrelated column: ignored
        }
    )
    traj = trajectory_from_frame(df)
    assert list(traj.markers) == ["com"]
    np.testing.assert_array_equal(traj.t, t)
    np.testing.assert_array_equal(traj.markers["com"], np.column_stack([t, 2 * t, [0.15, 0.15, np.nan, 0.15]]))
    with pytest.raises(TrajectoryError, match="'t'"):
        trajectory_from_frame(df.drop(columns="t"))
    with pytest.raises(TrajectoryError, match="no complete marker"):
        trajectory_from_frame(df[["t", "FL_n30.0", "FL_n30.1"]])


# --------------------------------------------------------------------------- figure


def test_plot_overlay_writes_png(tmp_path: Path) -> None:
    import matplotlib.pyplot as plt

    from slotexp.figures.validate import plot_overlay

    t = np.linspace(0.0, 2.0, 81)
    ref = {"com": _ramp(t) * 0.01, "FL_n30": np.sin(np.column_stack([t, 2 * t, 3 * t])) * 0.01}
    cand = {k: v + 0.0005 for k, v in ref.items()}
    cand["com"][10:15] = np.nan
    open_before = plt.get_fignums()
    out = plot_overlay(t, ref, cand, tmp_path / "fig" / "overlay.png", title="validate")
    assert out == tmp_path / "fig" / "overlay.png"
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
    assert plt.get_fignums() == open_before  # no pyplot figure left open
