"""Animated GIF of a soft-leg run, side and top views, rebuilt from its log."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from matplotlib.animation import FuncAnimation, PillowWriter

from .. import telemetry as T
from ..atomic import replacing
from ..body import horizontal, quat_to_rot
from .style import LEG_COLOURS, new_figure

BOX_EDGES = [(0, 1), (1, 3), (3, 2), (2, 0), (4, 5), (5, 7), (7, 6), (6, 4), (0, 4), (1, 5), (2, 6), (3, 7)]


def _box(position: np.ndarray, quat: np.ndarray, size: np.ndarray, com_offset: np.ndarray) -> np.ndarray:
    """The torso box's corners: about its own centre, ``com_offset`` (body frame) from the mass centre at
    ``position``."""
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * size / 2
    return position + (corners - com_offset) @ quat_to_rot(quat).T


def animate(
    t: np.ndarray,
    positions: np.ndarray,
    quats: np.ndarray,
    legs: dict[str, np.ndarray],
    torso_size: np.ndarray,
    path: str | Path,
    fps: float = 10.0,
    title: str = "",
    com_offset: np.ndarray | None = None,
) -> Path:
    """``legs[name]`` is (frames, N, 3) in the world frame; one frame per entry of ``t``; ``positions`` are the
    torso's mass centre, ``com_offset`` (body frame, horizontal) where it sits from the box's centre."""
    offset = np.zeros(3) if com_offset is None else horizontal(com_offset)
    fig = new_figure(9, 4.2)
    side, top = fig.subplots(1, 2)
    everything = np.concatenate([v.reshape(-1, 3) for v in legs.values()] + [positions])
    lo, hi = everything.min(axis=0) - 0.03, everything.max(axis=0) + 0.03
    side.set_xlim(lo[0], hi[0])
    side.set_ylim(-0.01, max(0.12, hi[2] + 0.02))
    side.set_aspect("equal")
    side.axhline(0.0, color="0.4", lw=1.5)
    side.set_xlabel("x [m]")
    side.set_ylabel("z [m]")
    side.set_title("side", fontsize=9)
    top.set_xlim(lo[0], hi[0])
    top.set_ylim(lo[1], hi[1])
    top.set_aspect("equal")
    top.set_xlabel("x [m]")
    top.set_ylabel("y [m]")
    top.set_title("top", fontsize=9)
    box_side = [side.plot([], [], color="0.2", lw=1)[0] for _ in BOX_EDGES]
    box_top = [top.plot([], [], color="0.2", lw=1)[0] for _ in BOX_EDGES]
    leg_side = {n: side.plot([], [], "-", lw=2, color=LEG_COLOURS.get(n, "m"))[0] for n in legs}
    leg_top = {n: top.plot([], [], "-", lw=2, color=LEG_COLOURS.get(n, "m"), label=n)[0] for n in legs}
    (trail,) = top.plot([], [], ":", color="0.5", lw=1)
    top.legend(fontsize=7, loc="upper left")
    label = fig.suptitle("", fontsize=9)

    def draw(k: int):
        box = _box(positions[k], quats[k], torso_size, offset)
        for line_s, line_t, (a, b) in zip(box_side, box_top, BOX_EDGES):
            line_s.set_data(box[[a, b], 0], box[[a, b], 2])
            line_t.set_data(box[[a, b], 0], box[[a, b], 1])
        for name, nodes in legs.items():
            leg_side[name].set_data(nodes[k, :, 0], nodes[k, :, 2])
            leg_top[name].set_data(nodes[k, :, 0], nodes[k, :, 1])
        trail.set_data(positions[: k + 1, 0], positions[: k + 1, 1])
        label.set_text(f"{title};  t = {t[k]:5.2f} s")
        return []

    anim = FuncAnimation(fig, draw, frames=len(t), blit=False)
    path = Path(path)
    with replacing(path) as tmp:  # a stopped save leaves the previous GIF or none, never a torn one
        # matplotlib announces every save at INFO, which Hydra's logging prints: one line of noise per GIF
        logging.getLogger("matplotlib.animation").setLevel(logging.WARNING)
        anim.save(tmp, writer=PillowWriter(fps=fps), dpi=80)
    return path


def animate_log(log_path: str | Path, out: str | Path, seconds: float = 8.0, fps: int = 10) -> Path | None:
    """The GIF for a logged soft-leg run, or None if the log has no leg shapes."""
    import yaml

    from ..record import read_log

    log = read_log(log_path)
    if T.LEGS_SHAPE not in log:
        return None
    shape = log[T.LEGS_SHAPE]
    pose = log[T.POSE]
    conf = yaml.safe_load(log.metadata["config"]["yaml"])
    names = conf["robot"]["leg"]["names"]
    n_nodes = len([c for c in shape.columns if c.startswith(f"{names[0]}.") and c.endswith(".0")])
    t = shape["t"].to_numpy(float)
    step = max(1, int(round(1.0 / (fps * (t[1] - t[0]))))) if len(t) > 1 else 1
    idx = np.arange(0, len(t), step)
    idx = idx[t[idx] <= t[0] + seconds]
    # frames every `step` samples of the log, played at the rate that shows them in real time (a GIF's frame
    # times are whole hundredths of a second: the title states the speed that leaves)
    frame_s = float(t[idx[1]] - t[idx[0]]) if len(idx) > 1 else 1.0 / fps
    shown_s = max(0.02, round(frame_s, 2))
    fps = 1.0 / shown_s
    legs = {
        n: shape[[f"{n}.{i}.{j}" for i in range(n_nodes) for j in range(3)]]
        .to_numpy(float)[idx]
        .reshape(len(idx), n_nodes, 3)
        for n in names
    }
    pos = pose[["pose.position.x", "pose.position.y", "pose.position.z"]].to_numpy(float)[idx]
    quat = pose[["pose.orientation.w", "pose.orientation.x", "pose.orientation.y", "pose.orientation.z"]].to_numpy(
        float
    )[idx]
    run = log.metadata.get("run", {})
    return animate(
        t[idx],
        pos,
        quat,
        legs,
        np.asarray(conf["robot"]["torso"]["size"], dtype=float),
        out,
        fps,
        title=f"{run.get('gait', '')} gait, {run.get('plant', '')} plant, plays at {frame_s / shown_s:.2g}x real time",
        com_offset=np.asarray(conf["robot"]["torso"].get("com_offset", [0.0, 0.0]), dtype=float),
    )
