"""What the force sensor reports, given the horizontal force on the rod: the spec's three modes, in torch.

The readings are smooth so that a fitter can backpropagate through them:

* component:  F · a, with the axis a normalised (it is a unit vector to within validate.AXIS_TOLERANCE)
* tangential: F · (-v) / sqrt(|v|² + VELOCITY_EPS²): the drag opposing the motion; tends to 0 as v -> 0 and
  differs from F · (-v/|v|) by a relative (VELOCITY_EPS/|v|)²/2, i.e. 5e-7 at 0.1 m/s
* magnitude:  sqrt(|F|² + FORCE_EPS²) - FORCE_EPS: |F| within FORCE_EPS, 0 at F = 0, gradient finite there
* one_sided:  relu(value)
"""

from __future__ import annotations

import numpy as np
import torch

from diffstir.recording.errors import RecordingError
from diffstir.recording.format import SENSOR_MODES, Recording, SensorSpec
from diffstir.recording.resample import resample_force

VELOCITY_EPS = 1e-4  # m/s: the rod speed below which the tangential direction fades out smoothly
FORCE_EPS = 1e-6  # N: smoothing of |F|, far below any sensor's resolution (0.005 N in the paper)


def _check_xy(name: str, value: torch.Tensor, length: int | None = None) -> None:
    if value.ndim != 2 or value.shape[1] != 2 or (length is not None and value.shape[0] != length):
        expected = f"({length}, 2)" if length is not None else "(T, 2)"
        raise RecordingError(f"sensor_reading: {name} has shape {tuple(value.shape)}; expected {expected}")


def sensor_reading(force_xy: torch.Tensor, velocity_xy: torch.Tensor | None, spec: SensorSpec) -> torch.Tensor:
    """The sensor's reading [N], shape (T,), of the horizontal force ``force_xy`` [N] (T, 2) on a rod moving at
    ``velocity_xy`` [m/s] (T, 2; needed in tangential mode only), as ``spec`` defines it."""
    _check_xy("force_xy", force_xy)
    if spec.mode == "component":
        if spec.axis is None:
            raise RecordingError("sensor_reading: sensor.axis is missing; mode component needs a unit vector")
        axis = torch.as_tensor(spec.axis, dtype=force_xy.dtype, device=force_xy.device)
        value = force_xy @ (axis / torch.linalg.vector_norm(axis))
    elif spec.mode == "tangential":
        if velocity_xy is None:
            raise RecordingError("sensor_reading: mode tangential needs velocity_xy (m/s)")
        _check_xy("velocity_xy", velocity_xy, force_xy.shape[0])
        velocity_xy = velocity_xy.to(force_xy.dtype)
        speed = torch.sqrt((velocity_xy * velocity_xy).sum(-1) + VELOCITY_EPS**2)
        value = -(force_xy * velocity_xy).sum(-1) / speed
    elif spec.mode == "magnitude":
        value = torch.sqrt((force_xy * force_xy).sum(-1) + FORCE_EPS**2) - FORCE_EPS
    else:
        raise RecordingError(f"sensor_reading: sensor.mode = {spec.mode!r}; expected one of {', '.join(SENSOR_MODES)}")
    return torch.relu(value) if spec.one_sided else value


def sensor_reading_np(force_xy, velocity_xy, spec: SensorSpec) -> np.ndarray:
    """sensor_reading on numpy arrays, in float64."""
    force = torch.as_tensor(np.asarray(force_xy, dtype=np.float64))
    velocity = None if velocity_xy is None else torch.as_tensor(np.asarray(velocity_xy, dtype=np.float64))
    return sensor_reading(force, velocity, spec).numpy()


def simulated_reading(rec: Recording, sim_times, sim_force_xy: torch.Tensor) -> torch.Tensor:
    """What ``rec``'s sensor would have read [N], shape (T,), at the recording's times, had the fluid pushed the
    rod with the simulated horizontal force ``sim_force_xy`` [N] (S, 2) at ``sim_times`` [s] (S,):
    resample_force to rec.t, then sensor_reading with rec.velocity(). Compare it with ``rec.force``."""
    force = resample_force(sim_times, sim_force_xy, rec.t)
    velocity = torch.as_tensor(rec.velocity(), dtype=force.dtype, device=force.device)
    return sensor_reading(force, velocity, rec.sensor)
