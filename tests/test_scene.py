"""The 3D scene: in the log (decoded with the schema foxglove-sdk wrote into it) and live over the SDK's
WebSocket server (a real client on 127.0.0.1).

The SDK's server (0.30) speaks the subprotocol ``foxglove.sdk.v1``, the successor of
``foxglove.websocket.v1`` with the same messages (it refuses a client offering only the old
name, HTTP 400); the client offers both, as the Foxglove app does, and the server picks."""

from __future__ import annotations

import base64
import json
import os
import stat
import struct
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from websockets.sync.client import connect

from slotexp.body import quat_to_rot
from slotexp.errors import ConfigError
from slotexp.foxglove_scene import (
    PATH_TOPICS,
    SCENE_TOPIC,
    TRANSFORMS_TOPIC,
    SceneEncoder,
    TransformEncoder,
    message_class,
    schemas,
)
from slotexp.live import LiveView
from slotexp.record import Recorder, read_log
from slotexp.scene import FORCE_SCALE_M_PER_N, SceneTrack, rotation_from_x, straight_legs
from slotexp.simulation import run_closed_loop
from slotexp.telemetry import Tee
from tests import sdk_scene
from tests.helpers import assert_one_line_error, load

LEGS = ("FL", "RL", "RR", "FR")


def rotate(q_xyzw: np.ndarray, v: np.ndarray) -> np.ndarray:
    x, y, z, w = q_xyzw
    u = np.array([x, y, z])
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


@pytest.fixture(scope="module")
def soft_log(tmp_path_factory) -> Path:
    """0.2 s (6 MPC steps) of the walk on the soft plant, logged as a run logs it."""
    cfg = load("experiment=simulate", "plant=cosserat")
    path = tmp_path_factory.mktemp("scene") / "walk.mcap"
    with Recorder(path) as rec:
        run_closed_loop(cfg, cfg.scenarios["baseline"], 0.2, rec)
    return path


def test_every_step_has_a_scene_that_decodes_with_the_sdk_schema(soft_log: Path) -> None:
    cfg = load("experiment=simulate", "plant=cosserat")
    n_nodes = cfg.robot.leg.n_nodes
    log = read_log(soft_log)  # the numeric topics still read; the scene is named, not tabulated
    assert set(log.scene_topics) == set(schemas()) == {SCENE_TOPIC, TRANSFORMS_TOPIC, *PATH_TOPICS.values()}
    forces = log["/forces"]
    markers = log["/markers"]
    reference = log["/reference"]
    with open(soft_log, "rb") as f:
        reader = make_reader(f)
        schemas_in_log = {
            c.topic: reader.get_summary().schemas[c.schema_id] for c in reader.get_summary().channels.values()
        }
        for topic in (SCENE_TOPIC, *PATH_TOPICS.values()):
            assert (schemas_in_log[topic].name, schemas_in_log[topic].encoding) == ("foxglove.SceneUpdate", "protobuf")
        assert schemas_in_log[TRANSFORMS_TOPIC].name == "foxglove.FrameTransforms"
        scene_cls = message_class("foxglove.SceneUpdate", schemas_in_log[SCENE_TOPIC].data)
        tf_cls = message_class("foxglove.FrameTransforms", schemas_in_log[TRANSFORMS_TOPIC].data)
        by_topic: dict[str, list] = {}
        for _, channel, m in make_reader(f).iter_messages():
            by_topic.setdefault(channel.topic, []).append((m.log_time, m.data))
    scenes = [(t, scene_cls.FromString(data)) for t, data in by_topic[SCENE_TOPIC]]
    tfs = [tf_cls.FromString(data) for _, data in by_topic[TRANSFORMS_TOPIC]]
    assert len(scenes) == len(forces) == len(tfs) == 6
    for k, (log_time, scene) in enumerate(scenes):
        assert log_time == round(forces["t"].iloc[k] * 1e9)
        entities = {e.id: e for e in scene.entities}
        assert not any(id.startswith("path/") for id in entities)  # on their own topics
        legs = [entities[f"leg/{name}"] for name in LEGS]
        assert all(len(e.lines) == 1 and len(e.lines[0].points) == n_nodes for e in legs)
        for i, name in enumerate(LEGS):
            foot = legs[i].lines[0].points[-1]
            assert [foot.x, foot.y, foot.z] == pytest.approx(
                [markers[f"{name}_foot.{a}"].iloc[k] for a in range(3)], abs=1e-12
            )
            arrow = entities[f"force/{name}"].arrows[0]
            q = arrow.pose.orientation
            length = arrow.shaft_length + arrow.head_length
            drawn = rotate(np.array([q.x, q.y, q.z, q.w]), np.array([1.0, 0.0, 0.0])) * length / FORCE_SCALE_M_PER_N
            logged = np.array([forces[f"applied.{i}.{a}"].iloc[k] for a in range(3)])
            assert drawn == pytest.approx(logged, abs=1e-9)
            tail = arrow.pose.position
            assert [tail.x, tail.y, tail.z] == pytest.approx([foot.x, foot.y, foot.z])
        feet = [[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in entities["feet"].spheres]
        ends = [[p.x, p.y, p.z] for p in (e.lines[0].points[-1] for e in legs)]
        np.testing.assert_allclose(feet, ends, atol=1e-12)
        assert "footholds" not in entities  # the gait controller plans none
        torso = entities["torso"].cubes[0]
        assert [torso.size.x, torso.size.y, torso.size.z] == pytest.approx(cfg.robot.torso.size)
        (tf,) = tfs[k].transforms
        assert (tf.parent_frame_id, tf.child_frame_id) == ("world", "torso")
        assert tf.translation.x == pytest.approx(torso.pose.position.x)
    # a path's message comes at the first step and where it gained a point: it ends at that step's point
    step_of = {t: k for k, (t, _) in enumerate(scenes)}
    for key, topic in PATH_TOPICS.items():
        assert by_topic[topic][0][0] == scenes[0][0]
        for log_time, data in by_topic[topic]:
            (entity,) = scene_cls.FromString(data).entities
            assert entity.id == f"path/{key}"
            end = entity.lines[0].points[-1]
            k = step_of[log_time]
            if key == "actual":
                expected = [scenes[k][1].entities[0].cubes[0].pose.position.__getattribute__(a) for a in "xyz"]
            else:
                expected = [reference[f"p.{a}"].iloc[k] for a in range(3)]
            assert [end.x, end.y, end.z] == pytest.approx(expected, abs=1e-12), (key, k)


@pytest.mark.mujoco
def test_the_rigid_quadrupeds_scene_shows_its_feet_and_the_planned_footholds(tmp_path: Path) -> None:
    cfg = load("experiment=simulate", "plant=rigid")
    path = tmp_path / "trot.mcap"
    with Recorder(path) as rec:
        run_closed_loop(cfg, cfg.scenarios["baseline"], 0.2, rec)
    planned = read_log(path)["/controller"]
    with open(path, "rb") as f:
        reader = make_reader(f)
        schema = next(s for s in reader.get_summary().schemas.values() if s.name == "foxglove.SceneUpdate")
        scene_cls = message_class("foxglove.SceneUpdate", schema.data)
        scenes = [scene_cls.FromString(m.data) for _, _, m in reader.iter_messages([SCENE_TOPIC])]
    assert len(scenes) == len(planned) == 10  # 0.2 s at the rigid plant's 50 Hz
    for k, scene in enumerate(scenes):
        entities = {e.id: e for e in scene.entities}
        drawn = [[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in entities["footholds"].spheres]
        logged = [[planned[f"foothold.{i}.{a}"].iloc[k] for a in range(3)] for i in range(4)]
        np.testing.assert_allclose(drawn, logged, atol=1e-12)
        feet = [[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in entities["feet"].spheres]
        ends = [entities[f"leg/{name}"].lines[0].points[-1] for name in cfg.robot.leg.names]
        assert all(len(entities[f"leg/{name}"].lines[0].points) == 4 for name in cfg.robot.leg.names)  # hip to foot
        np.testing.assert_allclose(feet, [[p.x, p.y, p.z] for p in ends], atol=1e-12)


def test_paths_keep_a_point_per_spacing_and_arrows_point_along_the_force() -> None:
    track = SceneTrack(LEGS, [0.1, 0.08, 0.03], spacing=0.0095, max_points=8)
    zero = np.zeros((4, 3))
    legs = np.zeros((4, 2, 3))
    paths = []
    for k in range(40):  # 1 mm steps: a kept point every 10 steps
        frame = track.frame(k / 30, [k * 1e-3, 0, 0.04], [1, 0, 0, 0], [k * 1e-3, 0, 0.04], legs, zero)
        paths.append(frame.actual_path)
    assert frame.actual_path[:, 0] == pytest.approx([0.0, 0.01, 0.02, 0.03])
    assert paths[31] is paths[39] and paths[30] is not paths[29]  # unchanged between kept points: the same array
    early = [p.copy() for p in paths]
    for k in range(40, 200):
        frame = track.frame(k / 30, [k * 1e-3, 0, 0.04], [1, 0, 0, 0], [0, 0, 0], legs, zero)
    assert all(np.array_equal(p, q) for p, q in zip(paths, early))  # a path given out never changes after
    assert len(frame.actual_path) <= 8 and frame.actual_path[-1, 0] == pytest.approx(0.19)
    assert frame.actual_path[0, 0] < 0.05 and np.all(np.diff(frame.actual_path[:, 0]) > 0)
    rng = np.random.default_rng(1)
    for d in [*rng.normal(size=(20, 3)), np.array([-1.0, 0, 0]), np.array([1.0, 0, 0])]:
        assert rotate(rotation_from_x(d), np.array([1.0, 0, 0])) == pytest.approx(d / np.linalg.norm(d))


def test_straight_legs_are_the_segments_at_the_torsos_pose() -> None:
    rng = np.random.default_rng(3)
    segments = rng.normal(scale=0.1, size=(4, 2, 3))
    for _ in range(10):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        position = rng.normal(size=3)
        expected = segments @ quat_to_rot(q).T + position
        np.testing.assert_allclose(straight_legs(segments, position, q), expected, rtol=0, atol=1e-15)
        wide = np.zeros((4, 3, 3))
        wide[:, ::2] = segments  # a strided view: the plants' arrays are not always contiguous
        np.testing.assert_allclose(straight_legs(wide[:, ::2], position, q), expected, rtol=0, atol=1e-15)


def test_a_frame_that_does_not_fit_the_layout_is_refused() -> None:
    """The compiled fill writes into a fixed buffer: a frame with more numbers than the layout has slots
    (here a foot more than the legs) is an error, not a write past the end; so is a transform with too
    few numbers, not a read past them."""
    track = SceneTrack(LEGS, [0.1, 0.08, 0.03])
    frame = track.frame(0.0, [0, 0, 0.04], [1, 0, 0, 0], [0, 0, 0.04], np.zeros((4, 5, 3)), np.ones((4, 3)))
    encoder = SceneEncoder()
    encoder.messages(frame)
    frame.feet = np.zeros((5, 3))
    with pytest.raises(ValueError, match="do not match its layout"):
        encoder.messages(frame)
    with pytest.raises(ValueError, match="do not match the message's layout"):
        TransformEncoder().message(0.0, np.zeros(2), np.array([1.0, 0.0, 0.0, 0.0]))  # a 2-D position


@pytest.mark.parametrize(("n_nodes", "footholds"), [(31, False), (2, False), (4, True)])
def test_the_encoders_bytes_decode_to_the_message_the_sdk_encodes(n_nodes: int, footholds: bool) -> None:
    """The scene's own wire bytes against the SDK's objects and encode(), step after step: paths that grow,
    stay and are thinned, zero, opposite and huge forces, timestamps with no seconds or no nanoseconds, a
    zero node. A path's message comes when the path changed, and with a refresh also when it is due."""
    scene_cls = message_class("foxglove.SceneUpdate", schemas()[SCENE_TOPIC].data)
    tf_cls = message_class("foxglove.FrameTransforms", schemas()[TRANSFORMS_TOPIC].data)
    rng = np.random.default_rng(7)
    track = SceneTrack(LEGS, [0.1255, 0.0855, 0.034], spacing=0.004, max_points=3)  # thinned at a 4th point
    logged, live, transforms = SceneEncoder(), SceneEncoder(path_refresh_s=1.0), TransformEncoder()
    lengths = []
    last: dict[str, np.ndarray] = {}
    made: dict[str, float] = {}
    written: list[list[str]] = []
    for k, t in enumerate([0.0, 0.4, 1.0, 1.0333333333, 2.5, 7.0, 8.0, 12345.678901, 12345.7]):
        legs = rng.normal(scale=0.05, size=(4, n_nodes, 3))
        legs[0, 0] = 0.0
        forces = rng.normal(size=(4, 3)) + [0.0, 0.0, 5.0]
        forces[k % 4] = [[0.0, 0.0, 0.0], [-3.0, 0.0, 0.0], [1e6, -2e6, 3.0], [0.0, 0.0, -1.0]][k % 4]
        position = [k * 3e-3, -k * 1e-3, 0.04] if k < 5 else [0.012, -0.004, 0.04]  # stands still from step 5
        q = rng.normal(size=4)
        planned = rng.normal(scale=0.1, size=(4, 3)) if footholds else None
        frame = track.frame(t, position, q / np.linalg.norm(q), [k * 2e-3, 0.0, 0.04], legs, forces, planned)
        changed = []
        for key, path in (("reference", frame.reference_path), ("actual", frame.actual_path)):
            if last.get(key) is not path:
                last[key] = path
                changed.append(key)
        due = [key for key in PATH_TOPICS if key in changed or t - made.get(key, -1e9) >= 1.0]
        made.update({key: t for key in due})
        lengths.append(len(frame.reference_path))
        expected = {
            SCENE_TOPIC: sdk_scene.scene_update(frame),
            **{PATH_TOPICS[key]: sdk_scene.path_update(frame, key) for key in PATH_TOPICS},
        }
        for encoder, paths in ((logged, changed), (live, due)):
            messages = encoder.messages(frame)
            assert [topic for topic, _ in messages] == [SCENE_TOPIC, *(PATH_TOPICS[key] for key in paths)]
            for topic, data in messages:
                assert scene_cls.FromString(data) == scene_cls.FromString(expected[topic].encode()), (k, topic)
        tf_bytes = transforms.message(t, frame.position, frame.quaternion_wxyz)
        assert tf_cls.FromString(tf_bytes) == tf_cls.FromString(sdk_scene.frame_transforms(frame).encode()), k
        written.append(changed)
    assert 3 in lengths and min(lengths[lengths.index(3) :]) < 3  # grew and was thinned
    assert "actual" not in written[-1] and "actual" not in written[-2]  # stood still: the log writes nothing
    assert made["actual"] == 12345.678901  # the live view resent it once a second had passed


def _frames(stop: threading.Event, view: LiveView, rec: Recorder | None = None) -> None:
    """The closed loop's scene, published until ``stop`` (as a run would, one step after another)."""
    track = SceneTrack(LEGS, [0.1, 0.08, 0.03])
    legs = np.linspace([0, 0, 0], [0.1, 0, -0.04], 31)[None].repeat(4, axis=0)
    k = 0
    while not stop.is_set() and k < 3000:
        view.write("/cost", k / 30, {"stage": 0.5})
        view.write_pose(k / 30, [0, 0, 0.04], [1, 0, 0, 0])
        view.write_scene(track.frame(k / 30, [0, 0, 0.04], [1, 0, 0, 0], [0, 0, 0.04], legs, np.ones((4, 3))))
        k += 1
        stop.wait(0.005)


def test_live_server_advertises_and_streams_the_scene_to_a_client() -> None:
    with LiveView(port=0) as view:
        stop = threading.Event()
        # no client yet: publishing must not block (the first steps create and advertise the channels)
        track = SceneTrack(LEGS, [0.1, 0.08, 0.03])
        legs = np.zeros((4, 31, 3))
        view.write("/cost", 0.0, {"stage": 0.5})
        view.write_scene(track.frame(0.0, [0, 0, 0.04], [1, 0, 0, 0], [0, 0, 0], legs, np.ones((4, 3))))
        publisher = threading.Thread(target=_frames, args=(stop, view), daemon=True)
        publisher.start()
        try:
            with connect(
                f"ws://127.0.0.1:{view.port}",
                subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
                open_timeout=10,
            ) as ws:
                assert ws.subprotocol == "foxglove.sdk.v1"
                channels: dict[str, dict] = {}
                while SCENE_TOPIC not in channels or "/cost" not in channels:
                    msg = ws.recv(timeout=10)
                    if isinstance(msg, str) and json.loads(msg)["op"] == "advertise":
                        channels.update({c["topic"]: c for c in json.loads(msg)["channels"]})
                scene = channels[SCENE_TOPIC]
                assert (scene["encoding"], scene["schemaName"]) == ("protobuf", "foxglove.SceneUpdate")
                assert {TRANSFORMS_TOPIC, "/torso/pose", *PATH_TOPICS.values()} <= set(channels)
                ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": scene["id"]}]}))
                while True:
                    msg = ws.recv(timeout=10)
                    if isinstance(msg, bytes) and msg[0] == 0x01:
                        break
                sub_id, _stamp = struct.unpack_from("<IQ", msg, 1)
                assert sub_id == 7
                cls = message_class("foxglove.SceneUpdate", base64.b64decode(scene["schema"]))
                update = cls.FromString(msg[13:])
                legs_seen = [e for e in update.entities if e.id.startswith("leg/")]
                assert len(legs_seen) == 4 and all(len(e.lines[0].points) == 31 for e in legs_seen)
        finally:
            stop.set()
            publisher.join(timeout=10)


def test_a_busy_live_port_is_a_one_line_config_error() -> None:
    with LiveView(port=0) as first:
        with pytest.raises(ConfigError, match=f"cannot listen on 127.0.0.1:{first.port}.*live_port"):
            LiveView(port=first.port)


def test_tee_writes_the_same_steps_to_the_log_and_the_view(tmp_path: Path) -> None:
    cfg = load("experiment=simulate")
    with Recorder(tmp_path / "a.mcap") as rec, LiveView(port=0) as view:
        run_closed_loop(cfg, cfg.scenarios["baseline"], 0.2, Tee(rec, view))
    log = read_log(tmp_path / "a.mcap")
    assert len(log["/state"]) == 6 and set(log.scene_topics) == set(schemas())


def test_shipped_layout_is_the_built_one_and_plots_only_what_a_run_logs(soft_log: Path, tmp_path: Path) -> None:
    from slotexp.layout import SHIPPED, layout_json, plotted_paths
    from tests.helpers import ok, slot

    assert SHIPPED.read_text() == layout_json()  # regenerate with slotexp.layout after changing it
    log = read_log(soft_log)
    for path in plotted_paths():
        topic, _, field = path.partition(".")
        column = field.replace("[", ".").replace("]", "")
        assert topic in log and column in log[topic].columns, path
    out = tmp_path / "sub" / "layout.json"
    proc = ok(slot("layout", out, cwd=tmp_path))
    assert proc.stdout.strip().splitlines()[-1] == str(out)
    layout = json.loads(out.read_text())
    panels = json.dumps(layout)
    assert '"panelType": "ThreeDee"' in panels and '"/scene"' in panels
    bad = slot("layout", tmp_path, cwd=tmp_path)
    assert bad.returncode == 2 and bad.stderr.startswith("error: ") and "Traceback" not in bad.stderr
    # a named pipe (or /dev/null) is left as it is: the atomic write would have renamed a file over it
    pipe = tmp_path / "pipe.json"
    os.mkfifo(pipe)
    assert_one_line_error(slot("layout", pipe, cwd=tmp_path), "not a regular file")
    assert stat.S_ISFIFO(pipe.lstat().st_mode)
    assert_one_line_error(slot("layout", tmp_path / ("a" * 300 + ".json"), cwd=tmp_path), "File name too long")


def test_the_live_view_waits_for_a_viewer_then_paces_the_run_and_lingers() -> None:
    # A simulation runs far faster than real time: the view holds the first step until a viewer subscribes
    # (wait_s), then keeps simulated time at `pace` times wall time, and stays open linger_s at the end.
    steps, dt, pace = 21, 0.05, 4.0  # 1 s simulated: 0.25 s of wall time at pace 4
    done: dict[str, float] = {}
    with LiveView(port=0, pace=pace, wait_s=30.0, linger_s=0.5) as view:
        view.write("/cost", 0.0, {"stage": 0.5})  # the channel a viewer can subscribe to

        def publish() -> None:
            for k in range(steps):
                view.write("/cost", k * dt, {"stage": 0.5})
                view.write_pose(k * dt, [0, 0, 0.04], [1, 0, 0, 0])
            done["t"] = time.monotonic()

        publisher = threading.Thread(target=publish, daemon=True)
        publisher.start()
        time.sleep(0.5)
        assert publisher.is_alive() and not done, "the run went on before anyone watched"
        with connect(
            f"ws://127.0.0.1:{view.port}",
            subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
            open_timeout=10,
            close_timeout=0.5,  # the server lets a client's close handshake time out; nothing to wait for
        ) as ws:
            channels: dict[str, dict] = {}
            while "/cost" not in channels:
                msg = ws.recv(timeout=10)
                if isinstance(msg, str) and json.loads(msg)["op"] == "advertise":
                    channels.update({c["topic"]: c for c in json.loads(msg)["channels"]})
            started = time.monotonic()
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": channels["/cost"]["id"]}]}))
            publisher.join(timeout=30)
            assert done["t"] - started >= (steps - 1) * dt / pace * 0.9  # paced, not flat out
        closing = time.monotonic()
    assert time.monotonic() - closing >= 0.45  # it lingered for the viewer


def test_the_torso_box_is_drawn_about_its_own_centre_not_the_mass_centre() -> None:
    # robot.torso.com_offset puts the mass centre (the pose) 15 mm behind the box's centre: turned 90 deg
    # left, the box's centre is 15 mm to the world's +y of the pose, in the scene's cube and the GIF's box
    from slotexp.figures.animation import _box

    yaw = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])
    pose = np.array([1.0, 2.0, 0.04])
    track = SceneTrack(LEGS, [0.1255, 0.0855, 0.034], com_offset=[-0.015, 0.0])
    frame = track.frame(0.0, pose, yaw, pose, np.zeros((4, 3, 3)), np.ones((4, 3)))
    np.testing.assert_allclose(frame.box_centre, [1.0, 2.015, 0.04], atol=1e-12)
    np.testing.assert_allclose(frame.position, pose)  # the pose itself (paths, transforms) is the mass centre
    scene_cls = message_class("foxglove.SceneUpdate", schemas()[SCENE_TOPIC].data)
    cube = scene_cls.FromString(SceneEncoder().messages(frame)[0][1]).entities[0].cubes[0]
    assert [cube.pose.position.x, cube.pose.position.y, cube.pose.position.z] == pytest.approx([1.0, 2.015, 0.04])
    corners = _box(pose, yaw, np.array([0.1255, 0.0855, 0.034]), np.array([-0.015, 0.0, 0.0]))
    np.testing.assert_allclose(corners.mean(axis=0), [1.0, 2.015, 0.04], atol=1e-12)
    plain = SceneTrack(LEGS, [0.1255, 0.0855, 0.034]).frame(0.0, pose, yaw, pose, np.zeros((4, 3, 3)), np.ones((4, 3)))
    np.testing.assert_allclose(plain.box_centre, pose)
