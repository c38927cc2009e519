"""A :class:`~slotexp.scene.SceneFrame` as Foxglove's own message types, built with ``foxglove-sdk``.

The SDK's message classes carry Foxglove's official schemas (``get_schema()``: a
protobuf descriptor set) and their encoder (``encode()``), so the log and the live
server write messages every Foxglove panel reads, with no hand-made schema.

Topics:
- ``/scene`` (``foxglove.SceneUpdate``): entities ``torso`` (a cube), ``leg/<name>``
  (a line strip through every node, root to foot), ``force/<name>`` (an arrow, see
  :mod:`slotexp.scene` for the scale), ``feet`` (a sphere per foot), ``footholds``
  (a flat disc per planned foothold, when the controller plans them: the rigid
  quadruped), ``path/reference`` and ``path/actual`` (line strips). Each message
  replaces every entity, so any one message draws the whole scene (a seek in
  Foxglove needs only the last one).
- ``/transforms`` (``foxglove.FrameTransforms``): world -> torso.
"""

from __future__ import annotations

import numpy as np
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    CubePrimitive,
    FrameTransform,
    FrameTransforms,
    LinePrimitive,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)

from .scene import ARROW_HEAD_FRACTION, SceneFrame

SCENE_TOPIC = "/scene"
TRANSFORMS_TOPIC = "/transforms"
WORLD_FRAME = "world"
TORSO_FRAME = "torso"
LINE_THICKNESS_M = 0.003
ARROW_SHAFT_DIAMETER_M = 0.004
ARROW_HEAD_DIAMETER_M = 0.01
FOOT_DIAMETER_M = 0.012
FOOTHOLD_SIZE_M = (0.03, 0.03, 0.002)  # a flat disc on the ground

_TORSO_COLOR = Color(r=0.6, g=0.6, b=0.65, a=0.8)
_LEG_COLORS = (  # FL, RL, RR, FR: the colours of the figures' legs
    Color(r=0.12, g=0.47, b=0.71, a=1.0),
    Color(r=1.0, g=0.5, b=0.05, a=1.0),
    Color(r=0.17, g=0.63, b=0.17, a=1.0),
    Color(r=0.84, g=0.15, b=0.16, a=1.0),
)
_FORCE_COLOR = Color(r=0.9, g=0.1, b=0.1, a=1.0)
_REFERENCE_COLOR = Color(r=0.2, g=0.8, b=0.2, a=0.9)
_ACTUAL_COLOR = Color(r=0.1, g=0.3, b=0.9, a=0.9)
_FOOT_COLOR = Color(r=0.1, g=0.1, b=0.1, a=1.0)
_FOOTHOLD_COLOR = Color(r=1.0, g=0.8, b=0.0, a=0.9)
_UPRIGHT = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)


def _spheres(points: np.ndarray, size: tuple[float, float, float], color: Color) -> list[SpherePrimitive]:
    return [
        SpherePrimitive(
            pose=Pose(position=_v(p), orientation=_UPRIGHT), size=Vector3(x=size[0], y=size[1], z=size[2]), color=color
        )
        for p in points
    ]


_NS_PER_S = 1_000_000_000


def timestamp(t: float) -> Timestamp:
    """Seconds -> Foxglove Timestamp (the same nanoseconds the MCAP log time holds)."""
    ns = int(round(float(t) * _NS_PER_S))
    return Timestamp(ns // _NS_PER_S, ns % _NS_PER_S)


def _v(p: np.ndarray) -> Vector3:
    return Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _q_xyzw(q: np.ndarray) -> Quaternion:
    return Quaternion(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3]))


def _q_wxyz(q: np.ndarray) -> Quaternion:
    return Quaternion(x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0]))


def _strip(points: np.ndarray | list[Point3], color: Color) -> LinePrimitive:
    if isinstance(points, np.ndarray):
        points = [Point3(x=p[0], y=p[1], z=p[2]) for p in points.tolist()]
    return LinePrimitive(thickness=LINE_THICKNESS_M, points=points, color=color)


class _PathEntities:
    """The path entities, rebuilt only when their path gained a point (:class:`slotexp.scene.SceneTrack`
    returns the same array until then): converting a whole path every step was most of the scene's cost on
    a fast loop. A rebuilt entity converts only the points that are new."""

    def __init__(self) -> None:
        self._source: dict[str, np.ndarray] = {}
        self._entity: dict[str, SceneEntity] = {}
        self._points: dict[str, list[Point3]] = {}

    def __call__(self, key: str, path: np.ndarray, stamp: Timestamp, color: Color) -> SceneEntity:
        if self._source.get(key) is path:
            return self._entity[key]
        old = self._points.get(key, [])
        prev = self._source.get(key)
        keep = (
            len(old) if prev is not None and len(prev) <= len(path) and np.array_equal(prev, path[: len(prev)]) else 0
        )
        points = old[:keep] + [Point3(x=r[0], y=r[1], z=r[2]) for r in path[keep:].tolist()]
        entity = SceneEntity(timestamp=stamp, frame_id=WORLD_FRAME, id=f"path/{key}", lines=[_strip(points, color)])
        self._source[key], self._points[key], self._entity[key] = path, points, entity
        return entity


def scene_update(frame: SceneFrame, paths: _PathEntities | None = None) -> SceneUpdate:
    """The whole scene at one step as one ``foxglove.SceneUpdate`` (world frame). A path entity keeps the
    timestamp of the step its path last changed (``paths`` reuses it until then)."""
    stamp = timestamp(frame.t)
    paths = paths or _PathEntities()

    def entity(id: str, **primitives) -> SceneEntity:
        return SceneEntity(timestamp=stamp, frame_id=WORLD_FRAME, id=id, **primitives)

    entities = [
        entity(
            "torso",
            cubes=[
                CubePrimitive(
                    pose=Pose(position=_v(frame.position), orientation=_q_wxyz(frame.quaternion_wxyz)),
                    size=_v(frame.torso_size),
                    color=_TORSO_COLOR,
                )
            ],
        )
    ]
    for i, name in enumerate(frame.leg_names):
        entities.append(entity(f"leg/{name}", lines=[_strip(frame.legs[i], _LEG_COLORS[i % len(_LEG_COLORS)])]))
    for name, arrow in zip(frame.leg_names, frame.arrows):
        head = ARROW_HEAD_FRACTION * arrow.length
        entities.append(
            entity(
                f"force/{name}",
                arrows=[
                    ArrowPrimitive(
                        pose=Pose(position=_v(arrow.tail), orientation=_q_xyzw(arrow.orientation_xyzw)),
                        shaft_length=arrow.length - head,
                        shaft_diameter=ARROW_SHAFT_DIAMETER_M,
                        head_length=head,
                        head_diameter=ARROW_HEAD_DIAMETER_M,
                        color=_FORCE_COLOR,
                    )
                ],
            )
        )
    foot = (FOOT_DIAMETER_M,) * 3
    entities.append(entity("feet", spheres=_spheres(frame.feet, foot, _FOOT_COLOR)))
    if frame.footholds is not None:
        entities.append(entity("footholds", spheres=_spheres(frame.footholds, FOOTHOLD_SIZE_M, _FOOTHOLD_COLOR)))
    entities.append(paths("reference", frame.reference_path, stamp, _REFERENCE_COLOR))
    entities.append(paths("actual", frame.actual_path, stamp, _ACTUAL_COLOR))
    return SceneUpdate(entities=entities)


def frame_transforms(frame: SceneFrame) -> FrameTransforms:
    """world -> torso as ``foxglove.FrameTransforms`` (the 3D panel's frame tree)."""
    return FrameTransforms(
        transforms=[
            FrameTransform(
                timestamp=timestamp(frame.t),
                parent_frame_id=WORLD_FRAME,
                child_frame_id=TORSO_FRAME,
                translation=_v(frame.position),
                rotation=_q_wxyz(frame.quaternion_wxyz),
            )
        ]
    )


class SceneEncoder:
    """Turns a run's frames, one step after another, into (topic, message) pairs (one per sink)."""

    def __init__(self) -> None:
        self._paths = _PathEntities()

    def messages(self, frame: SceneFrame) -> list[tuple[str, SceneUpdate | FrameTransforms]]:
        """(topic, message) pairs of one step's scene, in the order they are written."""
        return [(TRANSFORMS_TOPIC, frame_transforms(frame)), (SCENE_TOPIC, scene_update(frame, self._paths))]


__all__ = ["SCENE_TOPIC", "TRANSFORMS_TOPIC", "SceneEncoder", "scene_update", "frame_transforms", "timestamp"]
