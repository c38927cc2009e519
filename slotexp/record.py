"""MCAP run logs: one MCAP file per simulation run.

Files are written so that Foxglove can open them directly: the numeric topics are
JSON messages with ``jsonschema`` schemas (plus the well-known ``foxglove.PoseInFrame``
schema for the torso pose, which the figures read); the torso's transform
(``/transforms``, with the pose) and the 3D scene (:meth:`Recorder.write_scene`) are
Foxglove's own ``FrameTransforms`` and ``SceneUpdate``, protobuf-encoded in the schemas
``foxglove-sdk`` ships (:mod:`slotexp.foxglove_scene`).
A run that is killed part-way still leaves a readable file: data goes out in small
chunks and the file object is flushed whenever the writer emits bytes, so everything
but the last partial chunk survives a SIGKILL.

Reading (:func:`read_log`) turns each JSON topic into a :class:`pandas.DataFrame`
with a ``t`` column (seconds) followed by the flattened message fields; the
protobuf scene topics are for viewers and are skipped (listed in ``Log.scene_topics``).
"""

from __future__ import annotations

import io
import json
import math
import os
import re
import struct
from collections.abc import Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Any

import numpy as np
import orjson
import pandas as pd
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from .errors import LogReadError
from .foxglove_scene import TRANSFORMS_TOPIC, SceneEncoder, TransformEncoder, schemas
from .telemetry import POSE

__all__ = [
    "LogReadError",
    "Log",
    "Recorder",
    "flatten",
    "read_log",
]


_MAGIC = b"\x89MCAP0\r\n"
_NS_PER_S = 1_000_000_000
_MESSAGE_ENCODING = "json"
_SCHEMA_ENCODING = "jsonschema"
_BINARY_ENCODING = "protobuf"  # foxglove-sdk's messages (the scene, the transform): not tabular, skipped by read_log
_RESERVED_FIELD = "t"  # the DataFrame's log-time column


# --------------------------------------------------------------------------- encoding


def _to_json(value: Any, where: str) -> Any:
    """Convert a message value to plain JSON types; non-finite floats become null.

    JSON has no NaN/Inf, and numpy scalars/arrays are not JSON-serialisable, so
    both are normalised here once instead of relying on ``json`` defaults.
    """
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        f = float(value)
        return f if math.isfinite(f) else None
    if isinstance(value, np.ndarray):
        if value.dtype.kind in "iub":  # ints and bools: tolist() gives plain ints and bools
            return value.tolist()
        if value.dtype.kind == "f":  # the bulk of every log: one pass, not one call per number
            finite = np.isfinite(value)
            if finite.all():
                return value.tolist()
            masked = value.astype(object)
            masked[~finite] = None
            return masked.tolist()
        return _to_json(value.tolist(), where)
    if isinstance(value, Mapping):
        return {str(k): _to_json(v, f"{where}.{k}") for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_to_json(v, f"{where}.{i}") for i, v in enumerate(value)]
    if isinstance(value, np.generic):
        return _to_json(value.item(), where)
    raise TypeError(f"field {where!r}: unsupported type {type(value).__name__} in a log message")


def _schema_for(value: Any) -> dict[str, Any]:
    """JSON schema fragment for an already JSON-normalised value."""
    if isinstance(value, bool):
        return {"type": "boolean"}
    if isinstance(value, (int, float)) or value is None:
        # None only arises from non-finite floats (or explicit None), so the
        # field is numeric; readers map null back to NaN.
        return {"type": "number"}
    if isinstance(value, str):
        return {"type": "string"}
    if isinstance(value, list):
        schema: dict[str, Any] = {"type": "array"}
        if value:
            schema["items"] = _schema_for(value[0])
        return schema
    if isinstance(value, dict):
        return {
            "type": "object",
            "properties": {k: _schema_for(v) for k, v in value.items()},
        }
    raise TypeError(f"unsupported JSON value {value!r}")  # pragma: no cover - guarded by _to_json


def _schema_name(topic: str) -> str:
    """Topic-derived schema name, e.g. ``/state`` -> ``slotexp.state``."""
    parts = [re.sub(r"[^0-9A-Za-z_]", "_", p) for p in topic.strip("/").split("/") if p]
    return "slotexp." + (".".join(parts) if parts else "root")


def _time_ns(t: float) -> int:
    """Simulation time in seconds -> integer nanoseconds (MCAP timestamps are uint64)."""
    tf = float(t)
    if not math.isfinite(tf) or tf < 0:
        raise ValueError(f"log time must be a finite float >= 0 seconds, got {t!r}")
    return int(round(tf * _NS_PER_S))


def _dumps(obj: Any) -> bytes:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode("utf-8")


_ORJSON_OPTIONS = orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_NON_STR_KEYS


def _encode(message: Mapping[str, Any], where: str) -> bytes:
    """A message as JSON bytes: orjson writes numpy arrays and scalars itself and non-finite floats as
    null, the same JSON :func:`_to_json` makes, several times faster; what it refuses (a
    non-contiguous array, an unsupported type) goes through :func:`_to_json`, which converts
    it or names the field it cannot log."""
    try:
        return orjson.dumps(message, option=_ORJSON_OPTIONS)
    except TypeError:
        return _dumps(_to_json(message, where))


_TIME_SCHEMA: dict[str, Any] = {
    "type": "object",
    "title": "time",
    "properties": {
        "sec": {"type": "integer", "minimum": 0},
        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
    },
}
_VECTOR3_SCHEMA: dict[str, Any] = {
    "title": "foxglove.Vector3",
    "type": "object",
    "properties": {k: {"type": "number"} for k in ("x", "y", "z")},
}
_QUATERNION_SCHEMA: dict[str, Any] = {
    "title": "foxglove.Quaternion",
    "type": "object",
    "properties": {k: {"type": "number"} for k in ("x", "y", "z", "w")},
}

POSE_IN_FRAME_SCHEMA: dict[str, Any] = {
    "title": "foxglove.PoseInFrame",
    "description": "A timestamped pose for an object or reference frame in 3D space",
    "type": "object",
    "properties": {
        "timestamp": {**_TIME_SCHEMA, "description": "Timestamp of pose"},
        "frame_id": {"type": "string", "description": "Frame of reference for pose"},
        "pose": {
            "title": "foxglove.Pose",
            "type": "object",
            "properties": {
                "position": {**_VECTOR3_SCHEMA, "description": "Position in 3D space"},
                "orientation": {**_QUATERNION_SCHEMA, "description": "Orientation"},
            },
        },
    },
}

# --------------------------------------------------------------------------- writing


def pose_message(
    t: float, position: Sequence[float], quaternion_wxyz: Sequence[float], frame_id: str = "world"
) -> tuple[dict[str, Any], np.ndarray, np.ndarray]:
    """The torso pose as a ``foxglove.PoseInFrame`` payload (the quaternion (w, x, y, z) in, Foxglove's
    x, y, z, w out; for :func:`_encode`, which writes a non-finite number as null), and the checked
    position (3,) and quaternion (4,) as float arrays (the transform's).

    Foxglove's 3D panel draws a pose marker from it, and builds its frame tree from the
    ``/transforms`` written beside it. Shared by the log and the live view.
    """
    p = np.asarray(position, dtype=float).ravel()
    q = np.asarray(quaternion_wxyz, dtype=float).ravel()
    if len(p) != 3:
        raise ValueError(f"position must have 3 elements, got {len(p)}")
    if len(q) != 4:
        raise ValueError(f"quaternion_wxyz must have 4 elements, got {len(q)}")
    log_time = _time_ns(t)
    x, y, z = p.tolist()
    w, qx, qy, qz = q.tolist()
    pose = {
        "timestamp": {"sec": log_time // _NS_PER_S, "nsec": log_time % _NS_PER_S},
        "frame_id": frame_id,
        "pose": {
            "position": {"x": x, "y": y, "z": z},
            "orientation": {"x": qx, "y": qy, "z": qz, "w": w},
        },
    }
    return pose, p, q


class _FlushingFile:
    """File wrapper that flushes after every write.

    ``mcap.Writer`` only calls ``write`` when it emits a whole chunk (plus its
    message index), a metadata record, the header or the summary, so flushing
    each write puts every finished chunk on disk at negligible cost.  It is not
    an ``io.RawIOBase`` on purpose: the writer would wrap that in its own buffer.
    """

    def __init__(self, raw: IO[bytes]) -> None:
        self._raw = raw

    def write(self, data: bytes) -> int:
        n = self._raw.write(data)
        self._raw.flush()
        return n

    def tell(self) -> int:
        return self._raw.tell()

    def flush(self) -> None:
        self._raw.flush()

    def close(self) -> None:
        self._raw.close()


@dataclass
class _Chan:
    id: int
    sequence: int = 0


class Recorder:
    """Context manager. Writes one MCAP file; channels are registered on first write."""

    def __init__(
        self,
        path: str | Path,
        metadata: Mapping[str, Mapping[str, str]] | None = None,
        *,
        # A SIGKILL loses at most the open chunk: with the 3D scene (12-22 kB a step) up to 0.8 s of an
        # ideal-plant run, 0.3 s of a soft-plant one. Each chunk's compression also sets up a zstd context:
        # at 48 KiB (a chunk every 2-4 steps) writing the scene cost the loop as much as building it.
        chunk_size: int = 192 * 1024,
        profile: str = "slotexp",
    ) -> None:
        self.path = Path(path)
        self._file: IO[bytes] = open(self.path, "wb")
        self._closed = False
        self._channels: dict[str, _Chan] = {}
        self._scene = SceneEncoder()
        self._transforms = TransformEncoder()
        try:
            self._writer = Writer(
                _FlushingFile(self._file),  # type: ignore[arg-type]
                chunk_size=int(chunk_size),
                compression=CompressionType.ZSTD,
            )
            self._writer.start(profile=profile)
            for name, data in (metadata or {}).items():
                self.add_metadata(name, data)
        except BaseException:
            self._file.close()
            self._closed = True
            raise

    # -- channels -----------------------------------------------------------
    def _channel(self, topic: str, schema_name: str, schema: Mapping[str, Any]) -> _Chan:
        chan = self._channels.get(topic)
        if chan is None:
            schema_id = self._writer.register_schema(name=schema_name, encoding=_SCHEMA_ENCODING, data=_dumps(schema))
            cid = self._writer.register_channel(topic=topic, message_encoding=_MESSAGE_ENCODING, schema_id=schema_id)
            chan = self._channels[topic] = _Chan(cid)
        return chan

    def _emit(self, chan: _Chan, log_time: int, data: bytes) -> None:
        self._writer.add_message(
            channel_id=chan.id,
            log_time=log_time,
            publish_time=log_time,
            data=data,
            sequence=chan.sequence,
        )
        chan.sequence = (chan.sequence + 1) & 0xFFFFFFFF

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f"Recorder for {self.path} is closed")

    # -- public API -----------------------------------------------------------
    def write(self, topic: str, t: float, message: Mapping[str, Any]) -> None:
        """Log ``message`` on ``topic`` at simulation time ``t`` (seconds).

        The first message on a topic fixes the topic's JSON schema; field ``t``
        is reserved because the reader puts the log time in column ``t``.
        """
        self._check_open()
        if not isinstance(topic, str) or not topic:
            raise ValueError(f"topic must be a non-empty string, got {topic!r}")
        if not isinstance(message, Mapping):
            raise TypeError(f"message must be a mapping, got {type(message).__name__}")
        if _RESERVED_FIELD in message:
            raise ValueError(f"message field {_RESERVED_FIELD!r} on {topic} is reserved for the log time column")
        log_time = _time_ns(t)
        chan = self._channels.get(topic)
        if chan is None:  # the first message fixes the schema (and is checked field by field)
            chan = self._channel(topic, _schema_name(topic), _schema_for(_to_json(message, topic)))
        self._emit(chan, log_time, _encode(message, topic))

    def write_pose(
        self,
        t: float,
        position: Sequence[float],
        quaternion_wxyz: Sequence[float],
        *,
        frame_id: str = "world",
        child_frame_id: str = "torso",
    ) -> None:
        """Log the torso pose: ``/torso/pose`` (Foxglove ``PoseInFrame``, JSON, read by the figures) and
        ``/transforms`` (``FrameTransforms``, protobuf: the frame tree of Foxglove's 3D panel)."""
        self._check_open()
        pose, p, q = pose_message(t, position, quaternion_wxyz, frame_id)
        chan = self._channel(POSE, "foxglove.PoseInFrame", POSE_IN_FRAME_SCHEMA)
        self._emit(chan, _time_ns(t), _encode(pose, POSE))
        self.write_encoded(TRANSFORMS_TOPIC, t, self._transforms.message(t, p, q, frame_id, child_frame_id))

    def write_encoded(self, topic: str, t: float, data: bytes) -> None:
        """Log a protobuf message on one of :func:`slotexp.foxglove_scene.schemas`' topics, in its schema.

        The schema record is the SDK's own (name, encoding and descriptor), so a viewer
        decodes it exactly as the SDK's MCAP writer would have it.
        """
        self._check_open()
        chan = self._channels.get(topic)
        if chan is None:
            schema = schemas()[topic]
            schema_id = self._writer.register_schema(name=schema.name, encoding=schema.encoding, data=schema.data)
            cid = self._writer.register_channel(topic=topic, message_encoding=schema.encoding, schema_id=schema_id)
            chan = self._channels[topic] = _Chan(cid)
        self._emit(chan, _time_ns(t), data)

    def write_scene(self, frame: Any) -> None:
        """Log one step's 3D scene (a :class:`slotexp.scene.SceneFrame`) as Foxglove messages."""
        for topic, data in self._scene.messages(frame):
            self.write_encoded(topic, frame.t, data)

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Write an MCAP Metadata record (written immediately, so it survives a crash)."""
        self._check_open()
        bad = {k: type(v).__name__ for k, v in data.items() if not isinstance(k, str) or not isinstance(v, str)}
        if bad:
            raise TypeError(f"metadata {name!r}: keys and values must be str, got {bad}")
        self._writer.add_metadata(name, dict(data))

    def close(self) -> None:
        """Write the summary and footer and close the file; safe to call twice."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.finish()
        finally:
            self._file.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


# --------------------------------------------------------------------------- reading


_SCALARS = frozenset({int, float, bool, str, type(None)})  # what JSON decodes a leaf to


def flatten(message: Mapping[str, Any]) -> dict[str, Any]:
    """Flatten nested dicts/lists into ``a.b.0``-style keys (one DataFrame column each).

    A list of plain scalars (most of a log: a leg's node, a force) becomes its columns in one
    comprehension; the type checks are by exact type first, since an ABC check per value was
    most of the time spent reading a log back."""
    out: dict[str, Any] = {}

    def walk(prefix: str, value: Any) -> None:
        kind = type(value)
        if kind is dict or (kind not in _SCALARS and isinstance(value, Mapping)):
            for k, v in value.items():
                walk(f"{prefix}.{k}" if prefix else str(k), v)
        elif kind is list or kind is tuple or isinstance(value, (list, tuple, np.ndarray)):
            lead = f"{prefix}." if prefix else ""
            if all(type(v) in _SCALARS for v in value):
                out.update({f"{lead}{i}": v for i, v in enumerate(value)})
            else:
                for i, v in enumerate(value):
                    walk(f"{lead}{i}", v)
        else:
            out[prefix] = value

    walk("", message)
    return out


@dataclass
class Log:
    """Decoded run log: one DataFrame per topic plus the file's metadata records.

    ``truncated`` is True when the file had no valid summary/footer (e.g. the
    run was killed) and was recovered by streaming up to the first broken
    record, i.e. the tail of the run may be missing.
    """

    topics: dict[str, pd.DataFrame]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    truncated: bool = False
    scene_topics: tuple[str, ...] = ()  # protobuf (Foxglove scene) topics present but not tabulated

    def __getitem__(self, topic: str) -> pd.DataFrame:
        try:
            return self.topics[topic]
        except KeyError:
            raise KeyError(f"topic {topic!r} not in log; available topics: {sorted(self.topics)}") from None

    def __contains__(self, topic: object) -> bool:
        return topic in self.topics


# (topic, message_encoding, log_time, data) as collected from either read path
_Raw = tuple[str, str, int, bytes]


def _indexed_reader(f: IO[bytes], size: int) -> Any:
    """An mcap reader of a closed file (footer and summary in place); raises otherwise."""
    if size < len(_MAGIC) * 2:
        raise ValueError("file too short for a footer")
    f.seek(size - len(_MAGIC))
    if f.read(len(_MAGIC)) != _MAGIC:
        raise ValueError("no trailing magic")
    f.seek(0)
    reader = make_reader(f, validate_crcs=True)
    if reader.get_summary() is None:
        raise ValueError("no summary section")
    return reader


def is_closed(path: str | Path) -> bool:
    """Whether the log at ``path`` was closed (its footer and summary written), without reading its
    messages: a log cut off by a kill is not, and :func:`read_log` reports it ``truncated``."""
    try:
        with open(path, "rb") as f:
            _indexed_reader(f, os.fstat(f.fileno()).st_size)
    except Exception:  # noqa: BLE001 - any failure to find the summary means not closed
        return False
    return True


def _read_indexed(
    f: IO[bytes], size: int, topics: Collection[str] | None
) -> tuple[list[_Raw], dict[str, dict[str, str]]]:
    """Read through the summary index (only ``topics``' messages, when given: the index skips the chunks
    that hold none of them); raises if the file has no valid footer/summary."""
    reader = _indexed_reader(f, size)
    channels = reader.get_summary().channels.values()
    binary = {c.topic for c in channels if c.message_encoding == _BINARY_ENCODING}
    wanted = sorted({c.topic for c in channels if topics is None or c.topic in topics} - binary)
    raw: list[_Raw] = [(topic, _BINARY_ENCODING, 0, b"") for topic in sorted(binary)]  # named, not decoded
    raw += [
        (channel.topic, channel.message_encoding, message.log_time, message.data)
        for _schema, channel, message in reader.iter_messages(topics=wanted, log_time_order=True)
    ]
    metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return raw, metadata


def _complete_prefix(data: bytes) -> tuple[int, bool]:
    """Length of the longest prefix made of whole top-level records, and whether
    that prefix ends with a Footer followed by the closing magic (a finished file).

    ``mcap``'s ReadDataStream silently returns short reads, so a record cut
    off by a crash could otherwise be parsed with garbage; checking each
    record's declared length against the bytes present avoids that.
    """
    pos = len(_MAGIC)
    n = len(data)
    while pos + 9 <= n:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        end = pos + 9 + length
        if end > n:
            break
        pos = end
        if opcode == Opcode.FOOTER:
            if data[pos : pos + len(_MAGIC)] == _MAGIC:
                return pos + len(_MAGIC), True
            return pos, False
    return pos, False


def _iter_stream(data: bytes, finished: bool) -> Iterator[Any]:
    """Records from the complete prefix, stopping quietly at the first bad one."""
    reader = StreamReader(io.BytesIO(data), validate_crcs=True)
    records = reader.records
    while True:
        try:
            rec = next(records)
        except StopIteration:
            return
        except Exception:  # truncated/corrupt record (EndOfFile, CRC, zstd): keep what we have
            return
        if isinstance(rec, Footer) and not finished:
            return  # StreamReader would demand the closing magic next
        yield rec


def _read_streaming(data: bytes) -> tuple[list[_Raw], dict[str, dict[str, str]], bool]:
    """Linear read for files without a usable index.

    Returns (raw messages, metadata, complete) where complete means every
    record up to the footer and closing magic was read without error.
    """
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    raw: list[_Raw] = []
    metadata: dict[str, dict[str, str]] = {}
    prefix, finished = _complete_prefix(data)
    complete = False
    for rec in _iter_stream(data[:prefix], finished):
        if isinstance(rec, Schema):
            schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            channels[rec.id] = rec
        elif isinstance(rec, Message):
            chan = channels.get(rec.channel_id)
            if chan is None:  # corrupt: message before its channel
                break
            raw.append((chan.topic, chan.message_encoding, rec.log_time, rec.data))
        elif isinstance(rec, Metadata):
            metadata[rec.name] = dict(rec.metadata)
        elif isinstance(rec, Footer):
            complete = finished
    raw.sort(key=lambda r: r[2])  # stable: ties keep file order, like the indexed reader
    return raw, metadata, complete


def _column(values: list[Any]) -> Any:
    """Numeric -> float64 (null -> NaN); all-bool -> bool; anything else object.

    Decided on the set of the values' types (JSON gives exactly bool, int, float, str,
    None, list or dict), which is one pass in C instead of a check per value."""
    kinds = set(map(type, values))
    if kinds == {bool}:
        return np.array(values, dtype=bool)
    if bool in kinds and kinds <= {bool, type(None)}:
        return np.array(values, dtype=object)
    if kinds and kinds <= {int, float, type(None)}:
        return np.array(values, dtype=np.float64)  # numpy reads None as NaN
    if not kinds - {type(None)}:  # no value present at all
        return np.array([np.nan] * len(values), dtype=np.float64)
    return np.array(values, dtype=object)


def _frame(rows: list[tuple[int, dict[str, Any]]]) -> pd.DataFrame:
    columns: dict[str, None] = {}
    for _, flat in rows:
        for k in flat:
            columns.setdefault(k, None)
    data: dict[str, Any] = {"t": np.array([lt for lt, _ in rows], dtype=np.int64) / _NS_PER_S}
    for col in columns:
        arr = _column([flat.get(col) for _, flat in rows])
        # explicit dtype: pandas >= 3 would otherwise infer its "str" dtype for strings
        # a foreign file's message field "t" must not clobber the log-time column
        data["msg.t" if col == "t" else col] = pd.Series(arr, dtype=arr.dtype)
    return pd.DataFrame(data)


def read_log(path: str | Path, topics: Collection[str] | None = None) -> Log:
    """Read a run log written by :class:`Recorder` (or any JSON-encoded MCAP file); protobuf topics
    (the 3D scene, for viewers) are named in ``scene_topics`` but not decoded. With ``topics``
    only those are decoded (a table that needs the state need not decode the legs' shapes).

    Uses the summary index when the file is complete; otherwise (interrupted
    run) streams records up to the first truncated/corrupt one and sets
    ``truncated=True`` so callers know the tail of the run is missing.
    """
    p = Path(path)
    try:
        with open(p, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            head = f.read(len(_MAGIC))
            if head != _MAGIC:
                what = "empty file" if size == 0 else "bad magic bytes"
                raise LogReadError(f"{p}: not an MCAP file ({what})")
            try:
                raw, metadata = _read_indexed(f, size, topics)
                truncated = False
            except Exception:
                f.seek(0)
                raw, metadata, complete = _read_streaming(f.read())
                truncated = not complete
    except OSError as e:
        raise LogReadError(f"{p}: cannot open log ({e.strerror or e})") from None

    per_topic: dict[str, list[tuple[int, dict[str, Any]]]] = {}
    scene_topics: dict[str, None] = {}
    for topic, encoding, log_time, data in raw:
        if encoding == _BINARY_ENCODING:
            scene_topics.setdefault(topic, None)
            continue
        if topics is not None and topic not in topics:
            continue
        if encoding != _MESSAGE_ENCODING:
            raise LogReadError(
                f"{p}: topic {topic} uses message encoding {encoding!r}: only json (and protobuf, skipped) is read"
            )
        try:
            msg = orjson.loads(data)
        except ValueError:  # strict JSON refused: another writer's NaN or Infinity, which json reads
            try:
                msg = json.loads(data)
            except (ValueError, UnicodeDecodeError) as e:
                raise LogReadError(f"{p}: undecodable JSON message on {topic} at {log_time} ns ({e})") from None
        if not isinstance(msg, dict):
            msg = {"value": msg}
        per_topic.setdefault(topic, []).append((log_time, flatten(msg)))

    frames = {topic: _frame(rows) for topic, rows in per_topic.items()}
    return Log(topics=frames, metadata=metadata, truncated=truncated, scene_topics=tuple(sorted(scene_topics)))
