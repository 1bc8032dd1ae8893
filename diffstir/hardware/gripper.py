"""The DH-Robotics AG-95 adaptive gripper over Modbus-RTU (RS-485): initialise, set force, close on the rod.

The register map lives in ``AG95_REGISTERS`` and nowhere else. It comes from DH-Robotics' Modbus-RTU manuals
for the AG and PGE series (sibling models) and from public drivers written against them; none of it has been
confirmed on an AG-95 here (no hardware was available), hence ``confirmed=False`` on every entry.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from enum import IntEnum

from diffstir.hardware.errors import GripperError, GripperTimeout
from diffstir.hardware.modbus import ModbusRTU


@dataclass(frozen=True)
class Register:
    """One holding register: ``address``, ``access`` ("r", "w" or "rw"), what its values mean, and whether the
    map entry was confirmed on real hardware."""

    address: int
    access: str
    meaning: str
    confirmed: bool = False


AG95_REGISTERS: dict[str, Register] = {
    "initialise": Register(0x0100, "w", "1: initialise (find the stroke's ends); 0xA5: full recalibration"),
    "force": Register(0x0101, "rw", "gripping force, percent of the maximum, 20-100"),
    "position": Register(0x0103, "rw", "target opening, permille of the stroke: 0 closed, 1000 open"),
    "init_state": Register(0x0200, "r", "0: not initialised, 1: initialised, 2: initialising"),
    "grip_state": Register(0x0201, "r", "0: moving, 1: reached the target (no object), 2: object caught, "
                                        "3: object dropped"),
    "position_feedback": Register(0x0202, "r", "current opening, permille of the stroke"),
}
"""AG-95 register map (DH AG/PGE Modbus-RTU manual family; not confirmed on hardware here)."""

INITIALISE = 0x01
FULL_INITIALISE = 0xA5


class InitState(IntEnum):
    """Values of register ``init_state``."""

    NOT_INITIALISED = 0
    INITIALISED = 1
    INITIALISING = 2


class GripState(IntEnum):
    """Values of register ``grip_state``."""

    MOVING = 0
    REACHED = 1
    CAUGHT = 2
    DROPPED = 3


@dataclass(frozen=True)
class GripperStatus:
    """A snapshot of the gripper: initialisation, grip state and opening [permille of the stroke]."""

    init: InitState
    grip: GripState
    position: int


class Gripper(ABC):
    """What a session needs from the gripper that holds the rod."""

    @abstractmethod
    def initialise(self, timeout: float = 10.0) -> None:
        """Initialise (home) the gripper; returns when done, raises ``GripperTimeout`` after ``timeout`` [s]."""

    @abstractmethod
    def set_force(self, percent: float) -> None:
        """Gripping force for the next closing, percent of the maximum (20-100)."""

    @abstractmethod
    def close_on_rod(self, timeout: float = 5.0) -> GripperStatus:
        """Close until the fingers stop on the rod; raises ``GripperError`` if they close on nothing."""

    @abstractmethod
    def status(self) -> GripperStatus:
        """Read the current state."""

    @abstractmethod
    def close(self) -> None:
        """Release the connection (the gripper keeps holding)."""

    def __enter__(self) -> "Gripper":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class AG95Gripper(Gripper):
    """DH-Robotics AG-95 on an RS-485 adapter.

    Args:
        port: serial port or pyserial URL of the RS-485 adapter.
        slave: Modbus slave id (factory default 1).
        baudrate: line speed [bit/s] (factory default 115200, 8N1).
        timeout: time allowed for one Modbus reply [s].
        retries: Modbus retries after a timeout or CRC error.
        poll_interval: period of status polling while waiting for a motion [s].
    """

    def __init__(self, port: str, *, slave: int = 1, baudrate: int = 115200, timeout: float = 0.2,
                 retries: int = 3, poll_interval: float = 0.05) -> None:
        self.port, self.slave, self.poll_interval = port, slave, poll_interval
        self._bus = ModbusRTU(port, baudrate=baudrate, timeout=timeout, retries=retries,
                              name=f"AG-95 gripper (slave {slave})")

    def _read(self, name: str) -> int:
        return self._bus.read_registers(self.slave, AG95_REGISTERS[name].address)[0]

    def _write(self, name: str, value: int) -> None:
        self._bus.write_register(self.slave, AG95_REGISTERS[name].address, value)

    def initialise(self, timeout: float = 10.0, *, full: bool = False) -> None:
        """Write ``initialise`` (1, or 0xA5 with ``full``) and wait for ``init_state`` = initialised."""
        self._write("initialise", FULL_INITIALISE if full else INITIALISE)
        self._wait("init_state", InitState, {InitState.INITIALISED}, timeout)

    def set_force(self, percent: float) -> None:
        if not 20 <= percent <= 100:
            raise ValueError(f"AG-95 on {self.port}: force {percent} %; expected 20-100 % of the maximum")
        self._write("force", int(round(percent)))

    def set_position(self, permille: float) -> None:
        """Target opening, permille of the stroke (0 closed, 1000 open); the motion starts at once."""
        if not 0 <= permille <= 1000:
            raise ValueError(f"AG-95 on {self.port}: position {permille}; expected 0-1000 permille")
        self._write("position", int(round(permille)))

    def open(self, timeout: float = 5.0) -> GripperStatus:
        """Open fully and wait for ``grip_state`` = reached."""
        self.set_position(1000)
        self._wait("grip_state", GripState, {GripState.REACHED}, timeout)
        return self.status()

    def close_on_rod(self, timeout: float = 5.0) -> GripperStatus:
        """Command full closing and wait for ``grip_state`` = caught (the fingers stopped on the rod)."""
        self.set_position(0)
        state = self._wait("grip_state", GripState, {GripState.CAUGHT, GripState.REACHED, GripState.DROPPED},
                           timeout, expected="CAUGHT")
        if state is not GripState.CAUGHT:
            raise GripperError(f"AG-95 on {self.port}: register 0x0201 (grip_state) reports {state.name} after "
                               f"closing; expected CAUGHT: is the rod between the fingers?")
        return self.status()

    def status(self) -> GripperStatus:
        return GripperStatus(InitState(self._read("init_state")), GripState(self._read("grip_state")),
                             self._read("position_feedback"))

    def close(self) -> None:
        self._bus.close()

    def _wait(self, name: str, kind: type[IntEnum], accept: set, timeout: float, *, expected: str | None = None):
        """Poll register ``name`` until its value is in ``accept``; ``GripperTimeout`` names the register,
        the last state seen and the awaited one."""
        deadline = time.monotonic() + timeout
        while True:
            value = kind(self._read(name))
            if value in accept:
                return value
            if time.monotonic() > deadline:
                awaited = expected or " or ".join(sorted(s.name for s in accept))
                raise GripperTimeout(
                    f"AG-95 on {self.port}: register 0x{AG95_REGISTERS[name].address:04X} ({name}) still "
                    f"{value.name} after {timeout} s; expected {awaited}")
            time.sleep(self.poll_interval)
