"""The servo bus: one interface, implemented on the real dynamixel-sdk (Protocol 2.0).

The control loop sees only :class:`ServoBus`, so the same loop drives the robot, the
protocol-level emulator in the tests, and the simulator (:mod:`.simbus`).

Per cycle the robot costs two bus transactions: one GroupSyncWrite of Goal Position
(no reply) and one GroupSyncRead of Present Load, Velocity and Position (one
contiguous 10-byte block, one reply per servo). Hardware Error Status is read every
``hardware.error_check_every`` cycles. A failed transaction is retried
``hardware.comm_retries`` times, then :class:`BusError` stops the run, and the
caller turns the torque off. dynamixel-sdk's ``PortHandler`` opens the port with
pyserial (so a pseudo-terminal works as well as ``/dev/ttyUSB0``) in non-blocking
mode and polls for replies until a packet timeout of about
``2 * LATENCY_TIMER(16 ms) + 2 ms`` plus the bytes' transmission time.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from ..errors import BusError, UserError
from . import xl430 as X
from .config import HardwareConfig
from .mapping import ServoMap
from .portlock import PortLock


@dataclass
class ServoReadings:
    """One sync read, in leg order (raw XL430 units)."""

    position: np.ndarray  # ticks
    velocity: np.ndarray  # 0.229 rpm units
    load: np.ndarray  # 0.1 % of stall torque
    retries: int = 0


class ServoBus(Protocol):
    """What the control loop needs from the servos."""

    ids: list[int]

    def open(self) -> list[str]:
        """Connect, ping, check model numbers and hardware errors; no writes. Return notes for the user."""

    def configure(self, dry_run: bool) -> list[str]:
        """Torque off, position mode, limits, profile velocity; in a dry run only say what would change."""

    def enable(self) -> None:
        """Hold the present position, torque on, arm the bus watchdog."""

    def read(self) -> ServoReadings:
        """Present position, velocity and load of every servo."""

    def write_goals(self, ticks: np.ndarray) -> int:
        """Command goal positions (already clamped); return the retries it took."""

    def hardware_errors(self) -> np.ndarray:
        """Hardware Error Status of every servo (0 = fine)."""

    def disable(self) -> list[str]:
        """Torque off on every servo, best effort with retries; return what could not be done."""

    def close(self) -> None:
        """Release the port."""


@dataclass
class DynamixelBus:
    """XL430 servos through dynamixel-sdk's PortHandler / Protocol2PacketHandler / GroupSync*."""

    cfg: HardwareConfig
    legs: list[str]
    smap: ServoMap
    ids: list[int] = field(init=False)
    comm_errors: int = 0

    def __post_init__(self) -> None:
        self.ids = list(self.cfg.ids)
        self._port = None
        self._ph = None
        self._reader = None
        self._error_reader = None
        self._writer = None
        self._writer_ready = False
        self._torque_may_be_on = False
        self._lock = PortLock(self.cfg.port)

    # ------------------------------------------------------------------ helpers
    def _leg(self, servo_id: int) -> str:
        return self.legs[self.ids.index(servo_id)]

    def _where(self) -> str:
        return f"on {self.cfg.port} at {self.cfg.baudrate} baud"

    def _recover(self) -> None:
        """After a failed transaction: release the SDK's busy flag and drop stray bytes."""
        self.comm_errors += 1
        self._port.is_using = False
        time.sleep(0.002)
        try:
            self._port.clearPort()
        except OSError:
            pass

    def _packet_error(self, error: int) -> str:
        return self._ph.getRxPacketError(error & 0x7F) if error & 0x7F else ""

    def _read_reg(self, servo_id: int, name: str) -> int:
        """One control-table item of one servo, by name (:data:`.xl430.CONTROL_TABLE`), with retries."""
        addr, size = X.CONTROL_TABLE[name]
        what = X.label(name)
        fn = {1: self._ph.read1ByteTxRx, 2: self._ph.read2ByteTxRx, 4: self._ph.read4ByteTxRx}[size]
        msg = ""
        for _ in range(self.cfg.comm_retries + 1):
            value, result, error = fn(self._port, servo_id, addr)
            if result == X_COMM_SUCCESS and not error & 0x7F:
                return X.signed(value, size) if size > 1 else value
            msg = self._ph.getTxRxResult(result) if result != X_COMM_SUCCESS else self._packet_error(error)
            self._recover()
        raise BusError(f"servo {servo_id} ({self._leg(servo_id)}): reading {what} failed {self._where()}: {msg}")

    def _write_reg(self, servo_id: int, name: str, value: int) -> None:
        """Write one control-table item of one servo, by name, with retries (a refusal is not retried)."""
        addr, size = X.CONTROL_TABLE[name]
        what = X.label(name)
        fn = {1: self._ph.write1ByteTxRx, 2: self._ph.write2ByteTxRx, 4: self._ph.write4ByteTxRx}[size]
        msg = ""
        for _ in range(self.cfg.comm_retries + 1):
            result, error = fn(self._port, servo_id, addr, value & ((1 << (8 * size)) - 1))
            if result == X_COMM_SUCCESS and not error & 0x7F:
                return
            if result == X_COMM_SUCCESS:  # the servo answered and refused: retrying will not help
                raise BusError(
                    f"servo {servo_id} ({self._leg(servo_id)}) refused {what} = {value}: {self._packet_error(error)}"
                )
            msg = self._ph.getTxRxResult(result)
            self._recover()
        raise BusError(f"servo {servo_id} ({self._leg(servo_id)}): writing {what} failed {self._where()}: {msg}")

    # ------------------------------------------------------------------ interface
    def open(self) -> list[str]:
        import serial
        from dynamixel_sdk import GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler

        port_name = self.cfg.port
        if not os.path.exists(port_name):
            raise UserError(f"serial port {port_name} does not exist: is the U2D2 plugged in? (set hardware.port=...)")
        self._lock.acquire()  # before the SDK opens (and flushes) the port: a second run must not touch the bus
        self._port = PortHandler(port_name)
        self._ph = PacketHandler(X.PROTOCOL)
        try:
            opened = self._port.openPort() and self._port.setBaudRate(self.cfg.baudrate)
        except (serial.SerialException, OSError, ValueError) as exc:
            self._port = None
            raise UserError(f"cannot open serial port {port_name}: {exc}") from None
        if not opened:
            raise UserError(f"cannot open serial port {port_name} at {self.cfg.baudrate} baud")
        try:
            self._ping_all()
            self._check_errors()
        except BusError as exc:
            raise UserError(str(exc)) from None
        self._reader = GroupSyncRead(self._port, self._ph, X.PRESENT_BLOCK_ADDR, X.PRESENT_BLOCK_LEN)
        self._error_reader = GroupSyncRead(self._port, self._ph, *X.CONTROL_TABLE["Hardware_Error_Status"])
        self._writer = GroupSyncWrite(self._port, self._ph, *X.CONTROL_TABLE["Goal_Position"])
        for i in self.ids:
            self._reader.addParam(i)
            self._error_reader.addParam(i)
        return self._latency_notes()

    def _latency_notes(self) -> list[str]:
        """The U2D2's FTDI chip holds replies up to latency_timer ms; 16 (the default) breaks a 30 Hz loop."""
        sysfs = Path("/sys/bus/usb-serial/devices") / Path(os.path.realpath(self.cfg.port)).name / "latency_timer"
        try:
            ms = int(sysfs.read_text().strip())
        except (OSError, ValueError):
            return []
        if ms > 2:
            return [
                f"{sysfs} is {ms} ms: every bus round trip can take that long; set it to 1 (echo 1 | sudo tee {sysfs})"
            ]
        return []

    def _ping_all(self) -> None:
        for leg, servo_id in zip(self.legs, self.ids):
            msg = ""
            for _ in range(self.cfg.comm_retries + 1):
                model, result, error = self._ph.ping(self._port, servo_id)
                if result == X_COMM_SUCCESS:
                    break
                msg = self._ph.getTxRxResult(result)
                self._recover()
            else:
                raise UserError(
                    f"servo ID {servo_id} ({leg}) does not answer ping {self._where()} ({msg}): "
                    f"check power, wiring, the ID (hardware.ids) and the baud rate (hardware.baudrate)"
                )
            if model != self.cfg.model_number:
                raise UserError(
                    f"servo ID {servo_id} ({leg}) reports model number {model}, expected "
                    f"{self.cfg.model_number} (XL430-W250): check hardware.ids and the servo"
                )

    def _check_errors(self) -> None:
        for leg, i in zip(self.legs, self.ids):
            err = self._read_reg(i, "Hardware_Error_Status")
            if err:
                raise UserError(
                    f"servo ID {i} ({leg}) reports hardware error {X.describe_hardware_error(err)}: "
                    f"remove the cause, then reboot it (power cycle or Dynamixel Wizard > Reboot)"
                )

    def configure(self, dry_run: bool) -> list[str]:
        try:
            return self._configure(dry_run)
        except BusError as exc:
            raise UserError(str(exc)) from None

    def _configure(self, dry_run: bool) -> list[str]:
        notes: list[str] = []
        profile = int(round(self.cfg.profile_velocity_rpm / X.RPM_PER_VELOCITY_UNIT))
        for k, (leg, i) in enumerate(zip(self.legs, self.ids)):
            torque = self._read_reg(i, "Torque_Enable")
            mode = self._read_reg(i, "Operating_Mode")
            lo = self._read_reg(i, "Min_Position_Limit")
            hi = self._read_reg(i, "Max_Position_Limit")
            want_lo, want_hi = int(self.smap.min_ticks[k]), int(self.smap.max_ticks[k])
            if dry_run:
                if torque:
                    self._write_reg(i, "Torque_Enable", 0)
                    notes.append(f"servo {i} ({leg}) had torque on: turned it off for the dry run")
                if mode != X.OPERATING_MODE_POSITION:
                    notes.append(f"servo {i} ({leg}) is in operating mode {mode}: a live run sets 3 (position)")
                if self.cfg.write_position_limits and (lo, hi) != (want_lo, want_hi):
                    notes.append(
                        f"servo {i} ({leg}) position limits are {lo}-{hi} ticks: a live run writes {want_lo}-{want_hi}"
                    )
                continue
            self._write_reg(i, "Torque_Enable", 0)
            self._write_reg(i, "Bus_Watchdog", 0)
            if mode != X.OPERATING_MODE_POSITION:
                self._write_reg(i, "Operating_Mode", X.OPERATING_MODE_POSITION)
                notes.append(f"servo {i} ({leg}) was in operating mode {mode}: set 3 (position)")
            if self.cfg.write_position_limits and (lo, hi) != (want_lo, want_hi):
                self._write_reg(i, "Max_Position_Limit", want_hi)
                self._write_reg(i, "Min_Position_Limit", want_lo)
                notes.append(f"servo {i} ({leg}) position limits set to {want_lo}-{want_hi} ticks (were {lo}-{hi})")
            self._write_reg(i, "Profile_Velocity", profile)
        return notes

    def enable(self) -> None:
        self._torque_may_be_on = True
        units = self.cfg.watchdog_ms // X.WATCHDOG_UNIT_MS
        for k, i in enumerate(self.ids):
            present = self._read_reg(i, "Present_Position")
            hold = int(np.clip(present, self.smap.min_ticks[k], self.smap.max_ticks[k]))
            self._write_reg(i, "Goal_Position", hold)  # no jump on torque-on
            self._write_reg(i, "Torque_Enable", 1)
        for i in self.ids:
            if units:
                self._write_reg(i, "Bus_Watchdog", units)

    def read(self) -> ServoReadings:
        msg = ""
        for attempt in range(self.cfg.comm_retries + 1):
            result = self._reader.txRxPacket()
            if result == X_COMM_SUCCESS and all(
                self._reader.isAvailable(i, X.PRESENT_BLOCK_ADDR, X.PRESENT_BLOCK_LEN) for i in self.ids
            ):
                return ServoReadings(
                    position=self._present("Present_Position"),
                    velocity=self._present("Present_Velocity"),
                    load=self._present("Present_Load"),
                    retries=attempt,
                )
            msg = self._ph.getTxRxResult(result)
            self._recover()
        raise BusError(
            f"reading the servos failed {self.cfg.comm_retries + 1} times in a row {self._where()} "
            f"({msg}): check the cable and the servo power"
        )

    def _present(self, name: str) -> np.ndarray:
        """One item of the last present-block sync read, per servo, signed."""
        addr, size = X.CONTROL_TABLE[name]
        return np.array([X.signed(self._reader.getData(i, addr, size), size) for i in self.ids])

    def write_goals(self, ticks: np.ndarray) -> int:
        _addr, size = X.CONTROL_TABLE["Goal_Position"]
        for i, value in zip(self.ids, ticks):
            data = X.le_bytes(int(value), size)
            ok = self._writer.changeParam(i, data) if self._writer_ready else self._writer.addParam(i, data)
            if not ok:  # pragma: no cover - only on an SDK contract change
                raise BusError(f"servo {i}: GroupSyncWrite refused the goal position parameter")
        self._writer_ready = True
        msg = ""
        for attempt in range(self.cfg.comm_retries + 1):
            result = self._writer.txPacket()
            if result == X_COMM_SUCCESS:
                return attempt
            msg = self._ph.getTxRxResult(result)
            self._recover()
        raise BusError(
            f"sending goal positions failed {self.cfg.comm_retries + 1} times in a row {self._where()} ({msg})"
        )

    def hardware_errors(self) -> np.ndarray:
        item = X.CONTROL_TABLE["Hardware_Error_Status"]
        msg = ""
        for _ in range(self.cfg.comm_retries + 1):
            result = self._error_reader.txRxPacket()
            if result == X_COMM_SUCCESS and all(self._error_reader.isAvailable(i, *item) for i in self.ids):
                return np.array([self._error_reader.getData(i, *item) for i in self.ids])
            msg = self._ph.getTxRxResult(result)
            self._recover()
        raise BusError(
            f"reading Hardware Error Status failed {self.cfg.comm_retries + 1} times in a row {self._where()} ({msg})"
        )

    def disable(self) -> list[str]:
        if self._port is None or not self._torque_may_be_on:
            return []
        self._port.is_using = False  # an interrupted transaction must not block the torque-off writes
        problems = []
        for i in self.ids:
            try:
                self._write_reg(i, "Torque_Enable", 0)
            except BusError as exc:
                problems.append(str(exc))
                continue
            try:
                self._write_reg(i, "Bus_Watchdog", 0)
            except BusError:
                pass  # torque is off; the watchdog only acts while torque is on
        if not problems:
            self._torque_may_be_on = False
        return problems

    def close(self) -> None:
        if self._port is not None and self._port.is_open:
            self._port.closePort()
        self._lock.release()


X_COMM_SUCCESS = 0  # dynamixel_sdk.robotis_def.COMM_SUCCESS, without importing the SDK at module load
