"""The scene built as ``foxglove-sdk`` message objects and encoded by the SDK: the reference that
:class:`slotexp.foxglove_scene.SceneEncoder`'s own wire bytes are checked against (the library writes
the bytes itself because building these objects every step was most of what the scene cost)."""

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

from slotexp import foxglove_scene as fs
from slotexp.scene import SceneFrame

_UPRIGHT = Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)


def _color(rgba: tuple[float, float, float, float]) -> Color:
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def _v(p: np.ndarray) -> Vector3:
    return Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def _q_wxyz(q: np.ndarray) -> Quaternion:
    return Quaternion(x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0]))


def _strip(points: np.ndarray, rgba: tuple[float, float, float, float]) -> LinePrimitive:
    return LinePrimitive(
        thickness=fs.LINE_THICKNESS_M,
        points=[Point3(x=p[0], y=p[1], z=p[2]) for p in np.asarray(points).tolist()],
        color=_color(rgba),
    )


def _spheres(points: np.ndarray, size: tuple[float, float, float], rgba) -> list[SpherePrimitive]:
    return [
        SpherePrimitive(
            pose=Pose(position=_v(p), orientation=_UPRIGHT),
            size=Vector3(x=size[0], y=size[1], z=size[2]),
            color=_color(rgba),
        )
        for p in points
    ]


def _entity(t: float, id: str, **primitives) -> SceneEntity:
    return SceneEntity(timestamp=Timestamp(*fs.timestamp_ns(t)), frame_id=fs.WORLD_FRAME, id=id, **primitives)


def scene_update(frame: SceneFrame) -> SceneUpdate:
    """The step's ``/scene``: the robot (torso, legs, arrows, feet, footholds)."""

    def entity(id: str, **primitives) -> SceneEntity:
        return _entity(frame.t, id, **primitives)

    cube = CubePrimitive(
        pose=Pose(
            position=_v(frame.position if frame.box_centre is None else frame.box_centre),
            orientation=_q_wxyz(frame.quaternion_wxyz),
        ),
        size=_v(frame.torso_size),
        color=_color(fs.TORSO_COLOR),
    )
    entities = [entity("torso", cubes=[cube])]
    for i, name in enumerate(frame.leg_names):
        entities.append(entity(f"leg/{name}", lines=[_strip(frame.legs[i], fs.LEG_COLORS[i % 4])]))
    for i, name in enumerate(frame.leg_names):
        x, y, z, qx, qy, qz, qw, shaft, head = frame.arrows[i].tolist()
        arrow = ArrowPrimitive(
            pose=Pose(position=Vector3(x=x, y=y, z=z), orientation=Quaternion(x=qx, y=qy, z=qz, w=qw)),
            shaft_length=shaft,
            shaft_diameter=fs.ARROW_SHAFT_DIAMETER_M,
            head_length=head,
            head_diameter=fs.ARROW_HEAD_DIAMETER_M,
            color=_color(fs.FORCE_COLOR),
        )
        entities.append(entity(f"force/{name}", arrows=[arrow]))
    entities.append(entity("feet", spheres=_spheres(frame.feet, (fs.FOOT_DIAMETER_M,) * 3, fs.FOOT_COLOR)))
    if frame.footholds is not None:
        entities.append(entity("footholds", spheres=_spheres(frame.footholds, fs.FOOTHOLD_SIZE_M, fs.FOOTHOLD_COLOR)))
    return SceneUpdate(entities=entities)


def path_update(frame: SceneFrame, key: str) -> SceneUpdate:
    """The step's message on ``PATH_TOPICS[key]``: the path's one entity."""
    path, rgba = {
        "reference": (frame.reference_path, fs.REFERENCE_COLOR),
        "actual": (frame.actual_path, fs.ACTUAL_COLOR),
    }[key]
    return SceneUpdate(entities=[_entity(frame.t, f"path/{key}", lines=[_strip(path, rgba)])])


def frame_transforms(frame: SceneFrame) -> FrameTransforms:
    transform = FrameTransform(
        timestamp=Timestamp(*fs.timestamp_ns(frame.t)),
        parent_frame_id=fs.WORLD_FRAME,
        child_frame_id=fs.TORSO_FRAME,
        translation=_v(frame.position),
        rotation=_q_wxyz(frame.quaternion_wxyz),
    )
    return FrameTransforms(transforms=[transform])
