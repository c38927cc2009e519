"""A :class:`~slotexp.scene.SceneFrame` as Foxglove's own message types, in the schemas of ``foxglove-sdk``.

The schemas are the SDK's (``SceneUpdate.get_schema()``: Foxglove's protobuf descriptor
set), so the log and the live server carry messages every Foxglove panel reads, with no
hand-made schema. The bytes are written here, not by building the SDK's message objects
and calling their ``encode()``: a scene is some 50 such objects, plus a Point3 per leg
node (124 on the soft plant), and building them was most of what the scene cost a step.
Every step's message has the same layout, only its numbers change, so :class:`SceneEncoder`
lays the messages out once as protobuf wire bytes and each step writes its float64 values
into place with one numpy assignment. The tests decode its output and the SDK's
``encode()`` of the same scene with the SDK's schema and compare the two messages.

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

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache, lru_cache
from typing import TYPE_CHECKING

import numpy as np

from .scene import SceneFrame

if TYPE_CHECKING:
    from foxglove import Schema

SCENE_TOPIC = "/scene"
TRANSFORMS_TOPIC = "/transforms"
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

    return {SCENE_TOPIC: SceneUpdate.get_schema(), TRANSFORMS_TOPIC: FrameTransforms.get_schema()}


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


class _Layout:
    """One run's fixed messages in one buffer: every entity but the paths (each entity's fields after its
    timestamp), then the one FrameTransform's. Each step writes all their numbers with one numpy
    assignment, in the order laid out: the torso's pose and size, the legs' nodes, each arrow (tail,
    orientation, shaft and head length), the feet, the footholds, the transform's pose. Only the
    timestamps' lengths change a message's length, and so its header."""

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
        transform = _join([_string(2, WORLD_FRAME), _string(3, TORSO_FRAME), _nested(4, _XYZ), _nested(5, _XYZW)])
        whole = _join([*bodies, transform])
        self._buffer = np.frombuffer(bytearray(whole.data), dtype=np.uint8)
        self._value_bytes = (np.array(whole.slots, dtype=np.intp)[:, None] + np.arange(8)).ravel()
        view = memoryview(self._buffer)  # type: ignore[arg-type]
        ends = np.cumsum([len(b.data) for b in (*bodies, transform)]).tolist()
        spans = [view[a:b] for a, b in zip([0, *ends], ends)]  # they follow the buffer's numbers
        self._bodies, self.transform = spans[:-1], spans[-1]
        self._parts: list[bytes | memoryview] = []

    def fill(self, values: np.ndarray) -> None:
        """Write this step's numbers (float64, in the layout's order) into place."""
        self._buffer[self._value_bytes] = values.view(np.uint8)

    def entities(self, stamp: bytes) -> list[bytes | memoryview]:
        """The fixed entities as SceneUpdate fields, stamped, with the numbers last written."""
        if not self._parts or len(self._parts[2]) != len(stamp):  # a new timestamp length: new headers
            self._parts = [part for body in self._bodies for part in _entity(stamp, body)]
        else:
            self._parts[2::4] = [stamp] * len(self._bodies)
        return self._parts


class _PathEntity:
    """A path's entity, rebuilt only when the path gained a point (:class:`slotexp.scene.SceneTrack`
    returns the same array until then): it keeps the timestamp of the step it changed. On a walk
    that is every other step, so the points' bytes are written into rows kept from one rebuild to
    the next (their keys and lengths already in place)."""

    def __init__(self, key: str, color: RGBA) -> None:
        self._head = _entity_body(f"path/{key}").data + _key(11, _LEN)
        self._thickness = _double(3, LINE_THICKNESS_M).data
        self._color = _nested(6, _doubles(color)).data
        self._source: np.ndarray | None = None
        self._rows = np.empty((0, len(_POINT_ROW)), dtype=np.uint8)
        self._xyz = np.empty((0, 3))
        self.parts: list[bytes | memoryview] = []

    def _points(self, path: np.ndarray) -> bytes:
        """LinePrimitive.points (field 5) through ``path`` (k, 3)."""
        n = len(path)
        if n > len(self._rows):
            self._rows = np.tile(_POINT_ROW, (max(n, 2 * len(self._rows)), 1))
            shape, strides = (len(self._rows), 3), (len(_POINT_ROW), 9)
            self._xyz = np.ndarray(shape, dtype="<f8", buffer=self._rows, offset=_POINT.slots[0], strides=strides)
        self._xyz[:n] = path
        return self._rows[:n].tobytes()

    def update(self, path: np.ndarray, stamp: bytes) -> list[bytes | memoryview]:
        if path is not self._source:
            points = self._points(path)
            line = _varint(len(self._thickness) + len(points) + len(self._color))
            body = b"".join((self._head, line, self._thickness, points, self._color))
            self.parts = _entity(stamp, body)
            self._source = path
        return self.parts


class SceneEncoder:
    """Turns a run's frames, one step after another, into (topic, encoded message) pairs, ``/transforms``
    first; :func:`schemas` gives each topic's schema."""

    def __init__(self) -> None:
        self._layout: _Layout | None = None
        self._paths = (_PathEntity("reference", REFERENCE_COLOR), _PathEntity("actual", ACTUAL_COLOR))

    def messages(self, frame: SceneFrame) -> list[tuple[str, bytes]]:
        """(topic, protobuf bytes) of one step's scene, in the order they are written."""
        key = (frame.leg_names, frame.legs.shape[1], frame.footholds is not None)
        layout = self._layout
        if layout is None or layout.key != key:
            layout = self._layout = _Layout(*key)
        q = frame.quaternion_wxyz
        pose = (frame.position, q[1:4], q[:1])  # x, y, z, then the quaternion as x, y, z, w
        holds = () if frame.footholds is None else (frame.footholds,)
        values = (*pose, frame.torso_size, frame.legs, frame.arrows, frame.feet, *holds, *pose)
        layout.fill(np.concatenate(values, axis=None, dtype="<f8"))  # each array flattened, row by row
        stamp = _stamp_field(frame.t)
        parts = [*layout.entities(stamp), *self._paths[0].update(frame.reference_path, stamp)]
        parts += self._paths[1].update(frame.actual_path, stamp)
        transform = (_TRANSFORM_KEY, _varint(len(stamp) + len(layout.transform)), stamp, layout.transform)
        return [(TRANSFORMS_TOPIC, b"".join(transform)), (SCENE_TOPIC, b"".join(parts))]


__all__ = ["SCENE_TOPIC", "TRANSFORMS_TOPIC", "SceneEncoder", "schemas", "timestamp_ns"]
