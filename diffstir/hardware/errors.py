"""Errors and warnings of the rig's devices.

Every message names the device and its port, what was expected and what came.
"""

from __future__ import annotations


class HardwareError(RuntimeError):
    """A device could not be opened or did not behave as its protocol says."""


class DeviceDisconnected(HardwareError):
    """The device went away mid-session (cable pulled, USB reset, power lost)."""


class SensorStalled(HardwareError):
    """The force sensor sent no valid sample within its stall timeout."""


class ModbusError(HardwareError):
    """A Modbus-RTU transaction failed after all retries (no answer, CRC errors, malformed or exception reply)."""


class GripperError(HardwareError):
    """The gripper reported a state the session cannot continue from (rod not caught, rod dropped)."""


class GripperTimeout(GripperError):
    """The gripper did not reach the awaited state within the timeout."""


class MissingExtraError(ImportError):
    """An optional robot backend's package is not installed; the message says what to install."""


class HardwareWarning(UserWarning):
    """Something was skipped or repaired on the fly (a garbled sample line); the session goes on."""
