"""A Dynamixel Protocol 2.0 servo bus emulator on a pseudo-terminal (XL430-W250 control table).

Why: the hardware code must be tested against the real ``dynamixel-sdk`` (no mocks),
so this module plays the other end of the wire. It opens a pty pair; the SDK's
``PortHandler`` opens the *slave* path with pyserial exactly as it opens
``/dev/ttyUSB0``, and a thread here answers on the master side, byte for byte:

* instruction packets ``FF FF FD 00 | ID | LEN_L LEN_H | INST | params | CRC_L CRC_H``,
  byte stuffing (``FF FF FD`` -> ``FF FF FD FD`` in the body), CRC-16 (polynomial
  0x8005, the Dynamixel table);
* ping, read, write, sync read, sync write, reboot; status packets (0x55) with the
  error byte (alert bit 0x80 while Hardware Error Status is non-zero);
* a per-ID XL430 control table (EEPROM area locked while torque is on, read-only
  items, model number 1060), goal-position limits, a simple motion model
  (present position moves to the goal at the profile velocity while torque is on);
* the bus watchdog: with Bus Watchdog > 0 and torque on, no instruction for
  ``watchdog * 20 ms`` sets Bus Watchdog to 0xFF (-1, the error flag) and the
  emulator turns torque off (the observable "servo stopped"; a real XL430 holds
  position and refuses new goals, which the emulator also does until 98 is
  cleared);
* fault injection for tests: dropped, corrupted (bad CRC), garbage and truncated
  replies, and silent IDs.

Every applied or refused register write is recorded so tests can check what
reached the servos.
"""

from __future__ import annotations

import os
import random
import select
import threading
import time
import tty
from dataclasses import dataclass, field

INST_PING, INST_READ, INST_WRITE, INST_REBOOT = 0x01, 0x02, 0x03, 0x08
INST_SYNC_READ, INST_SYNC_WRITE, INST_STATUS = 0x82, 0x83, 0x55
BROADCAST = 0xFE
ERR_RESULT_FAIL, ERR_INSTRUCTION, ERR_CRC, ERR_DATA_RANGE = 1, 2, 3, 4
ERR_DATA_LENGTH, ERR_DATA_LIMIT, ERR_ACCESS = 5, 6, 7
ALERT = 0x80
XL430_MODEL = 1060
HEADER = b"\xff\xff\xfd\x00"

# XL430-W250 control table: name -> (address, size, access, initial value, signed)
CONTROL_TABLE: dict[str, tuple[int, int, str, int, bool]] = {
    "model_number": (0, 2, "R", XL430_MODEL, False),
    "model_information": (2, 4, "R", 0, False),
    "firmware_version": (6, 1, "R", 46, False),
    "id": (7, 1, "RW", 1, False),
    "baud_rate": (8, 1, "RW", 3, False),
    "return_delay_time": (9, 1, "RW", 0, False),
    "drive_mode": (10, 1, "RW", 0, False),
    "operating_mode": (11, 1, "RW", 3, False),
    "secondary_id": (12, 1, "RW", 255, False),
    "protocol_type": (13, 1, "RW", 2, False),
    "homing_offset": (20, 4, "RW", 0, True),
    "moving_threshold": (24, 4, "RW", 10, False),
    "temperature_limit": (31, 1, "RW", 72, False),
    "max_voltage_limit": (32, 2, "RW", 140, False),
    "min_voltage_limit": (34, 2, "RW", 60, False),
    "pwm_limit": (36, 2, "RW", 885, False),
    "velocity_limit": (44, 4, "RW", 265, False),
    "max_position_limit": (48, 4, "RW", 4095, False),
    "min_position_limit": (52, 4, "RW", 0, False),
    "startup_configuration": (60, 1, "RW", 0, False),
    "shutdown": (63, 1, "RW", 52, False),
    "torque_enable": (64, 1, "RW", 0, False),
    "led": (65, 1, "RW", 0, False),
    "status_return_level": (68, 1, "RW", 2, False),
    "registered_instruction": (69, 1, "R", 0, False),
    "hardware_error_status": (70, 1, "R", 0, False),
    "velocity_i_gain": (76, 2, "RW", 1000, False),
    "velocity_p_gain": (78, 2, "RW", 100, False),
    "position_d_gain": (80, 2, "RW", 4000, False),
    "position_i_gain": (82, 2, "RW", 0, False),
    "position_p_gain": (84, 2, "RW", 640, False),
    "feedforward_2nd_gain": (88, 2, "RW", 0, False),
    "feedforward_1st_gain": (90, 2, "RW", 0, False),
    "bus_watchdog": (98, 1, "RW", 0, True),
    "goal_pwm": (100, 2, "RW", 885, True),
    "goal_velocity": (104, 4, "RW", 0, True),
    "profile_acceleration": (108, 4, "RW", 0, False),
    "profile_velocity": (112, 4, "RW", 0, False),
    "goal_position": (116, 4, "RW", 2048, True),
    "realtime_tick": (120, 2, "R", 0, False),
    "moving": (122, 1, "R", 0, False),
    "moving_status": (123, 1, "R", 0, False),
    "present_pwm": (124, 2, "R", 0, True),
    "present_load": (126, 2, "R", 0, True),
    "present_velocity": (128, 4, "R", 0, True),
    "present_position": (132, 4, "R", 2048, True),
    "velocity_trajectory": (136, 4, "R", 0, True),
    "position_trajectory": (140, 4, "R", 0, True),
    "present_input_voltage": (144, 2, "R", 120, False),
    "present_temperature": (146, 1, "R", 30, False),
    "backup_ready": (147, 1, "R", 0, False),
}
TABLE_SIZE = 148
EEPROM_END = 64
_BY_ADDR = {spec[0]: (name, *spec[1:]) for name, spec in CONTROL_TABLE.items()}
RPM_PER_UNIT = 0.229
MAX_RPM = 61.0  # XL430-W250 no-load speed at 12 V


def _crc_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray) -> int:
    """Dynamixel CRC-16 (poly 0x8005, init 0, no reflection)."""
    crc = 0
    for b in data:
        crc = ((crc << 8) ^ CRC_TABLE[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def stuff(prefix: bytes, body: bytes) -> bytes:
    """Insert FD after every FF FF FD in ``body`` (``prefix`` is what precedes it on the wire)."""
    out = bytearray(prefix)
    for b in body:
        out.append(b)
        if b == 0xFD and out[-2] == 0xFF and out[-3] == 0xFF and len(out) - len(prefix) >= 1:
            out.append(0xFD)
    return bytes(out[len(prefix) :])


def unstuff(raw: bytes, start: int, end: int) -> bytes:
    """Remove the stuffing FD from raw[start:end] (looking back into raw for the FF FF FD pattern)."""
    out = bytearray()
    for j in range(start, end):
        if raw[j] == 0xFD and j >= 3 and raw[j - 1] == 0xFD and raw[j - 2] == 0xFF and raw[j - 3] == 0xFF:
            continue
        out.append(raw[j])
    return bytes(out)


def packet(servo_id: int, body: bytes) -> bytes:
    """A complete packet (header, stuffed body, CRC) for ``body`` = instruction + params."""
    stuffed = stuff(HEADER + bytes([servo_id, 0, 0]), body)
    n = len(stuffed) + 2
    head = HEADER + bytes([servo_id, n & 0xFF, n >> 8])
    crc = crc16(head + stuffed)
    return head + stuffed + bytes([crc & 0xFF, crc >> 8])


@dataclass
class WriteRecord:
    """One register write as it reached a servo."""

    t: float
    instruction: str  # "write" or "sync_write"
    servo_id: int
    address: int
    data: bytes
    accepted: bool
    error: int


@dataclass
class Fault:
    kind: str  # drop | corrupt | garbage | truncate
    remaining: int
    servo_id: int | None = None
    instruction: int | None = None


@dataclass
class Servo:
    """One XL430's control table and motion state."""

    servo_id: int
    model: int = XL430_MODEL
    table: bytearray = field(default_factory=lambda: bytearray(TABLE_SIZE))
    last_seen: float = 0.0
    position: float = 2048.0  # ticks, continuous
    watchdog_trips: int = 0
    torque_history: list[int] = field(default_factory=list)

    def __post_init__(self) -> None:
        for addr, size, _acc, value, _signed in CONTROL_TABLE.values():
            self.table[addr : addr + size] = (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")
        self.set("model_number", self.model)
        self.set("id", self.servo_id)
        self.last_seen = time.monotonic()

    def get(self, name: str) -> int:
        addr, size, _acc, _init, signed = CONTROL_TABLE[name]
        return int.from_bytes(self.table[addr : addr + size], "little", signed=signed)

    def set(self, name: str, value: int) -> None:
        addr, size, _acc, _init, _signed = CONTROL_TABLE[name]
        self.table[addr : addr + size] = (int(value) & ((1 << (8 * size)) - 1)).to_bytes(size, "little")
        if name == "torque_enable":
            self.torque_history.append(int(value))

    @property
    def error_byte(self) -> int:
        return ALERT if self.get("hardware_error_status") else 0


class ServoEmulator:
    """Emulated XL430 servos behind a pty; use as a context manager. ``port`` is the path to give the SDK."""

    def __init__(
        self,
        ids: list[int] = (1, 2, 3, 4),
        models: dict[int, int] | None = None,
        initial_position: dict[int, int] | None = None,
        step_s: float = 0.001,
    ) -> None:
        models = models or {}
        self.servos: dict[int, Servo] = {i: Servo(i, model=models.get(i, XL430_MODEL)) for i in ids}
        for i, pos in (initial_position or {}).items():
            self.servos[i].position = float(pos)
            self.servos[i].set("present_position", pos)
            self.servos[i].set("goal_position", pos)
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.port = os.ttyname(self.slave)
        self.step_s = step_s
        self.lock = threading.RLock()
        self.writes: list[WriteRecord] = []
        self.instructions: dict[int, int] = {}
        self.crc_errors = 0
        self.silent: set[int] = set()
        self.faults: list[Fault] = []
        self.replies_faulted = 0
        self._rx = bytearray()
        self._rx_since = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="servo-emulator", daemon=True)
        self._last_motion = time.monotonic()

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> ServoEmulator:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> ServoEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ test API
    def register(self, servo_id: int, name: str) -> int:
        with self.lock:
            return self.servos[servo_id].get(name)

    def set_register(self, servo_id: int, name: str, value: int) -> None:
        with self.lock:
            self.servos[servo_id].set(name, value)

    def set_hardware_error(self, servo_id: int, bits: int) -> None:
        """Raise a hardware error (as an overloaded servo would): torque goes off, alert bit set."""
        with self.lock:
            s = self.servos[servo_id]
            s.set("hardware_error_status", bits)
            if bits:
                s.set("torque_enable", 0)

    def inject(self, kind: str, count: int = 1, *, servo_id: int | None = None, instruction: int | None = None) -> None:
        """Spoil the next ``count`` status packets (optionally only for one ID / instruction)."""
        if kind not in ("drop", "corrupt", "garbage", "truncate"):
            raise ValueError(kind)
        with self.lock:
            self.faults.append(Fault(kind, count, servo_id, instruction))

    def goal_writes(self, servo_id: int | None = None) -> list[WriteRecord]:
        """Writes that touched Goal Position (116..119)."""
        with self.lock:
            return [
                w
                for w in self.writes
                if (servo_id is None or w.servo_id == servo_id) and w.address <= 119 and w.address + len(w.data) > 116
            ]

    def torque_writes(self) -> dict[int, list[int]]:
        """Per servo, the values the host wrote to Torque Enable (64), accepted, in order (not the watchdog's)."""
        with self.lock:
            out: dict[int, list[int]] = {i: [] for i in self.servos}
            for w in self.writes:
                if w.accepted and w.address <= 64 < w.address + len(w.data):
                    out[w.servo_id].append(w.data[64 - w.address])
            return out

    def torque(self) -> dict[int, int]:
        with self.lock:
            return {i: s.get("torque_enable") for i, s in self.servos.items()}

    # ------------------------------------------------------------------ the wire
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self.master], [], [], self.step_s)
            except (OSError, ValueError):
                return
            if ready:
                try:
                    data = os.read(self.master, 4096)
                except OSError:
                    data = b""  # EIO while no client has the slave open
                    time.sleep(self.step_s)
                if data:
                    if not self._rx:
                        self._rx_since = time.monotonic()
                    self._rx.extend(data)
                    self._parse()
            with self.lock:
                self._tick()

    def _send(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.master, view)
            except BlockingIOError:
                time.sleep(0.0005)
                continue
            except OSError:
                return
            view = view[n:]

    def _parse(self) -> None:
        buf = self._rx
        while True:
            start = buf.find(HEADER)
            if start < 0:
                del buf[: max(0, len(buf) - 3)]
                return
            if start:
                del buf[:start]
            if len(buf) < 7:
                return
            length = buf[5] | (buf[6] << 8)
            total = 7 + length
            if length < 3 or total > 1024:
                del buf[:1]
                continue
            if len(buf) < total:
                if time.monotonic() - self._rx_since > 0.1:  # a partial packet that never completed
                    del buf[:1]
                    continue
                return
            raw = bytes(buf[:total])
            del buf[:total]
            self._rx_since = time.monotonic()
            servo_id = raw[4]
            if crc16(raw[:-2]) != (raw[-2] | (raw[-1] << 8)):
                self.crc_errors += 1
                with self.lock:
                    if servo_id in self.servos and servo_id not in self.silent:
                        self._status(self.servos[servo_id], raw[7], ERR_CRC)
                continue
            body = unstuff(raw, 7, total - 2)
            with self.lock:
                self._dispatch(servo_id, body[0], body[1:])

    # ------------------------------------------------------------------ instructions
    def _status(self, servo: Servo, instruction: int, error: int, params: bytes = b"") -> None:
        if servo.servo_id in self.silent:
            return
        pkt = packet(servo.servo_id, bytes([INST_STATUS, error | servo.error_byte]) + params)
        for f in self.faults:
            if f.remaining > 0 and f.servo_id in (None, servo.servo_id) and f.instruction in (None, instruction):
                f.remaining -= 1
                self.replies_faulted += 1
                if f.kind == "drop":
                    pkt = b""
                elif f.kind == "corrupt":
                    pkt = pkt[:-1] + bytes([pkt[-1] ^ 0x5A])
                elif f.kind == "garbage":
                    pkt = bytes(random.randrange(256) for _ in range(len(pkt)))
                elif f.kind == "truncate":
                    pkt = pkt[: len(pkt) // 2]
                break
        self.faults = [f for f in self.faults if f.remaining > 0]
        if pkt:
            self._send(pkt)

    def _touch(self, ids: list[int]) -> None:
        now = time.monotonic()
        for i in ids:
            if i in self.servos:
                self.servos[i].last_seen = now

    def _dispatch(self, servo_id: int, inst: int, params: bytes) -> None:
        self.instructions[inst] = self.instructions.get(inst, 0) + 1
        if inst == INST_SYNC_WRITE:
            self._sync_write(params)
            return
        if inst == INST_SYNC_READ:
            self._sync_read(params)
            return
        targets = list(self.servos) if servo_id == BROADCAST else ([servo_id] if servo_id in self.servos else [])
        self._touch(targets)
        for i in targets:
            s = self.servos[i]
            reply = servo_id != BROADCAST or inst == INST_PING
            if inst == INST_PING:
                self._status(s, inst, 0, bytes([s.model & 0xFF, s.model >> 8, s.get("firmware_version")]))
            elif inst == INST_READ:
                if len(params) != 4:
                    err, data = ERR_DATA_LENGTH, b""
                else:
                    addr, n = params[0] | params[1] << 8, params[2] | params[3] << 8
                    err, data = self._read(s, addr, n)
                if reply:
                    self._status(s, inst, err, data)
            elif inst == INST_WRITE:
                err = (
                    ERR_DATA_LENGTH
                    if len(params) < 3
                    else self._write(s, params[0] | params[1] << 8, params[2:], "write")
                )
                if reply:
                    self._status(s, inst, err)
            elif inst == INST_REBOOT:
                s.set("hardware_error_status", 0)
                s.set("torque_enable", 0)
                s.set("bus_watchdog", 0)
                if reply:
                    self._status(s, inst, 0)
            elif reply:
                self._status(s, inst, ERR_INSTRUCTION)

    def _read(self, s: Servo, addr: int, n: int) -> tuple[int, bytes]:
        if n == 0 or addr + n > TABLE_SIZE:
            return ERR_DATA_RANGE, b""
        return 0, bytes(s.table[addr : addr + n])

    def _write(self, s: Servo, addr: int, data: bytes, how: str) -> int:
        err = self._check_write(s, addr, data)
        if err == 0:
            s.table[addr : addr + len(data)] = data
            if addr <= 64 < addr + len(data):
                s.torque_history.append(data[64 - addr])
                if data[64 - addr] == 1:
                    s.last_seen = time.monotonic()
                    s.position = float(s.get("present_position"))
        self.writes.append(WriteRecord(time.monotonic(), how, s.servo_id, addr, bytes(data), err == 0, err))
        return err

    def _check_write(self, s: Servo, addr: int, data: bytes) -> int:
        end = addr + len(data)
        if end > TABLE_SIZE:
            return ERR_DATA_RANGE
        a = addr
        while a < end:  # every touched item must exist, be writable, and be written whole
            item = _BY_ADDR.get(a)
            if item is None:
                return ERR_ACCESS
            _name, size, access, _init, _signed = item
            if access != "RW" or a + size > end:
                return ERR_ACCESS
            if a < EEPROM_END and s.get("torque_enable"):
                return ERR_ACCESS
            a += size
        new = bytearray(s.table)
        new[addr:end] = data

        def val(name: str) -> int:
            ad, size, _acc, _init, signed = CONTROL_TABLE[name]
            return int.from_bytes(new[ad : ad + size], "little", signed=signed)

        if addr <= 64 < end:
            if val("torque_enable") not in (0, 1):
                return ERR_DATA_RANGE
            if val("torque_enable") == 1 and s.get("hardware_error_status"):
                return ERR_RESULT_FAIL
        if addr <= 98 < end and not (0 <= val("bus_watchdog") <= 127):
            return ERR_DATA_RANGE
        if addr <= 116 < end:
            if s.get("bus_watchdog") == -1:
                return ERR_DATA_RANGE  # goal values are frozen after a watchdog error until 98 is cleared
            if not val("min_position_limit") <= val("goal_position") <= val("max_position_limit"):
                return ERR_DATA_LIMIT
        return 0

    def _sync_read(self, params: bytes) -> None:
        if len(params) < 5:
            return
        addr, n = params[0] | params[1] << 8, params[2] | params[3] << 8
        ids = list(params[4:])
        self._touch(ids)
        for i in ids:
            if i in self.servos:
                err, data = self._read(self.servos[i], addr, n)
                self._status(self.servos[i], INST_SYNC_READ, err, data)

    def _sync_write(self, params: bytes) -> None:
        if len(params) < 4:
            return
        addr, n = params[0] | params[1] << 8, params[2] | params[3] << 8
        rest = params[4:]
        ids = []
        for k in range(0, len(rest) - n, n + 1):
            i, data = rest[k], rest[k + 1 : k + 1 + n]
            ids.append(i)
            if i in self.servos and len(data) == n:
                self._write(self.servos[i], addr, data, "sync_write")
        self._touch(ids)

    # ------------------------------------------------------------------ time
    def _tick(self) -> None:
        now = time.monotonic()
        dt = now - self._last_motion
        self._last_motion = now
        for s in self.servos.values():
            wd = s.get("bus_watchdog")
            if s.get("torque_enable") and wd > 0 and now - s.last_seen > wd * 0.020:
                s.set("bus_watchdog", -1)
                s.set("torque_enable", 0)
                s.watchdog_trips += 1
            if s.get("torque_enable"):
                goal = s.get("goal_position")
                rpm = s.get("profile_velocity") * RPM_PER_UNIT or MAX_RPM
                max_step = min(rpm, MAX_RPM) / 60.0 * 4096.0 * dt
                err = goal - s.position
                step = max(-max_step, min(max_step, err))
                s.position += step
                s.set("present_velocity", int(round(step / dt * 60.0 / 4096.0 / RPM_PER_UNIT)) if dt > 0 else 0)
                s.set("present_load", max(-1000, min(1000, int(err * 2))))
            else:
                s.set("present_velocity", 0)
                s.set("present_load", 0)
            s.set("present_position", int(round(s.position)))
            s.set("moving", int(abs(s.get("goal_position") - s.position) > 1 and bool(s.get("torque_enable"))))


class OdometryPublisher:
    """The VIO end of the odometry wire: a ZeroMQ PUB socket on a free loopback port sending JSON states.

    ``pose(t)`` gives (position, quaternion xyzw, linear velocity, angular velocity in the body
    frame) at publisher time ``t``; by default the robot stands still at ``height``. ``stop_after``
    (s) or ``silence()`` makes it fall silent, as a crashed estimator would.
    """

    def __init__(
        self,
        rate_hz: float = 100.0,
        height: float = 0.04,
        stop_after: float | None = None,
        pose=None,
        endpoint: str = "tcp://127.0.0.1:*",
    ) -> None:
        import zmq

        self.rate_hz = rate_hz
        self.stop_after = stop_after
        self.pose = pose or (lambda t: ([0.0, 0.0, height], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]))
        self._ctx = zmq.Context()
        self._sock = self._ctx.socket(zmq.PUB)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.bind(endpoint)
        self.endpoint = self._sock.getsockopt(zmq.LAST_ENDPOINT).decode()
        self.sent = 0
        self._stop = threading.Event()
        self._silent = threading.Event()
        self._thread = threading.Thread(target=self._run, name="odometry-publisher", daemon=True)

    def silence(self) -> None:
        """Stop publishing from now on (the socket stays bound)."""
        self._silent.set()

    def _run(self) -> None:
        import json

        t0 = time.monotonic()
        period = 1.0 / self.rate_hz
        k = 0
        while not self._stop.is_set():
            t = time.monotonic() - t0
            if not self._silent.is_set() and (self.stop_after is None or t < self.stop_after):
                p, q, v, w = self.pose(t)
                self._sock.send(
                    json.dumps(
                        {
                            "t": t,
                            "position": list(p),
                            "orientation": list(q),
                            "linear_velocity": list(v),
                            "angular_velocity": list(w),
                        }
                    ).encode()
                )
                self.sent += 1
            k += 1
            time.sleep(max(0.0, t0 + k * period - time.monotonic()))

    def __enter__(self) -> OdometryPublisher:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self._sock.close(0)
        self._ctx.term()
