"""Compare the scene's two encodings on a run's log: protobuf (what slotexp writes) against JSON.

    python scripts/scene_encoding.py experiments/simulate/<timestamp>/logs/walk.mcap

The JSON copy holds the same messages: every protobuf message (``/scene``, the two
paths' topics and ``/transforms``) decoded with the schema stored in the log and written as JSON in
Foxglove's JSON layout (field names as in the schema, timestamps and durations as
``{sec, nsec}``), under the SDK's schema names with a ``jsonschema`` of the right type,
in a file with the same chunk size and compression. It prints file sizes, the time of
:func:`slotexp.record.read_log` on each (median of 3), and the time to decode every scene
message (protobuf class from the stored descriptor set, or ``json.loads``). Needs the
test extras (``protobuf``).
"""

from __future__ import annotations

import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

from google.protobuf.json_format import MessageToDict
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from slotexp.foxglove_scene import message_class, schemas


def _foxglove_json(value):
    """protobuf's JSON mapping -> Foxglove's JSON layout (timestamps/durations as {sec, nsec})."""
    if isinstance(value, dict):
        return {k: _foxglove_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_foxglove_json(v) for v in value]
    if isinstance(value, str) and value.endswith("Z") and "T" in value:  # RFC 3339 timestamp
        import datetime as dt

        head, _, frac = value[:-1].partition(".")
        sec = int(dt.datetime.fromisoformat(head).replace(tzinfo=dt.timezone.utc).timestamp())
        return {"sec": sec, "nsec": int((frac + "000000000")[:9]) if frac else 0}
    if isinstance(value, str) and value.endswith("s") and value[:-1].replace(".", "").isdigit():  # duration
        sec, _, frac = value[:-1].partition(".")
        return {"sec": int(sec), "nsec": int((frac + "000000000")[:9]) if frac else 0}
    return value


def to_json_copy(src: Path, dst: Path) -> None:
    with open(src, "rb") as f, open(dst, "wb") as out:
        reader = make_reader(f)
        summary = reader.get_summary()
        writer = Writer(out, chunk_size=48 * 1024, compression=CompressionType.ZSTD)
        writer.start(profile="slotexp")
        classes, channels = {}, {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.id not in channels:
                if channel.message_encoding == "protobuf":
                    classes[channel.id] = message_class(schema.name, schema.data)
                    sid = writer.register_schema(schema.name, "jsonschema", b'{"type":"object"}')
                else:
                    sid = writer.register_schema(schema.name, schema.encoding, schema.data)
                channels[channel.id] = writer.register_channel(channel.topic, "json", sid)
            data = message.data
            if channel.id in classes:
                msg = classes[channel.id].FromString(data)
                as_dict = MessageToDict(
                    msg, preserving_proto_field_name=True, always_print_fields_with_no_presence=True
                )
                data = json.dumps(_foxglove_json(as_dict), separators=(",", ":")).encode()
            writer.add_message(channels[channel.id], message.log_time, data, message.publish_time)
        for meta in reader.iter_metadata():
            writer.add_metadata(meta.name, dict(meta.metadata))
        writer.finish()
        del summary


def decode_scene(path: Path) -> float:
    """Seconds to decode every scene message in ``path`` (protobuf or JSON, as its channels say)."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        start = time.perf_counter()
        classes = {}
        for schema, channel, message in reader.iter_messages(topics=list(schemas())):
            if channel.message_encoding == "protobuf":
                cls = classes.get(channel.id) or classes.setdefault(channel.id, message_class(schema.name, schema.data))
                cls.FromString(message.data)
            else:
                json.loads(message.data)
        return time.perf_counter() - start


def timed(fn, *args) -> float:
    times = []
    for _ in range(3):
        start = time.perf_counter()
        fn(*args)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main(path: str) -> None:
    from slotexp.record import read_log

    src = Path(path)
    with tempfile.TemporaryDirectory() as tmp:
        dst = Path(tmp) / "json.mcap"
        to_json_copy(src, dst)
        with open(src, "rb") as f:
            n = sum(1 for _ in make_reader(f).iter_messages(topics=["/scene"]))
        print(f"{n} scene messages")
        for name, p in (("protobuf (shipped)", src), ("json", dst)):
            size = p.stat().st_size
            print(
                f"{name:20s} file {size / 1e6:7.2f} MB   read_log {timed(read_log, p):6.2f} s   "
                f"decode every scene message {timed(decode_scene, p):6.2f} s"
            )


if __name__ == "__main__":
    main(sys.argv[1])
