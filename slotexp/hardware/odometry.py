"""State-estimate sources behind one interface: ZeroMQ (the VIO stack), MCAP replay, the simulator.

Each source hands the loop its newest :class:`OdometrySample`: the MPC state
``[roll, pitch, yaw, p, omega_world, v]`` plus the pose it came from and the local
monotonic time it arrived. The loop judges staleness from that arrival time, so a
clock offset between the VIO computer and this one cannot hide a dead estimator.

ZeroMQ message (one JSON object per message, single frame)::

    {"t": 12.345, "position": [x, y, z], "orientation": [qx, qy, qz, qw],
     "linear_velocity": [vx, vy, vz], "angular_velocity": [wx, wy, wz]}

position and linear velocity in the world frame (z up), orientation body -> world,
angular velocity in the body frame (what an IMU / ROS ``nav_msgs/Odometry`` twist
gives); it is rotated to the world frame the MPC state uses.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from .. import telemetry as T
from ..body import euler_to_quat, quat_to_euler, quat_to_rot
from ..errors import UserError


@dataclass
class OdometrySample:
    state: np.ndarray  # (12,) MPC state
    position: np.ndarray  # (3,) world
    quaternion: np.ndarray  # (4,) w, x, y, z, body -> world
    stamp: float  # the source's own time (message t, log time, sim time)
    received: float  # local monotonic time of arrival


class OdometrySource(Protocol):
    name: str
    bad_messages: int

    def start(self) -> None:
        """Connect / load; raise :class:`UserError` if that is impossible."""

    def latest(self) -> OdometrySample | None:
        """The newest sample so far (None before the first)."""

    @property
    def finished(self) -> bool:
        """True when the source has no more data by design (a replay that reached its end)."""

    def close(self) -> None: ...


ROOM_M = 100.0  # m: an odometry position farther from its origin is not this robot's (units, or a fault)
MAX_SPEED = 5.0  # m/s: SLOT walks at tens of mm/s


def _vec(msg: Mapping[str, Any], key: str, n: int) -> np.ndarray:
    value = msg.get(key)
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise ValueError(f"{key!r} must be a list of {n} numbers")
    arr = np.array([float(v) for v in value])
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{key!r} has a non-finite entry")
    return arr


def sample_from_message(msg: Any, received: float) -> OdometrySample:
    """Decode one odometry message (a dict) into a sample; ValueError says what is wrong with it."""
    if not isinstance(msg, Mapping):
        raise ValueError("message is not a JSON object")
    try:
        stamp = float(msg["t"])
    except (KeyError, TypeError, ValueError):
        raise ValueError("'t' must be a number (seconds)") from None
    p = _vec(msg, "position", 3)
    if float(np.max(np.abs(p))) > ROOM_M:
        raise ValueError(
            f"'position' {p.tolist()} is beyond a room ({ROOM_M:g} m from the origin): positions are in metres"
        )
    qx, qy, qz, qw = _vec(msg, "orientation", 4)
    v = _vec(msg, "linear_velocity", 3)
    if float(np.linalg.norm(v)) > MAX_SPEED:
        raise ValueError(f"'linear_velocity' {v.tolist()} is faster than {MAX_SPEED:g} m/s: velocities are in m/s")
    w_body = _vec(msg, "angular_velocity", 3)
    q = np.array([qw, qx, qy, qz])
    norm = float(np.linalg.norm(q))
    if not 0.5 < norm < 1.5:
        raise ValueError(f"'orientation' is not a unit quaternion (norm {norm:.3g})")
    q = q / norm
    omega_world = quat_to_rot(q) @ w_body
    state = np.concatenate([quat_to_euler(q), p, omega_world, v])
    return OdometrySample(
        state=state, position=p, quaternion=q, stamp=stamp if math.isfinite(stamp) else 0.0, received=received
    )


def sample_from_state(x: np.ndarray, stamp: float, received: float) -> OdometrySample:
    """A sample from an MPC state (replay, simulator)."""
    x = np.asarray(x, dtype=float)
    return OdometrySample(
        state=x.copy(), position=x[3:6].copy(), quaternion=euler_to_quat(*x[0:3]), stamp=stamp, received=received
    )


class ZmqOdometry:
    """SUB socket with CONFLATE: the queue holds only the newest message, so the loop never lags the VIO."""

    name = "zmq"

    def __init__(self, endpoint: str, bind: bool = False, clock: Callable[[], float] = time.monotonic) -> None:
        self.endpoint = endpoint
        self.bind = bind
        self.clock = clock
        self.bad_messages = 0
        self.last_problem = ""
        self._sample: OdometrySample | None = None
        self._ctx = None
        self._sock = None

    def start(self) -> None:
        import zmq

        self._ctx = zmq.Context()
        sock = self._ctx.socket(zmq.SUB)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.CONFLATE, 1)  # must precede connect/bind
        sock.setsockopt(zmq.SUBSCRIBE, b"")
        try:
            (sock.bind if self.bind else sock.connect)(self.endpoint)
        except zmq.ZMQError as exc:
            sock.close(0)
            raise UserError(
                f"odometry.endpoint {self.endpoint}: cannot {'bind' if self.bind else 'connect'}: {exc}"
            ) from None
        self._sock = sock

    def latest(self) -> OdometrySample | None:
        import zmq

        while True:
            try:
                data = self._sock.recv(zmq.NOBLOCK)
            except zmq.Again:
                return self._sample
            now = self.clock()
            try:
                self._sample = sample_from_message(json.loads(data), now)
            except (ValueError, UnicodeDecodeError) as exc:  # json.JSONDecodeError is a ValueError
                self.bad_messages += 1
                self.last_problem = str(exc).splitlines()[0]

    @property
    def finished(self) -> bool:
        return False

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close(0)
            self._sock = None
        if self._ctx is not None:
            self._ctx.term()
            self._ctx = None


class ReplayOdometry:
    """The /state topic of an MCAP log, replayed in real time from :meth:`start`."""

    name = "replay"

    def __init__(self, path: str, clock: Callable[[], float] = time.monotonic) -> None:
        self.path = path
        self.clock = clock
        self.bad_messages = 0
        self._t = np.zeros(0)
        self._x = np.zeros((0, 12))
        self._t0 = 0.0
        self._index = -1
        self._sample: OdometrySample | None = None

    def start(self) -> None:
        from ..record import LogReadError, read_log
        from ..runlog import find_logs

        path = Path(self.path).expanduser()
        logs = find_logs(path) if path.exists() else []
        if not logs:
            raise UserError(f"odometry.path = {self.path}: no .mcap log there (give a run directory or an .mcap file)")
        try:
            log = read_log(logs[0])
        except LogReadError as exc:
            raise UserError(str(exc)) from None
        if T.STATE not in log or len(log[T.STATE]) == 0:
            raise UserError(f"{logs[0]}: the log has no /state messages to replay")
        df = log[T.STATE]
        self._t = df["t"].to_numpy(float)
        self._x = df[[f"{f}.{i}" for f in T.STATE_FIELDS for i in range(3)]].to_numpy(float)
        self._t0 = self.clock()

    def latest(self) -> OdometrySample | None:
        elapsed = self.clock() - self._t0
        k = int(np.searchsorted(self._t - self._t[0], elapsed, side="right")) - 1
        if k >= 0 and k != self._index:
            self._index = k
            self._sample = sample_from_state(self._x[k], float(self._t[k]), self._t0 + self._t[k] - self._t[0])
        return self._sample

    @property
    def finished(self) -> bool:
        return len(self._t) > 0 and self.clock() - self._t0 > self._t[-1] - self._t[0]

    def close(self) -> None:
        pass


class SimOdometry:
    """The simulator's true state, fresh at every call (HIL)."""

    name = "sim"

    def __init__(self, world: Any) -> None:
        self.world = world
        self.bad_messages = 0

    def start(self) -> None:
        pass

    def latest(self) -> OdometrySample | None:
        self.world.sync()
        return sample_from_state(self.world.plant.state(), self.world.sim_time, self.world.clock())

    @property
    def finished(self) -> bool:
        return False

    def close(self) -> None:
        pass


def wait_first(
    source: OdometrySource,
    timeout_s: float,
    stopped: Callable[[], bool],
    clock: Callable[[], float] = time.monotonic,
    poll_s: float = 0.01,
) -> OdometrySample | None:
    """Block until the first sample; None if a stop was requested; UserError after ``timeout_s``."""
    deadline = clock() + timeout_s
    while True:
        sample = source.latest()
        if sample is not None:
            return sample
        if stopped():
            return None
        if clock() > deadline:
            where = getattr(source, "endpoint", source.name)
            extra = ""
            if source.bad_messages:
                extra = f"; {source.bad_messages} unreadable message(s), last: {getattr(source, 'last_problem', '')}"
            raise UserError(
                f"no odometry from {where} within {timeout_s:g} s (odometry.startup_timeout_s): "
                f"is the VIO publisher running?{extra}"
            )
        time.sleep(poll_s)
