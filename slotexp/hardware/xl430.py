"""XL430-W250 control table (Protocol 2.0): the addresses, sizes and units the bus uses.

Kept in one place so the bus, the simulated bus and the README agree; values from
the ROBOTIS e-Manual for the XL430-W250 (firmware 45+).
"""

from __future__ import annotations

MODEL_NUMBER = 1060
PROTOCOL = 2.0

# EEPROM area (writable only while Torque Enable = 0)
ADDR_MODEL_NUMBER = 0            # 2 bytes
ADDR_OPERATING_MODE = 11         # 1 byte; 3 = position control
ADDR_MAX_POSITION_LIMIT = 48     # 4 bytes, ticks
ADDR_MIN_POSITION_LIMIT = 52     # 4 bytes, ticks
# RAM area
ADDR_TORQUE_ENABLE = 64          # 1 byte
ADDR_HARDWARE_ERROR_STATUS = 70  # 1 byte, bit field (below)
ADDR_BUS_WATCHDOG = 98           # 1 byte, 20 ms units; 0 off; -1 (0xFF) after it fired
ADDR_PROFILE_VELOCITY = 112      # 4 bytes, 0.229 rpm units; 0 = no profile
ADDR_GOAL_POSITION = 116         # 4 bytes, ticks
ADDR_PRESENT_LOAD = 126          # 2 bytes, signed, 0.1 % of stall torque
ADDR_PRESENT_VELOCITY = 128      # 4 bytes, signed, 0.229 rpm units
ADDR_PRESENT_POSITION = 132      # 4 bytes, signed, ticks

# Present Load, Velocity and Position are contiguous: one sync read covers all three.
PRESENT_BLOCK_ADDR = ADDR_PRESENT_LOAD
PRESENT_BLOCK_LEN = ADDR_PRESENT_POSITION + 4 - ADDR_PRESENT_LOAD  # 10 bytes

OPERATING_MODE_POSITION = 3
TICKS_PER_REV = 4096
DEG_PER_TICK = 360.0 / TICKS_PER_REV
MAX_TICK = 4095
RPM_PER_VELOCITY_UNIT = 0.229
LOAD_PERCENT_PER_UNIT = 0.1
WATCHDOG_UNIT_S = 0.020

HARDWARE_ERRORS = {
    0x01: "input voltage",
    0x04: "overheating",
    0x08: "motor encoder",
    0x10: "electrical shock",
    0x20: "overload",
}


def describe_hardware_error(bits: int) -> str:
    """'0x24 (overheating, overload)' for a Hardware Error Status value."""
    names = [name for bit, name in HARDWARE_ERRORS.items() if bits & bit]
    return f"0x{bits:02x} ({', '.join(names) or 'unknown bits'})"


def signed(value: int, size: int) -> int:
    """Two's-complement value of a ``size``-byte register read as unsigned."""
    bits = 8 * size
    value &= (1 << bits) - 1
    return value - (1 << bits) if value >= 1 << (bits - 1) else value


def le_bytes(value: int, size: int) -> list[int]:
    """Little-endian bytes of ``value`` for a ``size``-byte register (what GroupSyncWrite takes)."""
    value &= (1 << (8 * size)) - 1
    return [(value >> (8 * i)) & 0xFF for i in range(size)]
