"""XL430-W250 control table (Protocol 2.0) as data: ``{name: (address, size)}`` and the units.

Source: ROBOTIS e-Manual, XL430-W250, section "Control Table"
(https://emanual.robotis.com/docs/en/dxl/x/xl430-w250/#control-table), firmware 45+.
Names are the e-Manual's item names with ``_`` for spaces (``"Goal_Position"``), so
``label(name)`` is what the manual and Dynamixel Wizard call the item. Item 126 is
Present Load on the XL430 (the X-series models with a current sensor call it
Present Current).

The bus reads and writes items by name; their address and size come from
:data:`CONTROL_TABLE` only. A sync read or write that covers several items takes
its start address and length from :func:`span`, which refuses items that are not
back to back: :data:`PRESENT_BLOCK` is checked that way at import, since the
control loop reads it in one transaction per cycle.
"""

from __future__ import annotations

from collections.abc import Iterable

MODEL_NUMBER = 1060  # XL430-W250: what item Model_Number holds and what a ping reply carries
PROTOCOL = 2.0

# name: (address, size in bytes)          access, unit / meaning
CONTROL_TABLE: dict[str, tuple[int, int]] = {
    # EEPROM area: writable only while Torque_Enable = 0
    "Model_Number": (0, 2),  # R;  1060 for the XL430-W250
    "ID": (7, 1),  # RW; 0-252 (set once in Dynamixel Wizard, see docs/hardware.md)
    "Baud_Rate": (8, 1),  # RW; 3 = 1 Mbps (set once in Dynamixel Wizard)
    "Return_Delay_Time": (9, 1),  # RW; 2 us units (set once in Dynamixel Wizard)
    "Operating_Mode": (11, 1),  # RW; 3 = position control
    "Max_Position_Limit": (48, 4),  # RW; ticks (DEG_PER_TICK), 0-4095
    "Min_Position_Limit": (52, 4),  # RW; ticks, 0-4095
    # RAM area
    "Torque_Enable": (64, 1),  # RW; 0 off, 1 on
    "Hardware_Error_Status": (70, 1),  # R;  bit field (HARDWARE_ERRORS)
    "Bus_Watchdog": (98, 1),  # RW; WATCHDOG_UNIT_MS units, 1-127; 0 off; -1 (0xFF) after it fired
    "Profile_Velocity": (112, 4),  # RW; RPM_PER_VELOCITY_UNIT units; 0 = no profile
    "Goal_Position": (116, 4),  # RW; ticks, within the position limits
    "Present_Load": (126, 2),  # R;  signed, LOAD_PERCENT_PER_UNIT % of stall torque
    "Present_Velocity": (128, 4),  # R;  signed, RPM_PER_VELOCITY_UNIT units
    "Present_Position": (132, 4),  # R;  signed, ticks
}

OPERATING_MODE_POSITION = 3
TICKS_PER_REV = 4096
DEG_PER_TICK = 360.0 / TICKS_PER_REV
MAX_TICK = 4095
RPM_PER_VELOCITY_UNIT = 0.229
LOAD_PERCENT_PER_UNIT = 0.1
WATCHDOG_UNIT_MS = 20  # Bus_Watchdog counts in 20 ms steps
WATCHDOG_MAX_UNITS = 127  # ... up to 127 (2.54 s)

HARDWARE_ERRORS = {
    0x01: "input voltage",
    0x04: "overheating",
    0x08: "motor encoder",
    0x10: "electrical shock",
    0x20: "overload",
}


def label(name: str) -> str:
    """The item's name as the e-Manual writes it: ``"Goal_Position"`` -> ``"Goal Position"``."""
    return name.replace("_", " ")


def span(names: Iterable[str]) -> tuple[int, int]:
    """Start address and length in bytes of items that lie back to back in the table.

    What one GroupSyncRead/GroupSyncWrite over ``names`` needs; a gap or an overlap
    between them is a ValueError.
    """
    items = sorted((CONTROL_TABLE[n], n) for n in names)
    if not items:
        raise ValueError("span of no items")
    for ((addr, size), name), ((nxt, _), nxt_name) in zip(items, items[1:]):
        if addr + size != nxt:
            raise ValueError(
                f"{name} ({addr}, {size} bytes) and {nxt_name} ({nxt}) are not contiguous: "
                f"one sync transaction cannot cover them"
            )
    (start, _), _ = items[0]
    (last, last_size), _ = items[-1]
    return start, last + last_size - start


# Present Load, Velocity and Position: one sync read per cycle covers all three (126, 10 bytes).
PRESENT_BLOCK = ("Present_Load", "Present_Velocity", "Present_Position")
PRESENT_BLOCK_ADDR, PRESENT_BLOCK_LEN = span(PRESENT_BLOCK)


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
