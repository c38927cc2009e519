"""Pure pieces of `slot hardware`: its config, the tendon->servo mapping, odometry decoding, deadlines."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from slotexp.body import euler_to_quat, quat_to_rot
from slotexp.errors import ConfigError
from slotexp.hardware import xl430
from slotexp.hardware.config import HardwareConfig
from slotexp.hardware.mapping import ServoMap
from slotexp.hardware.odometry import sample_from_message
from slotexp.hardware.timing import Deadlines, LoopStats
from tests.helpers import CONF, load, load_hardware


# --------------------------------------------------------------------------- config
def test_hardware_config_composes_with_the_simulation_settings() -> None:
    cfg = load_hardware()
    assert cfg.experiment.name == "hardware" and cfg.duration is None and cfg.dry_run is False
    assert cfg.hardware.ids == [1, 2, 3, 4] and cfg.hardware.model_number == 1060
    assert cfg.hardware.rate_hz == cfg.mpc.rate_hz == 30.0
    assert cfg.odometry.source == "zmq"
    sim = load("experiment=simulate")
    # hardware_config.yaml repeats conf/config.yaml's group defaults and relies on the schema defaults for
    # mpc/sim: a live run must use the controller settings a simulation uses unless told otherwise
    for part in ("mpc", "sim", "robot", "gait", "solver", "plant"):
        assert getattr(cfg, part) == getattr(sim, part), f"{part}: keep conf/hardware_config.yaml in step"


@pytest.mark.parametrize(
    "override, words",
    [
        ("hardware.rate_hz=50", ["hardware.rate_hz", "mpc.rate_hz"]),
        ("hardware.watchdog_ms=90", ["watchdog_ms", "multiple of 20"]),
        ("hardware.watchdog_ms=40", ["watchdog_ms", "two loop periods"]),
        ("hardware.ids=[1,2,2,4]", ["hardware.ids", "repeats"]),
        ("hardware.ids=[1,2,3]", ["hardware.ids", "exactly 4"]),
        ("robot.servo.horn_direction=[1,0,1,1]", ["hardware.direction[1]"]),
        ("hardware.zero_offset_deg=[96,96,96,96]", ["hardware.zero_offset_deg", "robot.servo.horn_zero_deg"]),
        ("hardware.baudrate=12345", ["hardware.baudrate", "1000000"]),
        ("robot.servo.horn_min_deg=[130,355,130,130]", ["robot.servo.horn_min_deg", "RL"]),
        ("robot.servo.horn_max_deg=[250,250,250,400]", ["horn_max_deg[3]"]),
        ("odometry=replay", ["odometry.path"]),
        ("odometry.endpoint=localhost:5556", ["odometry.endpoint"]),
        ("odometry.max_age_s=0", ["odometry.max_age_s"]),
        ("duration=-1", ["duration"]),
    ],
)
def test_bad_values_fail_with_one_line_naming_the_key(override: str, words: list[str]) -> None:
    with pytest.raises(ConfigError) as err:
        load_hardware(override)
    text = str(err.value)
    assert "\n" not in text
    for w in words:
        assert w in text, text


def test_schema_defaults_come_from_the_control_table_module() -> None:
    hw = HardwareConfig()
    assert hw.model_number == xl430.MODEL_NUMBER == 1060
    assert hw.watchdog_ms % xl430.WATCHDOG_UNIT_MS == 0


# --------------------------------------------------------------------------- control table
def test_sync_transactions_span_contiguous_items_only() -> None:
    # Present Load, Velocity and Position: one 10-byte sync read from 126 (XL430-W250 e-Manual)
    assert xl430.span(xl430.PRESENT_BLOCK) == (xl430.PRESENT_BLOCK_ADDR, xl430.PRESENT_BLOCK_LEN) == (126, 10)
    assert xl430.span(["Goal_Position"]) == (116, 4)
    with pytest.raises(ValueError, match="not contiguous"):
        xl430.span(["Goal_Position", "Present_Position"])
    with pytest.raises(ValueError, match="not contiguous"):
        xl430.span(["Present_Load", "Present_Position"])  # a gap: Present Velocity left out


# --------------------------------------------------------------------------- mapping
def test_tendon_to_servo_mapping_is_the_documented_formula() -> None:
    cfg = load_hardware(
        "robot.servo.horn_direction=[1,-1,1,-1]",
        "robot.servo.horn_zero_deg=[130,250,130,250]",
        "robot.servo.horn_min_deg=[130,130,130,130]",
        "robot.servo.horn_max_deg=[250,250,250,250]",
    )
    smap = ServoMap.from_config(cfg.hardware, cfg.robot.leg.tendon_max_deg)
    theta = np.array([0.0, 50.0, 100.0, 116.28])
    ticks, clamped = smap.to_ticks(theta)
    zero = np.array([130.0, 250.0, 130.0, 250.0])
    sign = np.array([1, -1, 1, -1])
    assert np.array_equal(ticks, np.rint((zero + sign * theta) * 4096 / 360).astype(int))
    assert not clamped.any()
    assert np.allclose(smap.to_tendon_deg(ticks), theta, atol=360 / 4096)


def test_every_command_is_clamped_to_the_servo_limits() -> None:
    cfg = load_hardware("robot.servo.horn_max_deg=[200,255,255,255]")
    smap = ServoMap.from_config(cfg.hardware, cfg.robot.leg.tendon_max_deg)
    ticks, clamped = smap.to_ticks(np.array([100.0, 150.0, -130.0, np.nan]))
    assert ticks[0] == round(200 * 4096 / 360) and clamped[0]  # servo limit
    assert ticks[1] == round(255 * 4096 / 360) and clamped[1]  # the horn's upper limit
    assert ticks[2] == round(10 * 4096 / 360) and clamped[2]  # slack below the zero, down to the lower limit
    assert ticks[3] == round(130 * 4096 / 360) and clamped[3]  # a NaN never reaches the servo: the zero
    slack, _ = smap.to_ticks(np.array([-25.0, 0.0, 0.0, 0.0]))
    assert slack[0] == round(105 * 4096 / 360)  # the robot's own "step height" horn angle, 25 deg below the zero
    lo, hi = smap.tendon_range_deg()
    assert hi[0] == pytest.approx(70.0, abs=0.1) and hi[1] == pytest.approx(125.0, abs=0.1)
    assert lo[0] == pytest.approx(-120.0, abs=0.1)


# --------------------------------------------------------------------------- odometry
def test_odometry_message_to_mpc_state() -> None:
    rpy = np.array([0.1, -0.2, 0.7])
    q = euler_to_quat(*rpy)  # w, x, y, z
    w_body = np.array([0.3, -0.1, 0.2])
    msg = json.loads(
        json.dumps(
            {
                "t": 5.0,
                "position": [1, 2, 0.04],
                "orientation": [q[1], q[2], q[3], q[0]],
                "linear_velocity": [0.1, 0.0, -0.01],
                "angular_velocity": list(w_body),
            }
        )
    )
    s = sample_from_message(msg, received=123.0)
    assert np.allclose(s.state[0:3], rpy)
    assert np.allclose(s.state[3:6], [1, 2, 0.04])
    assert np.allclose(s.state[6:9], quat_to_rot(q) @ w_body)  # body rates -> world frame
    assert np.allclose(s.state[9:12], [0.1, 0.0, -0.01])
    assert np.allclose(s.quaternion, q) and s.stamp == 5.0 and s.received == 123.0


@pytest.mark.parametrize(
    "msg",
    [
        [1, 2],
        {"position": [0, 0, 0]},
        {
            "t": 0,
            "position": [0, 0],
            "orientation": [0, 0, 0, 1],
            "linear_velocity": [0, 0, 0],
            "angular_velocity": [0, 0, 0],
        },
        {
            "t": 0,
            "position": [0, 0, 0],
            "orientation": [0, 0, 0, 0],
            "linear_velocity": [0, 0, 0],
            "angular_velocity": [0, 0, 0],
        },
        {
            "t": 0,
            "position": [0, 0, None],
            "orientation": [0, 0, 0, 1],
            "linear_velocity": [0, 0, 0],
            "angular_velocity": [0, 0, 0],
        },
    ],
)
def test_malformed_odometry_is_rejected(msg) -> None:
    with pytest.raises((ValueError, TypeError)):
        sample_from_message(msg, 0.0)


@pytest.mark.parametrize(
    ("key", "value", "words"),
    [("position", [1e300, 0, 0.04], "beyond a room"), ("position", [1500.0, 0, 40.0], "beyond a room"),
     ("linear_velocity", [0, 20.0, 0], "faster than 5 m/s")],
)  # fmt: skip
def test_odometry_out_of_a_rooms_scale_is_refused_with_its_units(key, value, words) -> None:
    # x = 1e300 m once ran the whole hardware loop and reported speed 0; a position in mm reads 1000x too far
    msg = {"t": 0, "position": [0, 0, 0.04], "orientation": [0, 0, 0, 1], "linear_velocity": [0, 0, 0]}
    msg |= {"angular_velocity": [0, 0, 0], key: value}
    with pytest.raises(ValueError, match=words):
        sample_from_message(msg, 0.0)


# --------------------------------------------------------------------------- deadlines
class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        assert s >= 0
        self.now += s


def test_deadlines_do_not_drift_and_count_overruns() -> None:
    clock = FakeClock()
    d = Deadlines(0.1, clock, clock.sleep)
    d.start()
    starts = []
    for work in [0.03, 0.05, 0.13, 0.01, 0.02, 0.35, 0.01]:
        starts.append(clock.now)
        clock.now += work
        d.wait_next()
    # on time: cycles start on the 0.1 s grid; a late cycle runs at once; a cycle >1 period late skips
    assert starts[:3] == pytest.approx([0.0, 0.1, 0.2])
    assert starts[3] == pytest.approx(0.33)  # 0.2 + 0.13: late, started immediately
    assert starts[4] == pytest.approx(0.4)  # back on the grid
    assert starts[5] == pytest.approx(0.5)
    assert starts[6] == pytest.approx(0.85)  # 0.5 + 0.35: deadlines 0.6 and 0.7 skipped, the 0.8 one runs late
    assert d.overruns == 2 and d.skipped == 2
    stats = LoopStats(0.1)
    for s in starts:
        stats.add(s, 0.01, 0.0, 0.0)
    assert stats.summary()["achieved_rate_hz"] == pytest.approx(6 / 0.85)


def test_config_files_exist_for_every_option() -> None:
    conf = Path(CONF)
    assert sorted(p.stem for p in (conf / "odometry").glob("*.yaml")) == ["replay", "sim", "zmq"]
    assert (conf / "hardware" / "xl430.yaml").is_file() and (conf / "hardware_config.yaml").is_file()


def test_warm_up_leaves_the_controller_as_it_was() -> None:
    from slotexp.controllers.paper import PaperController as Controller
    from slotexp.hardware.odometry import sample_from_state
    from slotexp.hardware.run import warm_up
    from slotexp.plants import nominal_state
    from slotexp.robot import build_robot

    cfg = load_hardware()
    robot = build_robot(cfg.robot)
    x = nominal_state(robot)
    fresh, warmed = Controller(cfg, robot), Controller(cfg, robot)
    warm_up(warmed, robot, sample_from_state(x, 0.0, 0.0))
    feet = x[3:6] + robot.feet_body
    for k in range(20):  # same gait phase, same commands, step for step
        a, b = fresh.step(k / 30, x, feet), warmed.step(k / 30, x, feet)
        assert np.array_equal(a.plan.stance, b.plan.stance)
        assert np.allclose(a.tendon_deg, b.tendon_deg, atol=1e-2)
    assert fresh.infeasible_steps == warmed.infeasible_steps
