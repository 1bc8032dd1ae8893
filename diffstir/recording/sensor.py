"""What the force sensor reports, given the horizontal force on the rod: the spec's three modes, in torch.

The readings are smooth so that a fitter can backpropagate through them:

* component:  F · a, with the axis a normalised (it is a unit vector to within validate.AXIS_TOLERANCE)
* tangential: F · (-v) / sqrt(|v|² + VELOCITY_EPS²): the drag opposing the motion; tends to 0 as v -> 0 and
  differs from F · (-v/|v|) by a relative (VELOCITY_EPS/|v|)²/2, i.e. 5e-7 at 0.1 m/s
* magnitude:  sqrt(|F|² + FORCE_EPS²) - FORCE_EPS: |F| within FORCE_EPS, 0 at F = 0, gradient finite there
* one_sided:  relu(value)

and, when the spec states a ``time_constant`` τ, through the sensor's first-order response τ dy/dt = x − y
(``first_order_response``), applied as a real sensor does, to the whole force history before it is sampled and
before a one-sided sensor clips it (``sensor_history``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from diffstir.recording.errors import RecordingError
from diffstir.recording.format import SENSOR_MODES, Recording, SensorSpec
from diffstir.recording.resample import resample_force, trajectory_at

RESPONSE_BLOCK = 256  # samples per block of first_order_response's exact scan
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


def first_order_response(x: torch.Tensor, times, time_constant: float | None) -> torch.Tensor:
    """y with τ dy/dt = x − y, y(t_0) = x(t_0), for ``x`` [any unit] (M,) or (M, k) linear between the
    increasing sample ``times`` [s] (M,) (first-order hold); ``time_constant`` τ [s], None or 0: y = x.

        y_k = Σ_{j ≤ k} exp(−(t_k − t_j)/τ) c_j,  c_0 = x_0,
        c_j = x_j − a_j x_{j−1} − (x_j − x_{j−1}) (τ/h_j)(1 − a_j),  a_j = exp(−h_j/τ),  h_j = t_j − t_{j−1},

    which is the exact recurrence y_k = a_k y_{k−1} + c_k, evaluated in blocks of ``RESPONSE_BLOCK`` samples
    (a matrix product within a block, the state carried between blocks). Differentiable in ``x``.
    """
    if not time_constant or x.shape[0] < 2:
        return x
    t = torch.as_tensor(np.asarray(times, dtype=np.float64))
    if t.shape[0] != x.shape[0] or not bool(torch.all(torch.diff(t) > 0)):
        raise RecordingError(f"first_order_response: times has shape {tuple(t.shape)}, x {tuple(x.shape)}; "
                             "expected one strictly increasing time (s) per sample")
    h = torch.diff(t)
    a = torch.exp(-h / time_constant)
    b = (time_constant / h) * (1.0 - a)
    shape = (-1,) + (1,) * (x.ndim - 1)
    a_x, b_x = (v.to(device=x.device, dtype=x.dtype).reshape(shape) for v in (a, b))
    c = torch.cat([x[:1], x[1:] - a_x * x[:-1] - (x[1:] - x[:-1]) * b_x])
    blocks, state = [], None
    for start in range(0, x.shape[0], RESPONSE_BLOCK):
        tb = t[start:start + RESPONSE_BLOCK]
        decay = torch.tril(torch.exp(-(tb[:, None] - tb[None, :]).clamp(min=0.0) / time_constant))
        y = decay.to(device=x.device, dtype=x.dtype) @ c[start:start + RESPONSE_BLOCK]
        if state is not None:
            carry = torch.exp(-(tb - t[start - 1]) / time_constant).to(device=x.device, dtype=x.dtype).reshape(shape)
            y = y + carry * state
        blocks.append(y)
        state = y[-1]
    return torch.cat(blocks)


def sensor_history(force_xy: torch.Tensor, velocity_xy: torch.Tensor | None, times, spec: SensorSpec) -> torch.Tensor:
    """The readings [N], (S,), that a sensor as ``spec`` states it gives of the force history ``force_xy`` [N]
    (S, 2) on a rod moving at ``velocity_xy`` [m/s] (S, 2; tangential mode only), at increasing ``times`` [s]
    (S,): the mode's value, through the stated first-order response, then clipped if one-sided, the order of a
    real sensor (the element responds to the force; the clip is on what it reports)."""
    value = sensor_reading(force_xy, velocity_xy, replace(spec, one_sided=False))
    value = first_order_response(value, times, spec.time_constant)
    return torch.relu(value) if spec.one_sided else value


def sensor_history_at(rec: Recording, sim_times, sim_force_xy: torch.Tensor, times) -> torch.Tensor:
    """``sensor_history`` of the simulated horizontal force ``sim_force_xy`` [N] (S, 2) at ``sim_times`` [s] (S,),
    with the rod's velocities there from the recording (``trajectory_at``), resampled to ``times`` [s]: what
    ``rec``'s sensor reads when it states a response time."""
    clipped = np.clip(np.asarray(sim_times, dtype=np.float64), rec.t[0], rec.t[-1])
    velocity = torch.as_tensor(trajectory_at(rec, clipped)[1], dtype=sim_force_xy.dtype, device=sim_force_xy.device)
    return resample_force(sim_times, sensor_history(sim_force_xy, velocity, sim_times, rec.sensor), times)


def sensor_reading_np(force_xy, velocity_xy, spec: SensorSpec) -> np.ndarray:
    """sensor_reading on numpy arrays, in float64."""
    force = torch.as_tensor(np.asarray(force_xy, dtype=np.float64))
    velocity = None if velocity_xy is None else torch.as_tensor(np.asarray(velocity_xy, dtype=np.float64))
    return sensor_reading(force, velocity, spec).numpy()


def simulated_reading(rec: Recording, sim_times, sim_force_xy: torch.Tensor) -> torch.Tensor:
    """What ``rec``'s sensor would have read [N], shape (T,), at the recording's times, had the fluid pushed the
    rod with the simulated horizontal force ``sim_force_xy`` [N] (S, 2) at ``sim_times`` [s] (S,):
    resample_force to rec.t, then sensor_reading with rec.velocity(); with a stated ``time_constant``,
    ``sensor_history_at`` rec.t. Compare it with ``rec.force``."""
    if rec.sensor.time_constant:
        return sensor_history_at(rec, sim_times, sim_force_xy, rec.t)
    force = resample_force(sim_times, sim_force_xy, rec.t)
    velocity = torch.as_tensor(rec.velocity(), dtype=force.dtype, device=force.device)
    return sensor_reading(force, velocity, rec.sensor)
