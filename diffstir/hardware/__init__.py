"""The rig's devices: the thin-film force sensor's ADC, the AG-95 gripper, the arm, and a recording session.

Library code only (no Hydra); the ``diffstir-record`` app (``diffstir.apps.record``) drives it from a config.
Emulated devices for tests and dry rehearsals are in ``diffstir.hardware.emulators``; a session's settings, the
``diffstir-record`` config's checked blocks, in ``diffstir.hardware.settings``. See docs/hardware.md.
"""

from diffstir.hardware.adc import ADC, Sample, SerialADC
from diffstir.hardware.arm import Arm, CupFrame, Pose, ReplayArm, URArm, XArmArm, load_trajectory
from diffstir.hardware.calibration import (
    Calibration, CalibrationPoint, Divider, fit_calibration, load_calibration, measure_point,
)
from diffstir.hardware.clock import ClockAligner, ClockFit, align_clocks
from diffstir.hardware.errors import (
    DeviceDisconnected, GripperError, GripperTimeout, HardwareError, HardwareWarning, MissingExtraError,
    ModbusError, SensorStalled,
)
from diffstir.hardware.filters import Baseline, Smoothed, adaptive_gaussian, gaussian_smooth, robust_noise
from diffstir.hardware.gripper import AG95_REGISTERS, AG95Gripper, Gripper, GripperStatus, GripState, InitState
from diffstir.hardware.modbus import ModbusRTU, crc16
from diffstir.hardware.session import Session, read_session
from diffstir.hardware.settings import (
    DRY_RUN_MODES, GRIP_FORCE_PERCENT, DensitySettings, DryRunSettings, GripSettings, SensorSettings, StirSettings,
)

__all__ = [
    "ADC", "AG95Gripper", "AG95_REGISTERS", "Arm", "Baseline", "Calibration", "CalibrationPoint", "ClockAligner",
    "ClockFit", "CupFrame", "DRY_RUN_MODES", "DensitySettings", "DeviceDisconnected", "Divider", "DryRunSettings",
    "GRIP_FORCE_PERCENT", "GripSettings", "GripState", "Gripper", "GripperError", "GripperStatus", "GripperTimeout",
    "HardwareError", "HardwareWarning", "InitState", "MissingExtraError", "ModbusError", "ModbusRTU", "Pose",
    "ReplayArm", "Sample", "SensorSettings", "SensorStalled", "SerialADC", "Session", "Smoothed", "StirSettings",
    "URArm", "XArmArm", "adaptive_gaussian", "align_clocks", "crc16", "fit_calibration", "gaussian_smooth",
    "load_calibration", "load_trajectory", "measure_point", "read_session", "robust_noise",
]
