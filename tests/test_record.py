"""Tests for slotexp.record: MCAP run logs (write, read back, crash recovery)."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from mcap.reader import make_reader

from slotexp.foxglove_scene import message_class
from slotexp.record import LogReadError, Recorder, flatten, is_closed, read_log

REPO_ROOT = Path(__file__).resolve().parents[1]


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def _write_rich_log(path: Path, n: int = 50, chunk_size: int = 64 * 1024) -> list[float]:
    """Write the reference log used by several tests; returns the times written."""
    times = [0.0] + [0.001 * k + 1e-9 * (k % 7) for k in range(1, n)]
    with Recorder(path, {"run": {"seed": "3", "controller": "mpc"}}, chunk_size=chunk_size) as rec:
        for k, t in enumerate(times):
            rec.write(
                "/state",
                t,
                {
                    "p": np.array([k, 2.0 * k, -0.5 * k]),
                    "v": [float(k), np.float32(0.25), np.int64(k)],
                    "forces": np.arange(12, dtype=np.float64).reshape(4, 3) + k,
                    "contact": [bool(k % 2), True, False, np.bool_(k % 3 == 0)],
                    "cost": math.nan if k % 5 == 0 else 1.5 * k,
                    "inf": math.inf,
                    "mode": f"gait{k % 3}",
                    "nested": {"a": {"b": np.float64(k) / 3.0}, "c": np.int32(-k)},
                    "flag": k % 2 == 0,
                },
            )
            if k % 2 == 0:
                rec.write("/ctrl", t, {"u": np.full(3, 0.1 * k), "solve_ms": 0.3})
    return times


def test_flatten_layout() -> None:
    msg = {"a": 1, "p": [1, 2, 3], "f": [[1, 2], [3, 4]], "n": {"x": {"y": "s"}}, "e": []}
    assert flatten(msg) == {
        "a": 1,
        "p.0": 1,
        "p.1": 2,
        "p.2": 3,
        "f.0.0": 1,
        "f.0.1": 2,
        "f.1.0": 3,
        "f.1.1": 4,
        "n.x.y": "s",
    }


def test_round_trip_values_times_and_columns(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    times = _write_rich_log(path)
    log = read_log(path)

    assert log.truncated is False
    assert set(log.topics) == {"/state", "/ctrl"}
    st = log["/state"]
    expected_cols = (
        ["t", "p.0", "p.1", "p.2", "v.0", "v.1", "v.2"]
        + [f"forces.{i}.{j}" for i in range(4) for j in range(3)]
        + [f"contact.{i}" for i in range(4)]
        + ["cost", "inf", "mode", "nested.a.b", "nested.c", "flag"]
    )
    assert list(st.columns) == expected_cols
    assert len(st) == len(times)
    # times exact to the nanosecond
    assert [_ns(t) for t in st["t"]] == [_ns(t) for t in times]
    assert st["t"].dtype == np.float64

    for k, row in st.iterrows():
        assert [row["p.0"], row["p.1"], row["p.2"]] == [k, 2.0 * k, -0.5 * k]
        assert [row["v.0"], row["v.1"], row["v.2"]] == [float(k), 0.25, float(k)]
        forces = np.array([[row[f"forces.{i}.{j}"] for j in range(3)] for i in range(4)])
        np.testing.assert_array_equal(forces, np.arange(12).reshape(4, 3) + k)
        if k % 5 == 0:
            assert math.isnan(row["cost"])
        else:
            assert row["cost"] == 1.5 * k
        assert math.isnan(row["inf"])  # non-finite -> null -> NaN
        assert row["mode"] == f"gait{k % 3}"
        assert row["nested.a.b"] == np.float64(k) / 3.0
        assert row["nested.c"] == -k
        assert row["contact.0"] == bool(k % 2)
        assert row["contact.3"] == (k % 3 == 0)
        assert row["flag"] == (k % 2 == 0)

    for col in expected_cols:
        if col == "mode":
            assert st[col].dtype == object
        elif col.startswith("contact") or col == "flag":
            assert st[col].dtype == bool
        else:
            assert st[col].dtype == np.float64, col

    ctrl = log["/ctrl"]
    assert list(ctrl.columns) == ["t", "u.0", "u.1", "u.2", "solve_ms"]
    assert [_ns(t) for t in ctrl["t"]] == [_ns(t) for k, t in enumerate(times) if k % 2 == 0]
    np.testing.assert_array_equal(ctrl["u.1"].to_numpy(), 0.1 * np.arange(0, len(times), 2))


def test_file_is_standard_mcap_with_json_schemas(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    _write_rich_log(path)
    with open(path, "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
    assert header.profile == "slotexp"
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == 50 + 25
    chans = {c.topic: c for c in summary.channels.values()}
    assert all(c.message_encoding == "json" for c in chans.values())
    schema = summary.schemas[chans["/state"].schema_id]
    assert schema.name == "slotexp.state" and schema.encoding == "jsonschema"
    js = json.loads(schema.data)
    assert js["type"] == "object"
    props = js["properties"]
    assert props["cost"] == {"type": "number"}
    assert props["mode"] == {"type": "string"}
    assert props["flag"] == {"type": "boolean"}
    assert props["p"] == {"type": "array", "items": {"type": "number"}}
    assert props["forces"] == {
        "type": "array",
        "items": {"type": "array", "items": {"type": "number"}},
    }
    assert props["nested"]["type"] == "object"
    assert props["nested"]["properties"]["a"]["properties"]["b"] == {"type": "number"}
    assert summary.schemas[chans["/ctrl"].schema_id].name == "slotexp.ctrl"


def test_metadata_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "meta.mcap"
    with Recorder(path, {"config": {"a": "1", "b": "x=y"}}) as rec:
        rec.add_metadata("git", {"sha": "abc123", "dirty": "false"})
        rec.write("/s", 0.0, {"x": 1.0})
        with pytest.raises(TypeError):
            rec.add_metadata("bad", {"n": 3})  # type: ignore[dict-item]
    log = read_log(path)
    assert log.metadata == {
        "config": {"a": "1", "b": "x=y"},
        "git": {"sha": "abc123", "dirty": "false"},
    }


def test_reading_some_topics_gives_those_topics_whole_and_all_the_metadata(tmp_path: Path) -> None:
    path = tmp_path / "rich.mcap"
    _write_rich_log(path, n=400, chunk_size=2048)
    full = read_log(path)
    cut = tmp_path / "cut.mcap"  # no summary index: read by streaming
    cut.write_bytes(path.read_bytes()[:-1])
    for p in (path, cut):
        some = read_log(p, topics=("/ctrl",))
        assert list(some.topics) == ["/ctrl"] and some.metadata == full.metadata
        pd.testing.assert_frame_equal(some["/ctrl"], full["/ctrl"])
        none = read_log(p, topics=())
        assert none.topics == {} and none.metadata == full.metadata


def test_foxglove_pose_and_transform(tmp_path: Path) -> None:
    path = tmp_path / "pose.mcap"
    with Recorder(path) as rec:
        rec.write_pose(0.5, [1.0, 2.0, 3.0], [0.9, 0.1, 0.2, 0.3])
        rec.write_pose(
            2.000000007,
            np.array([4.0, 5.0, 6.0]),
            np.array([0.0, 1.0, 0.0, 0.0]),
            frame_id="map",
            child_frame_id="base",
        )
    log = read_log(path)

    pose = log["/torso/pose"]
    assert list(pose.columns) == [
        "t",
        "timestamp.sec",
        "timestamp.nsec",
        "frame_id",
        "pose.position.x",
        "pose.position.y",
        "pose.position.z",
        "pose.orientation.x",
        "pose.orientation.y",
        "pose.orientation.z",
        "pose.orientation.w",
    ]
    r0 = pose.iloc[0]
    assert (r0["timestamp.sec"], r0["timestamp.nsec"]) == (0, 500_000_000)
    assert r0["frame_id"] == "world"
    assert [r0[f"pose.position.{a}"] for a in "xyz"] == [1.0, 2.0, 3.0]
    # (w, x, y, z) in -> x, y, z, w fields
    assert [r0[f"pose.orientation.{a}"] for a in "xyzw"] == [0.1, 0.2, 0.3, 0.9]
    r1 = pose.iloc[1]
    assert (r1["timestamp.sec"], r1["timestamp.nsec"]) == (2, 7)
    assert _ns(r1["t"]) == 2_000_000_007

    assert log.scene_topics == ("/transforms",)  # protobuf: named, not tabulated
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        by_topic = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
        transforms = [m for _, _, m in reader.iter_messages(["/transforms"])]
    assert (by_topic["/transforms"].name, by_topic["/transforms"].encoding) == ("foxglove.FrameTransforms", "protobuf")
    cls = message_class("foxglove.FrameTransforms", by_topic["/transforms"].data)
    tfs = [cls.FromString(m.data).transforms for m in transforms]
    assert [m.log_time for m in transforms] == [500_000_000, 2_000_000_007]
    assert [(tf.timestamp.seconds, tf.timestamp.nanos) for (tf,) in tfs] == [(0, 500_000_000), (2, 7)]
    assert [(tf.parent_frame_id, tf.child_frame_id) for (tf,) in tfs] == [("world", "torso"), ("map", "base")]
    assert [[getattr(tf.translation, a) for a in "xyz"] for (tf,) in tfs] == [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]
    assert [[getattr(tf.rotation, a) for a in "xyzw"] for (tf,) in tfs] == [[0.1, 0.2, 0.3, 0.9], [1.0, 0.0, 0.0, 0.0]]

    assert by_topic["/torso/pose"].name == "foxglove.PoseInFrame"
    assert by_topic["/torso/pose"].encoding == "jsonschema"
    pj = json.loads(by_topic["/torso/pose"].data)
    assert pj["type"] == "object"
    assert set(pj["properties"]) == {"timestamp", "frame_id", "pose"}
    assert set(pj["properties"]["timestamp"]["properties"]) == {"sec", "nsec"}
    assert set(pj["properties"]["pose"]["properties"]) == {"position", "orientation"}
    assert set(pj["properties"]["pose"]["properties"]["orientation"]["properties"]) == set("xyzw")


def _assert_prefix(recovered: pd.DataFrame, full: pd.DataFrame) -> None:
    assert list(recovered.columns) == list(full.columns)
    expected = full.iloc[: len(recovered)].reset_index(drop=True)
    pd.testing.assert_frame_equal(recovered.reset_index(drop=True), expected)


def test_truncated_copies_recover_a_prefix(tmp_path: Path) -> None:
    path = tmp_path / "full.mcap"
    _write_rich_log(path, n=400, chunk_size=2048)
    data = path.read_bytes()
    full = read_log(path)
    assert not full.truncated and is_closed(path)

    counts = []
    for frac in (0.001, 0.1, 0.25, 0.4, 0.55, 0.7, 0.85, 0.97):
        cut = max(9, int(len(data) * frac))
        p = tmp_path / f"cut_{frac}.mcap"
        p.write_bytes(data[:cut])
        log = read_log(p)
        assert log.truncated is True, frac
        assert not is_closed(p), frac  # the cheap probe agrees, without reading the messages
        # metadata record is written right after the header
        if cut > 200:
            assert log.metadata == full.metadata
        for topic, df in log.topics.items():
            _assert_prefix(df, full[topic])
        n = sum(len(df) for df in log.topics.values())
        if frac >= 0.25:
            assert n > 0, frac
        counts.append(n)
    assert counts == sorted(counts)
    assert counts[0] == 0 and counts[-1] > 0

    # only the closing magic is damaged: all data is there but the file is not finished
    p = tmp_path / "nomagic.mcap"
    p.write_bytes(data[:-1])
    log = read_log(p)
    assert log.truncated is True
    for topic in full.topics:
        pd.testing.assert_frame_equal(log[topic], full[topic])


def test_corrupt_chunk_stops_cleanly(tmp_path: Path) -> None:
    path = tmp_path / "full.mcap"
    _write_rich_log(path, n=400, chunk_size=2048)
    full = read_log(path)
    data = bytearray(path.read_bytes())
    mid = len(data) // 2
    data[mid : mid + 64] = bytes(64)  # zero out bytes inside a chunk's payload
    p = tmp_path / "corrupt.mcap"
    p.write_bytes(bytes(data))
    log = read_log(p)
    assert log.truncated is True
    for topic, df in log.topics.items():
        _assert_prefix(df, full[topic])
        assert len(df) < len(full[topic])


def test_open_recorder_file_is_readable_mid_run(tmp_path: Path) -> None:
    """Chunks are flushed as they are emitted, so a live file is readable."""
    path = tmp_path / "live.mcap"
    rec = Recorder(path, chunk_size=1024)
    try:
        for k in range(300):
            rec.write("/s", k * 0.01, {"k": k, "x": np.random.default_rng(k).standard_normal(6)})
        log = read_log(path)
        assert log.truncated is True
        df = log["/s"]
        assert len(df) > 100
        assert list(df["k"]) == list(range(len(df)))
    finally:
        rec.close()
    rec.close()  # idempotent
    log = read_log(path)
    assert not log.truncated and len(log["/s"]) == 300
    with pytest.raises(RuntimeError):
        rec.write("/s", 4.0, {"k": 1})


_CHILD = textwrap.dedent(
    """
    import sys
    import numpy as np
    from slotexp.record import Recorder

    rec = Recorder(sys.argv[1], {"run": {"id": "killed"}}, chunk_size=2048)
    rng = np.random.default_rng(0)
    k = 0
    while True:
        rec.write("/state", k * 1e-3, {"k": k, "q": rng.standard_normal(12)})
        k += 1
    """
)


def test_sigkilled_writer_leaves_readable_file(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO_ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.Popen(
        [sys.executable, "-c", _CHILD, str(path)], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    try:
        deadline = time.monotonic() + 8.0
        while time.monotonic() < deadline:
            if path.exists() and path.stat().st_size > 6 * 2048:
                break
            if proc.poll() is not None:
                err = proc.stderr.read().decode() if proc.stderr else ""
                pytest.fail(f"writer exited early: {err}")
            time.sleep(0.01)
        else:
            pytest.fail("writer did not produce several chunks in time")
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=5)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)
        if proc.stderr:
            proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL

    log = read_log(path)
    assert log.truncated is True
    assert log.metadata == {"run": {"id": "killed"}}
    df = log["/state"]
    assert len(df) > 0
    assert df["t"].is_monotonic_increasing
    assert list(df["k"]) == list(range(len(df)))
    assert [_ns(t) for t in df["t"]] == [_ns(k * 1e-3) for k in range(len(df))]
    rng = np.random.default_rng(0)
    q = np.array([rng.standard_normal(12) for _ in range(len(df))])
    np.testing.assert_array_equal(df[[f"q.{i}" for i in range(12)]].to_numpy(), q)


def test_keyboard_interrupt_leaves_complete_file(tmp_path: Path) -> None:
    path = tmp_path / "ki.mcap"
    with pytest.raises(KeyboardInterrupt):
        with Recorder(path, chunk_size=1024) as rec:
            for k in range(200):
                rec.write("/s", k * 0.01, {"k": k})
            raise KeyboardInterrupt
    log = read_log(path)
    assert log.truncated is False
    assert list(log["/s"]["k"]) == list(range(200))


def test_empty_log_and_missing_topic(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    with Recorder(path, {"a": {"b": "c"}}):
        pass
    log = read_log(path)
    assert log.topics == {} and log.truncated is False
    assert log.metadata == {"a": {"b": "c"}}
    with pytest.raises(KeyError, match="available topics"):
        log["/nope"]


def test_not_mcap_and_missing_raise_log_read_error(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_text("this is not an mcap file at all\n")
    with pytest.raises(LogReadError, match="bad.mcap") as ei:
        read_log(bad)
    assert "\n" not in str(ei.value)
    empty = tmp_path / "zero.mcap"
    empty.write_bytes(b"")
    with pytest.raises(LogReadError, match="zero.mcap"):
        read_log(empty)
    missing = tmp_path / "missing.mcap"
    with pytest.raises(LogReadError, match="missing.mcap"):
        read_log(missing)
    assert issubclass(LogReadError, ValueError)


def test_write_validation(tmp_path: Path) -> None:
    with Recorder(tmp_path / "v.mcap") as rec:
        with pytest.raises(ValueError):
            rec.write("/s", -1.0, {"x": 1})
        with pytest.raises(ValueError):
            rec.write("/s", math.nan, {"x": 1})
        with pytest.raises(ValueError, match="reserved"):
            rec.write("/s", 0.0, {"t": 1.0})
        with pytest.raises(TypeError):
            rec.write("/s", 0.0, {"x": object()})
        with pytest.raises(ValueError):
            rec.write_pose(0.0, [1.0, 2.0], [1.0, 0.0, 0.0, 0.0])


def test_outputs_are_replaced_whole_or_not_at_all(tmp_path) -> None:
    from slotexp.atomic import replacing, write_text

    target = tmp_path / "table1.csv"
    write_text(target, "old\n")
    with pytest.raises(RuntimeError):
        with replacing(target) as tmp:
            tmp.write_text("half of a new ta")
            raise RuntimeError("stopped while writing")
    assert target.read_text() == "old\n"  # the reader still sees the complete old file
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table1.csv"]  # and no temporary is left
    write_text(target, "new\n")
    assert target.read_text() == "new\n"


def test_the_fast_encoder_writes_what_the_checked_conversion_writes(tmp_path: Path) -> None:
    # Messages are encoded by orjson; _to_json (the first message's schema, and any message orjson
    # refuses) must give the same JSON, and a message orjson refuses is still logged or named.
    import json

    from slotexp.record import _encode, _to_json

    grid = np.arange(12.0).reshape(3, 4)
    messages = [
        {"a": np.array([1.0, np.nan, -np.inf, 1e-5, 123456789.125]), "c": np.bool_(True)},
        {"nested": {"k": (1, 2.5, None), "ints": np.arange(3, dtype=np.int64), "flags": np.array([True, False])}},
        {"scalars": [np.int32(-4), np.float64("nan"), 7, "text"], "grid": grid},
        {"strided": grid[:, 1], "sliced": grid.T},  # not C-contiguous: orjson refuses, the fallback converts
        {1: "int key", "x": float("inf")},
    ]
    for message in messages:
        assert json.loads(_encode(message, "/m")) == json.loads(json.dumps(_to_json(message, "/m")))
    # a float32 is written at its own precision (the same float32 when read back), not widened first
    assert np.float32(json.loads(_encode({"b": np.float32(0.1)}, "/m"))["b"]) == np.float32(0.1)
    with Recorder(tmp_path / "e.mcap") as rec:
        rec.write("/m", 0.0, {"x": 1.0})
        with pytest.raises(TypeError, match="'/m.x'"):
            rec.write("/m", 0.1, {"x": object()})


def test_outputs_get_the_mode_open_would_give_them_and_json_is_strict(tmp_path: Path):
    # Colleagues on a shared machine read our tables and figures: an atomically written output has the
    # mode an ordinary open() gives (0666 less the umask), not mkstemp's 0600. JSON holds no NaN, which
    # strict readers (a browser's JSON.parse) refuse: non-finite numbers are null.
    import json
    import os
    import stat

    from slotexp.atomic import write_json, write_text

    mask = os.umask(0o022)
    os.umask(mask)
    ordinary = tmp_path / "ordinary.txt"
    ordinary.write_text("x")
    write_text(tmp_path / "table.md", "| a |\n")
    assert stat.S_IMODE((tmp_path / "table.md").stat().st_mode) == stat.S_IMODE(ordinary.stat().st_mode)
    assert stat.S_IMODE((tmp_path / "table.md").stat().st_mode) == 0o666 & ~mask
    write_json(tmp_path / "m.json", {"a": float("nan"), "b": [np.float64(np.inf), 1.5], "c": np.int64(3)})
    text = (tmp_path / "m.json").read_text()
    assert "NaN" not in text and "Infinity" not in text
    assert json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict JSON: {c}")) == {
        "a": None,
        "b": [None, 1.5],
        "c": 3,
    }


def test_a_stop_signal_while_a_run_sets_up_is_taken_by_the_run_and_closes_its_log(tmp_path: Path, monkeypatch) -> None:
    # a sweep's job gets SIGTERM when its parent dies, possibly while its kernels still compile: the run, not the
    # handler in place before it (the default action, which would end the process with the log unfinished),
    # takes it, stops before the first step and closes the log
    import slotexp.simulation as simulation
    from slotexp.errors import Interrupted
    from slotexp.jobs._logged import run_logged

    from .helpers import load

    build = simulation.make_plant

    def signalled_while_building(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        return build(*args, **kwargs)

    monkeypatch.setattr(simulation, "make_plant", signalled_while_building)
    reached_before: list[int] = []

    def handler_before(num, frame) -> None:
        reached_before.append(num)

    before = signal.signal(signal.SIGTERM, handler_before)
    try:
        cfg = load("experiment=simulate")
        log = tmp_path / "walk.mcap"
        with pytest.raises(Interrupted) as stopped:
            run_logged(cfg, cfg.scenarios["baseline"], 600.0, log, "", "")
        assert stopped.value.signum == signal.SIGTERM
        assert reached_before == []
        assert is_closed(log)
        assert signal.getsignal(signal.SIGTERM) is handler_before  # back in place after the run
    finally:
        signal.signal(signal.SIGTERM, before)
