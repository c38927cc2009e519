"""What the 3D view of a run shows at one MPC step, as plain geometry (numpy, no file or viewer code).

A :class:`SceneFrame` holds the torso box, each leg's centreline (every node), the
feet, each foot's ground-reaction force as an arrow, the footholds a controller plans
(the rigid quadruped's footstep planner), and the reference and actual paths so far.
:class:`SceneTrack` builds one per step and keeps the two paths; the log and the live
view (``slotexp/foxglove_scene.py``) turn the same frame into Foxglove messages, so
what a log shows and what a live client sees cannot differ.

Force arrows: tail at the foot, pointing along the applied force (world frame), length
``FORCE_SCALE_M_PER_N`` metres per newton (1 cm/N: a foot carrying a quarter of the
robot's weight, about 5.3 N, draws a 5.3 cm arrow, about half a leg). The last
``ARROW_HEAD_FRACTION`` of the length is the head.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .body import horizontal, quat_to_rot
from .jit import njit

FORCE_SCALE_M_PER_N = 0.01
ARROW_HEAD_FRACTION = 0.25
PATH_SPACING_M = 0.005  # a path keeps a point each time the robot has moved this far: bounded by distance, not time
PATH_MAX_POINTS = 500  # beyond this a path keeps every other point: a step costs the same on any run length


@dataclass(slots=True)
class SceneFrame:
    """One step of the 3D scene, world frame, metres. Read-only by convention: one frame goes to every
    sink (the log and the live view). Not a frozen dataclass: its ``__init__`` cost three times as much,
    every logged step."""

    t: float
    position: np.ndarray  # torso centre (3,)
    quaternion_wxyz: np.ndarray  # torso attitude (4,)
    torso_size: np.ndarray  # box edges (3,)
    leg_names: tuple[str, ...]
    legs: np.ndarray  # (4, N, 3) centreline nodes, root to foot
    forces: np.ndarray  # (4, 3) applied ground-reaction forces, N
    arrows: np.ndarray  # (4, 9) per foot: tail (the foot), rotation x, y, z, w from +x onto the force, shaft, head
    reference_path: np.ndarray  # (M, 3)
    actual_path: np.ndarray  # (K, 3)
    feet: np.ndarray  # (4, 3) where the forces act
    footholds: np.ndarray | None = None  # (4, 3) where the controller plans to put each foot; None: it plans none
    box_centre: np.ndarray | None = None  # the torso box's centre (3,), where the cube is drawn; None: ``position``


@njit(cache=True)
def rotation_from_x(direction: np.ndarray) -> tuple[float, float, float, float]:
    """Shortest rotation (x, y, z, w) from the +x axis to ``direction`` (3,); identity for a zero or
    non-finite vector, half a turn about z for -x."""
    dx, dy, dz = float(direction[0]), float(direction[1]), float(direction[2])
    n = math.sqrt(dx * dx + dy * dy + dz * dz)
    if not (n > 0.0 and math.isfinite(n)):
        return (0.0, 0.0, 0.0, 1.0)
    dx, dy, dz = dx / n, dy / n, dz / n
    if dx < -1.0 + 1e-12:
        return (0.0, 0.0, 1.0, 0.0)
    w = 1.0 + dx  # (x cross d, 1 + x . d), normalised
    m = math.sqrt(dz * dz + dy * dy + w * w)
    return (0.0, -dz / m, dy / m, w / m)


@njit(cache=True)
def force_arrows(feet: np.ndarray, forces: np.ndarray, scale: float = FORCE_SCALE_M_PER_N) -> np.ndarray:
    """Each foot's force as an arrow (n, 9): the tail (the foot), the rotation x, y, z, w from +x onto the
    force, then the shaft's and the head's length, together ``scale`` metres per newton (zero for a zero or
    non-finite force). Compiled: in Python, four arrows cost as much as the rest of a step's scene."""
    out = np.empty((feet.shape[0], 9))
    for i in range(feet.shape[0]):
        f = forces[i]
        magnitude = math.sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2])
        length = magnitude * scale if math.isfinite(magnitude) else 0.0
        head = ARROW_HEAD_FRACTION * length
        out[i, :3] = feet[i]
        out[i, 3:7] = rotation_from_x(f)
        out[i, 7] = length - head
        out[i, 8] = head
    return out


@njit(cache=True)
def straight_legs(segments_body: np.ndarray, position: np.ndarray, quaternion_wxyz: np.ndarray) -> np.ndarray:
    """Legs drawn as straight segments (n, 2, 3), ``segments_body`` (n, 2, 3) (each leg's torso corner and
    foot, body frame) at the torso's pose (float arrays), where no leg shape is known (the ideal plant, and
    the robot's nominal feet). Compiled: it runs every logged step."""
    rot = quat_to_rot(quaternion_wxyz)
    out = np.empty(segments_body.shape)
    for i in range(segments_body.shape[0]):
        for j in range(segments_body.shape[1]):
            x, y, z = segments_body[i, j, 0], segments_body[i, j, 1], segments_body[i, j, 2]
            for a in range(3):
                out[i, j, a] = position[a] + rot[a, 0] * x + rot[a, 1] * y + rot[a, 2] * z
    return out


class _Path:
    """Points along a trajectory, one each time it has moved ``spacing`` metres from the last.

    The path ends at most ``spacing`` behind the robot (5 mm against a 125 mm torso) and
    changes only when it gains a point: :meth:`add` then returns a new array, and otherwise
    the same one, so a consumer can tell an unchanged path by identity and reuse what it
    built from it (the scene's most expensive part on a fast loop).
    """

    def __init__(self, spacing: float, max_points: int) -> None:
        self._spacing = spacing
        self._max = max_points
        self._last: list[float] | None = None
        self._buffer = np.empty((max_points + 1, 3))  # the kept points are its first rows
        self._points = self._buffer[:0]

    def add(self, point: Sequence[float]) -> np.ndarray:
        """Keep ``point`` if it is ``spacing`` from the last kept one; the kept points (k, 3).

        The kept points are a view of a buffer that a new point extends past the end of every
        earlier view, so a path once returned never changes; thinning starts a new buffer."""
        p = point.tolist() if isinstance(point, np.ndarray) else [float(v) for v in point]
        if not (math.isfinite(p[0]) and math.isfinite(p[1]) and math.isfinite(p[2])):
            return self._points
        if self._last is not None and math.dist(p, self._last) < self._spacing:
            return self._points
        n = len(self._points)
        self._buffer[n] = p
        self._last = p
        if n + 1 > self._max:  # every other point, the newest always kept
            kept = self._buffer[n::-2][::-1]
            self._buffer = np.empty_like(self._buffer)
            self._buffer[: len(kept)] = kept
            n = len(kept) - 1
        self._points = self._buffer[: n + 1]
        return self._points


class SceneTrack:
    """Builds each step's :class:`SceneFrame` and remembers the reference and actual paths."""

    def __init__(
        self,
        leg_names: Sequence[str],
        torso_size: Sequence[float],
        spacing: float = PATH_SPACING_M,
        max_points: int = PATH_MAX_POINTS,
        com_offset: Sequence[float] = (0.0, 0.0),
    ) -> None:
        self.leg_names = tuple(leg_names)
        self.torso_size = np.asarray(torso_size, dtype=float)
        # the mass centre (the pose's position) from the box's centre, body frame (robot.torso.com_offset)
        self.com_offset = horizontal(com_offset)
        self._reference = _Path(spacing, max_points)
        self._actual = _Path(spacing, max_points)

    def frame(
        self,
        t: float,
        position: np.ndarray,
        quaternion_wxyz: np.ndarray,
        reference_position: np.ndarray,
        legs: np.ndarray,
        forces: np.ndarray,
        footholds: np.ndarray | None = None,
    ) -> SceneFrame:
        """The scene at ``t``: ``legs`` (4, N, 3) root to foot, ``forces`` (4, 3) applied at each leg's last
        point (the foot), and the controller's planned ``footholds`` (4, 3), if it plans any."""
        legs = np.asarray(legs, dtype=float)
        feet = legs[:, -1, :]
        forces = np.asarray(forces, dtype=float)
        position = np.asarray(position, dtype=float)
        centre = position
        if self.com_offset.any():  # the box is drawn about its own centre, not the mass centre
            centre = position - quat_to_rot(np.asarray(quaternion_wxyz, dtype=float)) @ self.com_offset
        return SceneFrame(
            t=float(t),
            position=position,
            quaternion_wxyz=np.asarray(quaternion_wxyz, dtype=float),
            torso_size=self.torso_size,
            leg_names=self.leg_names,
            legs=legs,
            forces=forces,
            arrows=force_arrows(feet, forces),
            reference_path=self._reference.add(reference_position),
            actual_path=self._actual.add(position),
            feet=feet,
            footholds=None if footholds is None else np.asarray(footholds, dtype=float),
            box_centre=centre,
        )


__all__ = [
    "SceneFrame",
    "SceneTrack",
    "FORCE_SCALE_M_PER_N",
    "ARROW_HEAD_FRACTION",
    "force_arrows",
    "rotation_from_x",
    "straight_legs",
]
