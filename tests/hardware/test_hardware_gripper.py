"""Modbus-RTU framing and the AG-95 driver against an emulated gripper on a pseudo-terminal, faults included."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from diffstir.hardware import (
    AG95_REGISTERS, AG95Gripper, GripperError, GripperTimeout, GripState, HardwareError, InitState, ModbusError,
)
from diffstir.hardware.modbus import crc16, crc_ok, with_crc

pytestmark = pytest.mark.timeout(10)


@pytest.mark.parametrize("payload, frame", [
    ("01 03 00 00 00 0A", "01 03 00 00 00 0A C5 CD"),  # the Modbus over Serial Line specification's example
    ("01 06 01 00 00 01", "01 06 01 00 00 01 49 F6"),  # DH manuals: initialise
    ("01 06 01 00 00 A5", "01 06 01 00 00 A5 48 4D"),  # DH manuals: full initialisation
])
def test_crc_known_frames(payload, frame):
    assert with_crc(bytes.fromhex(payload)) == bytes.fromhex(frame)
    assert crc_ok(bytes.fromhex(frame))
    assert not crc_ok(bytes.fromhex(frame)[:-1] + b"\x00")


def test_crc_check_value():
    assert crc16(b"123456789") == 0x4B37  # CRC-16/MODBUS catalogue check value


def _gripper(emulator, **kwargs) -> AG95Gripper:
    return AG95Gripper(emulator.port, timeout=kwargs.pop("timeout", 0.1), **kwargs)


def test_initialise_and_close_on_rod(gripper_emulator):
    emulator = gripper_emulator(rod_position=420)
    with _gripper(emulator) as gripper:
        assert gripper.status().init is InitState.NOT_INITIALISED
        gripper.initialise(timeout=2.0)
        gripper.set_force(35)
        status = gripper.close_on_rod(timeout=2.0)
        assert (status.init, status.grip, status.position) == (InitState.INITIALISED, GripState.CAUGHT, 420)
        assert emulator.registers[AG95_REGISTERS["force"].address] == 35
        assert gripper.open(timeout=2.0).grip is GripState.REACHED


def test_crc_errors_are_retried(gripper_emulator):
    emulator = gripper_emulator(crc_errors=2)
    with _gripper(emulator, retries=3) as gripper:
        assert gripper.status().init is InitState.NOT_INITIALISED
    assert emulator.requests == 3 + 2  # three registers, two of the replies repeated


def test_crc_errors_beyond_retries_fail_clearly(gripper_emulator):
    emulator = gripper_emulator(crc_errors=10)
    with _gripper(emulator, retries=2) as gripper, pytest.raises(ModbusError) as err:
        gripper.set_force(50)
    message = str(err.value)
    assert emulator.port in message and "register 0x0101" in message and "3 attempts" in message
    assert message.count("CRC error") == 3


def test_silent_gripper_times_out(gripper_emulator):
    emulator = gripper_emulator(silent=True)
    with _gripper(emulator, retries=1, timeout=0.05) as gripper, pytest.raises(ModbusError, match="got nothing"):
        gripper.status()


def test_never_reaches_names_register_and_state(gripper_emulator):
    emulator = gripper_emulator(never_reaches=True)
    with _gripper(emulator) as gripper:
        gripper.initialise(timeout=2.0)
        with pytest.raises(GripperTimeout) as err:
            gripper.close_on_rod(timeout=0.3)
    assert re.search(r"0x0201 \(grip_state\) still MOVING after 0.3 s; expected CAUGHT", str(err.value))


def test_closing_on_nothing_is_an_error(gripper_emulator):
    emulator = gripper_emulator(rod_position=None)
    with _gripper(emulator) as gripper:
        gripper.initialise(timeout=2.0)
        with pytest.raises(GripperError, match="REACHED after closing; expected CAUGHT"):
            gripper.close_on_rod(timeout=2.0)


def test_exception_reply_is_not_retried(gripper_emulator):
    emulator = gripper_emulator()
    with _gripper(emulator) as gripper:
        with pytest.raises(ModbusError, match=r"exception reply 3 \(illegal data value\)"):
            gripper._bus.write_register(1, AG95_REGISTERS["force"].address, 5)
    assert emulator.requests == 1


def test_force_range_is_checked(gripper_emulator):
    with _gripper(gripper_emulator()) as gripper, pytest.raises(ValueError, match="20-100"):
        gripper.set_force(10)


def test_missing_port_names_it():
    with pytest.raises(HardwareError, match="/dev/diffstir-no-such-port"):
        AG95Gripper("/dev/diffstir-no-such-port")


def test_docs_register_table_matches_the_map():
    docs = (Path(__file__).parents[2] / "docs" / "hardware.md").read_text()
    for name, register in AG95_REGISTERS.items():
        row = re.search(rf"^\| `0x{register.address:04X}` \| `{name}` \|.*\| (\w+) \|$", docs, re.MULTILINE)
        assert row, f"docs/hardware.md has no register table row for 0x{register.address:04X} {name}"
        assert row.group(1) == ("yes" if register.confirmed else "no")
