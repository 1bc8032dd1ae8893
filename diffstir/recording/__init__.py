"""Stirring recordings: the diffstir-recording/1 format (recording.yaml + stir.csv), its validation, a
crash-safe streaming writer, the physical plausibility of a recording's force and motion, the force sensor's modes
and resampling between recording and simulation times.

See docs/recording-format.md. All quantities are SI (m, s, N, kg/m³). Importing this package does not import
torch (a recorder on a robot computer does not need it); the sensor and resampling functions load it on first use.
"""

import importlib

from diffstir.recording.errors import RecordingError, RecordingNotFound, RecordingWarning
from diffstir.recording.files import load_recording, save_recording
from diffstir.recording.format import (
    FORMAT, CupGeometry, DensityMeasurement, Recording, RodGeometry, SensorSpec,
)
from diffstir.recording.plausibility import check_plausibility
from diffstir.recording.stirring import stirring_frequency
from diffstir.recording.validate import validate_recording
from diffstir.recording.writer import RecordingWriter

_TORCH_MODULES = {
    "first_order_response": "diffstir.recording.sensor",
    "resample_force": "diffstir.recording.resample",
    "trajectory_at": "diffstir.recording.resample",
    "sensor_reading": "diffstir.recording.sensor",
    "sensor_reading_np": "diffstir.recording.sensor",
    "simulated_reading": "diffstir.recording.sensor",
}


def __getattr__(name: str):
    if name in _TORCH_MODULES:
        return getattr(importlib.import_module(_TORCH_MODULES[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "FORMAT",
    "CupGeometry",
    "DensityMeasurement",
    "Recording",
    "RecordingError",
    "RecordingNotFound",
    "RecordingWarning",
    "RecordingWriter",
    "RodGeometry",
    "SensorSpec",
    "check_plausibility",
    "first_order_response",
    "load_recording",
    "resample_force",
    "save_recording",
    "sensor_reading",
    "sensor_reading_np",
    "simulated_reading",
    "stirring_frequency",
    "trajectory_at",
    "validate_recording",
]
