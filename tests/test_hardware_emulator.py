"""The servo emulator speaks Protocol 2.0 the way the real dynamixel-sdk expects (the SDK is the client).

These pin the emulator itself, so the hardware tests built on it test our code and
not the emulator's mistakes: CRC, byte stuffing, read/write/sync access rules, the
XL430 control table, the bus watchdog and the fault injection all behave as the
SDK sees a servo.
"""

from __future__ import annotations

import ast
import random
import time

import pytest
from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)
from dynamixel_sdk.protocol2_packet_handler import Protocol2PacketHandler

from slotexp.hardware import xl430
from tests import servo_emulator
from tests.servo_emulator import CONTROL_TABLE, XL430_MODEL, ServoEmulator, crc16, packet, stuff, unstuff


@pytest.fixture()
def bus():
    with ServoEmulator([1, 2, 3, 4]) as emu:
        port = PortHandler(emu.port)
        assert port.openPort() and port.setBaudRate(1000000)
        yield emu, port, PacketHandler(2.0)
        port.closePort()


def test_the_emulator_control_table_agrees_with_the_library() -> None:
    """Two control tables written independently from the e-Manual: every item the library defines has the
    same address and size in the emulator's (names map by lower case: "Goal_Position" -> "goal_position")."""
    for name, (addr, size) in xl430.CONTROL_TABLE.items():
        assert name.lower() in CONTROL_TABLE, f"{name} is not in the emulator's control table"
        assert CONTROL_TABLE[name.lower()][:2] == (addr, size), name
    assert XL430_MODEL == xl430.MODEL_NUMBER
    # the agreement means something only while the emulator does not take the library's table
    tree = ast.parse(open(servo_emulator.__file__).read())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not any(m.split(".")[0] in ("slotexp", "tests") for m in imported), imported


def test_crc_matches_the_sdk_table() -> None:
    ph = Protocol2PacketHandler()
    rng = random.Random(1)
    for n in (1, 7, 64, 300):
        data = [rng.randrange(256) for _ in range(n)]
        assert crc16(bytes(data)) == ph.updateCRC(0, data, n)


def test_stuffing_round_trip_matches_the_sdk() -> None:
    body = bytes([0x03, 0x74, 0x00, 0xFF, 0xFF, 0xFD, 0x00, 0xFF, 0xFF, 0xFD])
    ours = packet(1, body)
    sdk = [0xFF, 0xFF, 0xFD, 0x00, 1, len(body) + 2, 0, *body, 0, 0]
    ph = Protocol2PacketHandler()
    stuffed = ph.addStuffing(sdk)
    n = stuffed[5] + 7
    crc = ph.updateCRC(0, stuffed, n - 2)
    stuffed[n - 2 : n] = [crc & 0xFF, crc >> 8]
    assert list(ours) == stuffed[:n]
    assert unstuff(ours, 7, len(ours) - 2) == body
    assert stuff(b"\x00\x00\x00", b"\xff\xff\xfd") == b"\xff\xff\xfd\xfd"


def test_ping_read_write_and_access_rules(bus) -> None:
    emu, port, ph = bus
    assert ph.ping(port, 3)[:2] == (XL430_MODEL, COMM_SUCCESS)
    assert ph.ping(port, 9)[1] == COMM_RX_TIMEOUT  # no such ID: no reply
    assert ph.read2ByteTxRx(port, 2, 0) == (XL430_MODEL, COMM_SUCCESS, 0)
    # A value whose bytes contain the header pattern survives stuffing both ways.
    assert ph.write4ByteTxRx(port, 1, 48, 0x00FDFFFF) == (COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 1, 48)[0] == 0x00FDFFFF
    assert ph.write4ByteTxRx(port, 1, 48, 4095) == (COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 1, 70, 1)[1] == 7  # Hardware Error Status is read-only: access error
    assert ph.write4ByteTxRx(port, 1, 52, 1000) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 1, 116, 500)[1] == 6  # below Min Position Limit: data limit error
    assert ph.write1ByteTxRx(port, 1, 64, 1) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 1, 48, 3000)[1] == 7  # EEPROM is locked while torque is on
    assert ph.write4ByteTxRx(port, 1, 116, 1500) == (COMM_SUCCESS, 0)
    assert emu.register(1, "goal_position") == 1500
    assert [w.accepted for w in emu.goal_writes(1)] == [False, True]


def test_sync_write_and_sync_read(bus) -> None:
    emu, port, ph = bus
    writer = GroupSyncWrite(port, ph, 116, 4)
    for i in (1, 2, 3, 4):
        assert writer.addParam(i, list((2000 + i).to_bytes(4, "little")))
    assert writer.txPacket() == COMM_SUCCESS
    reader = GroupSyncRead(port, ph, 116, 4)
    for i in (1, 2, 3, 4):
        reader.addParam(i)
    assert reader.txRxPacket() == COMM_SUCCESS
    assert [reader.getData(i, 116, 4) for i in (1, 2, 3, 4)] == [2001, 2002, 2003, 2004]
    assert {w.instruction for w in emu.goal_writes()} == {"sync_write"}


def test_motion_toward_goal_and_hardware_error_alert(bus) -> None:
    emu, port, ph = bus
    ph.write1ByteTxRx(port, 2, 64, 1)
    ph.write4ByteTxRx(port, 2, 116, 2100)
    deadline = time.monotonic() + 2
    while abs(ph.read4ByteTxRx(port, 2, 132)[0] - 2100) > 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert ph.read4ByteTxRx(port, 2, 132)[0] == pytest.approx(2100, abs=1)
    emu.set_hardware_error(2, 0x20)
    _value, result, error = ph.read1ByteTxRx(port, 2, 70)
    assert (result, error & 0x80) == (COMM_SUCCESS, 0x80)  # alert bit in every status packet
    assert emu.torque()[2] == 0
    assert ph.write1ByteTxRx(port, 2, 64, 1)[1] & 0x7F == 1  # cannot re-enable torque until rebooted


def test_bus_watchdog_stops_a_servo_that_hears_nothing(bus) -> None:
    emu, port, ph = bus
    ph.write1ByteTxRx(port, 4, 64, 1)
    ph.write1ByteTxRx(port, 4, 98, 3)  # 60 ms
    time.sleep(0.2)
    assert emu.torque()[4] == 0 and emu.servos[4].watchdog_trips == 1
    assert ph.read1ByteTxRx(port, 4, 98)[0] == 0xFF  # -1: the watchdog fired
    assert ph.write4ByteTxRx(port, 4, 116, 2000)[1] != 0  # goals are refused until 98 is cleared
    assert ph.write1ByteTxRx(port, 4, 98, 0) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 4, 116, 2000) == (COMM_SUCCESS, 0)


def test_fault_injection_as_the_sdk_sees_it(bus) -> None:
    emu, port, ph = bus
    reader = GroupSyncRead(port, ph, 126, 10)
    for i in (1, 2, 3, 4):
        reader.addParam(i)
    emu.inject("drop", servo_id=3)
    assert reader.txRxPacket() == COMM_RX_TIMEOUT
    emu.inject("corrupt")
    assert reader.txRxPacket() == COMM_RX_CORRUPT
    emu.inject("truncate")
    assert reader.txRxPacket() in (COMM_RX_CORRUPT, COMM_RX_TIMEOUT)
    emu.inject("garbage")
    assert reader.txRxPacket() != COMM_SUCCESS
    time.sleep(0.05)
    assert reader.txRxPacket() == COMM_SUCCESS  # and the bus recovers once the faults are used up
    emu.silent.add(2)
    assert ph.ping(port, 2)[1] == COMM_RX_TIMEOUT
