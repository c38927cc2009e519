"""A :class:`~slotexp.scene.SceneFrame` and the torso's transform as Foxglove's own message types, in the
schemas of ``foxglove-sdk``.

The schemas are the SDK's (``SceneUpdate.get_schema()``: Foxglove's protobuf descriptor
set), so the log and the live server carry messages every Foxglove panel reads, with no
hand-made schema. The bytes are written here, not by building the SDK's message objects
and calling their ``encode()``: a scene is some 50 such objects, plus a Point3 per leg
node (124 on the soft plant), and building them was most of what the scene cost a step.
Every step's message has the same layout, only its numbers change, so :class:`SceneEncoder`
lays the messages out once as protobuf wire bytes and each step writes its float64 values
into place with one compiled call (:func:`_fill_scene`). The tests decode its output and the SDK's
``encode()`` of the same scene with the SDK's schema and compare the two messages.

Topics:
- ``/scene`` (``foxglove.SceneUpdate``): entities ``torso`` (a cube), ``leg/<name>``
  (a line strip through every node, root to foot), ``force/<name>`` (an arrow, see
  :mod:`slotexp.scene` for the scale), ``feet`` (a sphere per foot), ``footholds``
  (a flat disc per planned foothold, when the controller plans them: the rigid
  quadruped). Each message replaces every entity, so any one message draws the
  whole robot.
- ``/scene/reference_path`` and ``/scene/actual_path`` (``foxglove.SceneUpdate``):
  one entity each, ``path/reference`` and ``path/actual`` (a line strip), written
  only at the steps where the path gained a point (:class:`slotexp.scene.SceneTrack`
  keeps one per 5 mm travelled, up to 500). A path is most of the scene's bytes
  (29 bytes a point, up to 14.5 kB) and changes on one step in several on a walk,
  so it has its own topic instead of being resent with every step's robot. A seek
  in Foxglove shows each topic's last message before that time, so a log needs no
  more; the live view also resends each path every ``LIVE_PATH_REFRESH_S`` (1 s)
  for a client that connects while the robot stands still.
- ``/transforms`` (``foxglove.FrameTransforms``): world -> torso, written with the pose
  (``write_pose``) by every log and live view, with or without the scene
  (:class:`TransformEncoder`).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache, lru_cache
from typing import TYPE_CHECKING

import numpy as np

from .jit import njit

if TYPE_CHECKING:
    from foxglove import Schema

    from .scene import SceneFrame

SCENE_TOPIC = "/scene"
PATH_TOPICS = {"reference": "/scene/reference_path", "actual": "/scene/actual_path"}
TRANSFORMS_TOPIC = "/transforms"
SCENE_TOPICS = (SCENE_TOPIC, *PATH_TOPICS.values())  # what write_scene writes (the transform comes with the pose)
LIVE_PATH_REFRESH_S = 1.0  # the live view resends an unchanged path this often (a client may join any time)
WORLD_FRAME = "world"
TORSO_FRAME = "torso"
LINE_THICKNESS_M = 0.003
ARROW_SHAFT_DIAMETER_M = 0.004
ARROW_HEAD_DIAMETER_M = 0.01
FOOT_DIAMETER_M = 0.012
FOOTHOLD_SIZE_M = (0.03, 0.03, 0.002)  # a flat disc on the ground

RGBA = tuple[float, float, float, float]
TORSO_COLOR: RGBA = (0.6, 0.6, 0.65, 0.8)
LEG_COLORS: tuple[RGBA, ...] = (  # FL, RL, RR, FR: the colours of the figures' legs
    (0.12, 0.47, 0.71, 1.0),
    (1.0, 0.5, 0.05, 1.0),
    (0.17, 0.63, 0.17, 1.0),
    (0.84, 0.15, 0.16, 1.0),
)
FORCE_COLOR: RGBA = (0.9, 0.1, 0.1, 1.0)
REFERENCE_COLOR: RGBA = (0.2, 0.8, 0.2, 0.9)
ACTUAL_COLOR: RGBA = (0.1, 0.3, 0.9, 0.9)
FOOT_COLOR: RGBA = (0.1, 0.1, 0.1, 1.0)
FOOTHOLD_COLOR: RGBA = (1.0, 0.8, 0.0, 0.9)

_NS_PER_S = 1_000_000_000


@cache
def schemas() -> dict[str, Schema]:
    """Each topic's ``foxglove.Schema`` (name, encoding ``protobuf``, descriptor set), from the SDK."""
    from foxglove.messages import FrameTransforms, SceneUpdate

    scene = SceneUpdate.get_schema()
    paths = {topic: scene for topic in PATH_TOPICS.values()}
    return {SCENE_TOPIC: scene, **paths, TRANSFORMS_TOPIC: FrameTransforms.get_schema()}


@lru_cache(maxsize=16)
def message_class(schema_name: str, descriptor_set: bytes) -> type:
    """The protobuf message class for ``schema_name`` (``foxglove.SceneUpdate``, ...) built from a
    descriptor set: a log's schema record (``schema.data``) or :func:`schemas`' ``data``. To decode the
    scene topics in Python; needs ``protobuf`` (in the ``test`` extras). Cached: call it per message."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    files = descriptor_pb2.FileDescriptorSet.FromString(descriptor_set).file
    pool = descriptor_pool.DescriptorPool()
    pending = list(files)
    while pending:  # add each file after the ones it imports
        added = {f.name for f in files if f not in pending}
        ready = [f for f in pending if set(f.dependency) <= added]
        if not ready:
            raise ValueError(f"the descriptor set for {schema_name} has an import cycle or a missing file")
        for f in ready:
            pool.Add(f)
            pending.remove(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def timestamp_ns(t: float) -> tuple[int, int]:
    """Seconds -> (sec, nsec) of a Foxglove Timestamp (the same nanoseconds the MCAP log time holds)."""
    ns = int(round(float(t) * _NS_PER_S))
    return ns // _NS_PER_S, ns % _NS_PER_S


# --------------------------------------------------------------------------- protobuf wire format
# https://protobuf.dev/programming-guides/encoding/: a message is its fields, each a key
# (field number << 3 | wire type) and a value; a nested message is a length-prefixed field.
# A double (wire type 1) is 8 bytes little-endian, so a message whose doubles are all
# written (a zero too, which protobuf's own encoders leave out but every decoder reads
# the same) has a fixed length whatever the numbers: the layout below relies on it.

_VARINT, _I64, _LEN = 0, 1, 2


@lru_cache(maxsize=4096)  # a run's timestamps repeat their nanoseconds every second (30 values at 30 Hz)
def _varint(n: int) -> bytes:
    n &= (1 << 64) - 1  # a negative int64 is its two's complement, ten bytes
    out = bytearray()
    while n > 0x7F:
        out.append(n & 0x7F | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def _key(number: int, wire: int) -> bytes:
    return _varint(number << 3 | wire)


@dataclass
class _Piece:
    """Encoded fields whose float64 values at ``slots`` (byte offsets, zeros until written) change each step."""

    data: bytes = b""
    slots: list[int] = field(default_factory=list)

    def __add__(self, other: _Piece) -> _Piece:
        n = len(self.data)
        return _Piece(self.data + other.data, self.slots + [n + s for s in other.slots])


def _join(pieces: Sequence[_Piece]) -> _Piece:
    out = _Piece()
    for p in pieces:
        out = out + p
    return out


def _nested(number: int, *pieces: _Piece) -> _Piece:
    """A message field: key, length, then the message's fields."""
    body = _join(pieces)
    return _Piece(_key(number, _LEN) + _varint(len(body.data))) + body


def _string(number: int, text: str) -> _Piece:
    raw = text.encode()
    return _Piece(_key(number, _LEN) + _varint(len(raw)) + raw)


def _double(number: int, value: float | None = None) -> _Piece:
    """A double field: ``value`` if given (left out when zero, as protobuf does), else a slot."""
    key = _key(number, _I64)
    if value is None:
        return _Piece(key + bytes(8), [len(key)])
    return _Piece(key + struct.pack("<d", value)) if value != 0.0 else _Piece()


def _doubles(values: Sequence[float | None]) -> _Piece:
    """Fields 1, 2, ... of a Vector3, Point3, Quaternion or Color."""
    return _join([_double(i + 1, v) for i, v in enumerate(values)])


_XYZ = _doubles((None, None, None))
_XYZW = _doubles((None, None, None, None))
_POINT = _nested(5, _XYZ)  # one of LinePrimitive.points (field 5): always 29 bytes
_POINT_ROW = np.frombuffer(_POINT.data, dtype=np.uint8)


def _pose(orientation: _Piece = _XYZW) -> _Piece:
    return _nested(1, _nested(1, _XYZ), _nested(2, orientation))


def _line(points: _Piece, color: RGBA) -> _Piece:
    """SceneEntity.lines (field 11): a line strip (type 0, left out as protobuf's default) through ``points``."""
    return _nested(11, _double(3, LINE_THICKNESS_M), points, _nested(6, _doubles(color)))


def _spheres(n: int, size: Sequence[float], color: RGBA) -> _Piece:
    """SceneEntity.spheres (field 9), upright, at ``n`` positions."""
    upright = _doubles((0.0, 0.0, 0.0, 1.0))
    sphere = _nested(9, _pose(upright), _nested(2, _doubles(size)), _nested(3, _doubles(color)))
    return _join([sphere] * n)


def _entity_body(id: str, *primitives: _Piece) -> _Piece:
    """A SceneEntity's fields after its timestamp (field 1), which each step writes in front."""
    return _join([_string(2, WORLD_FRAME), _string(3, id), *primitives])


def _stamp_field(t: float) -> bytes:
    """A Timestamp as field 1 (SceneEntity.timestamp, FrameTransform.timestamp); zeros left out."""
    sec, nsec = timestamp_ns(t)
    body = (_SECONDS + _varint(sec) if sec else b"") + (_NANOS + _varint(nsec) if nsec else b"")
    return _STAMP_KEY + _varint(len(body)) + body


_SECONDS, _NANOS, _STAMP_KEY = _key(1, _VARINT), _key(2, _VARINT), _key(1, _LEN)
_ENTITY_KEY = _key(2, _LEN)  # SceneUpdate.entities
_TRANSFORM_KEY = _key(1, _LEN)  # FrameTransforms.transforms


def _entity(stamp: bytes, body: bytes | memoryview) -> list[bytes | memoryview]:
    """SceneUpdate.entities (field 2): key, length, the timestamp field, the entity's other fields."""
    return [_ENTITY_KEY, _varint(len(stamp) + len(body)), stamp, body]


# --------------------------------------------------------------------------- the scene


@njit(cache=True)
def _scatter(buffer: np.ndarray, slots: np.ndarray, values: np.ndarray) -> None:
    """Write ``values`` (float64) into ``buffer`` (bytes) at the byte offsets ``slots``, one each."""
    if values.shape[0] != slots.shape[0]:
        raise ValueError("the numbers do not match the message's layout")
    raw = values.view(np.uint8)
    for i in range(slots.shape[0]):
        for b in range(8):
            buffer[slots[i] + b] = raw[8 * i + b]


class _Template:
    """Encoded fields in one writable buffer; :meth:`fill` writes a step's float64 values into the slots."""

    def __init__(self, piece: _Piece) -> None:
        self.buffer = np.frombuffer(bytearray(piece.data), dtype=np.uint8)
        self.slots = np.array(piece.slots, dtype=np.intp)

    def fill(self, values: np.ndarray) -> None:
        """Write this step's numbers (float64, in the slots' order) into place."""
        _scatter(self.buffer, self.slots, values)


class TransformEncoder:
    """The torso's pose as a ``foxglove.FrameTransforms`` message holding one transform, parent -> child."""

    def __init__(self) -> None:
        self._bodies: dict[tuple[str, str], tuple[_Template, memoryview]] = {}

    def message(
        self,
        t: float,
        position: np.ndarray,
        quaternion_wxyz: np.ndarray,
        parent: str = WORLD_FRAME,
        child: str = TORSO_FRAME,
    ) -> bytes:
        """The message at ``t``: ``position`` (3,) and ``quaternion_wxyz`` (4,), float arrays."""
        body = self._bodies.get((parent, child))
        if body is None:
            fields = _join([_string(2, parent), _string(3, child), _nested(4, _XYZ), _nested(5, _XYZW)])
            template = _Template(fields)
            body = self._bodies[(parent, child)] = (template, memoryview(template.buffer))  # type: ignore[arg-type]
        template, view = body
        q = quaternion_wxyz
        template.fill(np.concatenate((position, q[1:4], q[:1]), dtype="<f8"))  # Foxglove's x, y, z, w
        stamp = _stamp_field(t)
        return b"".join((_TRANSFORM_KEY, _varint(len(stamp) + len(view)), stamp, view))


_NO_POINTS = np.empty((0, 3))  # the footholds of a controller that plans none


@njit(cache=True)
def _put_rows(values: np.ndarray, k: int, rows: np.ndarray) -> int:
    """Copy ``rows`` (n, m) into ``values`` from ``k`` on, row by row; the index after them."""
    for i in range(rows.shape[0]):
        for a in range(rows.shape[1]):
            values[k] = rows[i, a]
            k += 1
    return k


@njit(cache=True)
def _fill_scene(
    buffer: np.ndarray,
    slots: np.ndarray,
    position: np.ndarray,
    quaternion_wxyz: np.ndarray,
    torso_size: np.ndarray,
    legs: np.ndarray,
    arrows: np.ndarray,
    feet: np.ndarray,
    footholds: np.ndarray,
) -> None:
    """Write a step's numbers as float64 into ``buffer`` at the byte offsets ``slots``, in :class:`_Layout`'s
    order. Compiled: gathering the arrays and scattering their bytes was most of a step's encoding."""
    if 10 + legs.size + arrows.size + feet.size + footholds.size != slots.shape[0]:
        raise ValueError("the scene's arrays do not match its layout")
    values = np.empty(slots.shape[0])
    values[0:3] = position
    values[3:6] = quaternion_wxyz[1:4]  # Foxglove's x, y, z, w
    values[6] = quaternion_wxyz[0]
    values[7:10] = torso_size
    k = 10
    for i in range(legs.shape[0]):
        k = _put_rows(values, k, legs[i])
    k = _put_rows(values, k, arrows)
    k = _put_rows(values, k, feet)
    _put_rows(values, k, footholds)
    _scatter(buffer, slots, values)


class _Layout:
    """One run's ``/scene`` in one buffer: every entity's fields after its timestamp. Each step writes all
    their numbers (:func:`_fill_scene`) in the order laid out: the torso's pose and size, the legs' nodes,
    each arrow (tail, orientation, shaft and head length), the feet, the footholds. Only the timestamp's
    length changes the message's length, and so the entities' headers."""

    def __init__(self, leg_names: tuple[str, ...], n_nodes: int, footholds: bool) -> None:
        self.key = (leg_names, n_nodes, footholds)
        torso = _nested(8, _pose(), _nested(2, _XYZ), _nested(3, _doubles(TORSO_COLOR)))
        legs = [_line(_join([_POINT] * n_nodes), LEG_COLORS[i % len(LEG_COLORS)]) for i in range(len(leg_names))]
        arrow = _nested(
            7,
            _pose(),
            _double(2),  # shaft_length
            _double(3, ARROW_SHAFT_DIAMETER_M),
            _double(4),  # head_length
            _double(5, ARROW_HEAD_DIAMETER_M),
            _nested(6, _doubles(FORCE_COLOR)),
        )
        n = len(leg_names)
        bodies = [_entity_body("torso", torso)]
        bodies += [_entity_body(f"leg/{name}", line) for name, line in zip(leg_names, legs)]
        bodies += [_entity_body(f"force/{name}", arrow) for name in leg_names]
        bodies.append(_entity_body("feet", _spheres(n, (FOOT_DIAMETER_M,) * 3, FOOT_COLOR)))
        if footholds:
            bodies.append(_entity_body("footholds", _spheres(n, FOOTHOLD_SIZE_M, FOOTHOLD_COLOR)))
        template = _Template(_join(bodies))
        self.buffer, self.slots = template.buffer, template.slots
        view = memoryview(self.buffer)  # type: ignore[arg-type]
        ends = np.cumsum([len(b.data) for b in bodies]).tolist()
        self._bodies = [view[a:b] for a, b in zip([0, *ends], ends)]  # they follow the buffer's numbers
        self._parts: list[bytes | memoryview] = []

    def entities(self, stamp: bytes) -> list[bytes | memoryview]:
        """The fixed entities as SceneUpdate fields, stamped, with the numbers last written."""
        if not self._parts or len(self._parts[2]) != len(stamp):  # a new timestamp length: new headers
            self._parts = [part for body in self._bodies for part in _entity(stamp, body)]
        else:
            self._parts[2::4] = [stamp] * len(self._bodies)
        return self._parts


class _PathMessage:
    """A path's message (a SceneUpdate of one entity), made only when the path gained a point
    (:class:`slotexp.scene.SceneTrack` returns the same array until then) or, with ``refresh_s``,
    once that much frame time has passed since it was last made. The points' bytes are written
    into rows kept from one message to the next (their keys and lengths already in place)."""

    def __init__(self, key: str, color: RGBA, refresh_s: float | None) -> None:
        self.topic = PATH_TOPICS[key]
        self._refresh_s = refresh_s
        self._made_at = 0.0
        self._head = _entity_body(f"path/{key}").data + _key(11, _LEN)
        self._thickness = _double(3, LINE_THICKNESS_M).data
        self._color = _nested(6, _doubles(color)).data
        self._source: np.ndarray | None = None
        self._rows = np.empty((0, len(_POINT_ROW)), dtype=np.uint8)
        self._xyz = np.empty((0, 3))

    def _points(self, path: np.ndarray) -> bytes:
        """LinePrimitive.points (field 5) through ``path`` (k, 3)."""
        n = len(path)
        if n > len(self._rows):
            self._rows = np.tile(_POINT_ROW, (max(n, 2 * len(self._rows)), 1))
            shape, strides = (len(self._rows), 3), (len(_POINT_ROW), 9)
            self._xyz = np.ndarray(shape, dtype="<f8", buffer=self._rows, offset=_POINT.slots[0], strides=strides)
        self._xyz[:n] = path
        return self._rows[:n].tobytes()

    def message(self, path: np.ndarray, t: float, stamp: bytes) -> bytes | None:
        """The path's SceneUpdate at ``t``, or None where the last one made still shows it."""
        fresh = self._refresh_s is None or abs(t - self._made_at) < self._refresh_s
        if path is self._source and fresh:
            return None
        points = self._points(path)
        line = _varint(len(self._thickness) + len(points) + len(self._color))
        body = b"".join((self._head, line, self._thickness, points, self._color))
        self._source, self._made_at = path, t
        return b"".join(_entity(stamp, body))


class SceneEncoder:
    """Turns a run's frames, one step after another, into (topic, encoded message) pairs: ``/scene``, then
    each path whose message is due (it changed; with ``path_refresh_s``, the live
    view's, also that long after it was last sent). :func:`schemas` gives each topic's schema."""

    def __init__(self, path_refresh_s: float | None = None) -> None:
        self._layout: _Layout | None = None
        self._paths = (
            _PathMessage("reference", REFERENCE_COLOR, path_refresh_s),
            _PathMessage("actual", ACTUAL_COLOR, path_refresh_s),
        )

    def messages(self, frame: SceneFrame) -> list[tuple[str, bytes]]:
        """(topic, protobuf bytes) of one step's scene, in the order they are written."""
        key = (frame.leg_names, frame.legs.shape[1], frame.footholds is not None)
        layout = self._layout
        if layout is None or layout.key != key:
            layout = self._layout = _Layout(*key)
        holds = _NO_POINTS if frame.footholds is None else frame.footholds
        _fill_scene(
            layout.buffer,
            layout.slots,
            frame.position if frame.box_centre is None else frame.box_centre,
            frame.quaternion_wxyz,
            frame.torso_size,
            frame.legs,
            frame.arrows,
            frame.feet,
            holds,
        )
        stamp = _stamp_field(frame.t)
        out = [(SCENE_TOPIC, b"".join(layout.entities(stamp)))]
        for encoder, path in zip(self._paths, (frame.reference_path, frame.actual_path)):
            data = encoder.message(path, frame.t, stamp)
            if data is not None:
                out.append((encoder.topic, data))
        return out


__all__ = [
    "SCENE_TOPIC",
    "PATH_TOPICS",
    "TRANSFORMS_TOPIC",
    "LIVE_PATH_REFRESH_S",
    "SCENE_TOPICS",
    "SceneEncoder",
    "TransformEncoder",
    "message_class",
    "schemas",
    "timestamp_ns",
]
