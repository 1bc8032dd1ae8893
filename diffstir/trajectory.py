"""Rod trajectories: where the rod's axis is, over time, and how it turns about its own axis.

A trajectory is sampled data (times and poses); the simulator interpolates it linearly to its own time step.
Constructors build the stirring programmes used in studies and validation, and ``through_samples`` the path the
arm moved through a recording's samples.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from diffstir.recording.files import warn
from diffstir.recording.smoothing import smooth_path, smoothing_spline

#: Rate [Hz] at which ``through_samples`` samples its spline: along a circle of radius R at speed U, the chords of
#: the dense samples turn the rod's velocity by U / (R · rate) at each sample, 1e-3 rad for the benchmarks' 15 mm
#: circle at 0.06 m/s.
REPLAY_RATE = 4000.0


@dataclass(frozen=True)
class Trajectory:
    """Rod poses over time, in the cup frame (origin on the cup's axis, z up).

    Attributes:
        t: sample times [s], strictly increasing, shape (T,).
        xy: horizontal position of the rod's axis [m], shape (T, 2).
        z: vertical displacement of the rod from its rest immersion [m], up positive, shape (T,).
        angle: rotation of the rod about its own axis [rad], counter-clockwise seen from above, shape (T,).
    """

    t: np.ndarray
    xy: np.ndarray
    z: np.ndarray
    angle: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=np.float64)
        n = t.shape[0]
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "xy", np.asarray(self.xy, dtype=np.float64).reshape(n, 2))
        object.__setattr__(self, "z", np.broadcast_to(np.asarray(self.z, dtype=np.float64), (n,)).copy())
        object.__setattr__(self, "angle", np.broadcast_to(np.asarray(self.angle, dtype=np.float64), (n,)).copy())
        if n < 2:
            raise ValueError("trajectory.t: need at least 2 samples")
        if not np.all(np.diff(t) > 0):
            i = int(np.argmin(np.diff(t)))
            raise ValueError(f"trajectory.t must increase strictly; t[{i}] = {t[i]} s, t[{i + 1}] = {t[i + 1]} s")
        for name in ("t", "xy", "z", "angle"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"trajectory.{name} holds NaN or infinite values")

    @property
    def duration(self) -> float:
        """Time span [s]."""
        return float(self.t[-1] - self.t[0])

    def poses(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Linear interpolation of (xy [m], z [m], angle [rad]) at ``times`` [s]; held constant outside the span."""
        times = np.asarray(times, dtype=np.float64)
        xy = np.stack([np.interp(times, self.t, self.xy[:, k]) for k in range(2)], axis=-1)
        return xy, np.interp(times, self.t, self.z), np.interp(times, self.t, self.angle)

    def velocity(self) -> np.ndarray:
        """Horizontal velocity of the rod's axis at the samples [m/s], second-order differences on any spacing."""
        return np.stack([np.gradient(self.xy[:, k], self.t) for k in range(2)], axis=-1)

    def max_speed(self, rod_radius: float = 0.0) -> float:
        """Largest speed of any point of a rod of radius ``rod_radius`` [m]: translation plus spin [m/s]."""
        spin = np.abs(np.gradient(self.angle, self.t)) * rod_radius
        vz = np.abs(np.gradient(self.z, self.t))
        return float(np.max(np.linalg.norm(self.velocity(), axis=-1) + spin + vz))

    def max_offset(self) -> float:
        """Largest distance of the rod's axis from the cup's axis [m]."""
        return float(np.max(np.linalg.norm(self.xy, axis=-1)))


def _ramp(t: np.ndarray, ramp_time: float) -> np.ndarray:
    """Smooth start, 0 -> 1 over ``ramp_time`` [s] (cosine), so the rod does not jump to full speed."""
    if ramp_time <= 0:
        return np.ones_like(t)
    s = np.clip(t / ramp_time, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(math.pi * s)


def _ramp_integral(t: np.ndarray, ramp_time: float) -> np.ndarray:
    """Integral of ``_ramp`` from 0 to t [s]: the phase of a programme that ramps up to a constant rate."""
    if ramp_time <= 0:
        return t.copy()
    s = np.clip(t, 0.0, ramp_time)
    inside = 0.5 * s - 0.5 * ramp_time / math.pi * np.sin(math.pi * s / ramp_time)
    return inside + np.clip(t - ramp_time, 0.0, None)


def _times(duration: float, sample_rate: float) -> np.ndarray:
    if duration <= 0:
        raise ValueError(f"duration = {duration} s; expected a positive duration")
    n = max(2, int(round(duration * sample_rate)) + 1)
    return np.linspace(0.0, duration, n)


def circle(
    radius: float, speed: float, duration: float, *, ramp_time: float = 0.5, clockwise: bool = False,
    sample_rate: float = 1000.0, start_angle: float = 0.0,
) -> Trajectory:
    """The rod's axis on a circle of ``radius`` [m] about the cup's axis at tangential ``speed`` [m/s].

    The speed ramps up smoothly over ``ramp_time`` [s]; the rod starts at rest at angle ``start_angle`` [rad].
    """
    if radius <= 0 or speed <= 0:
        raise ValueError(f"circle: radius = {radius} m and speed = {speed} m/s must be positive")
    t = _times(duration, sample_rate)
    phase = start_angle + (-1 if clockwise else 1) * speed / radius * _ramp_integral(t, ramp_time)
    return Trajectory(t, radius * np.stack([np.cos(phase), np.sin(phase)], -1), 0.0, 0.0)


def spin(angular_speed: float, duration: float, *, ramp_time: float = 0.1, sample_rate: float = 1000.0) -> Trajectory:
    """The rod turning about its own axis at the cup's centre at ``angular_speed`` [rad/s] (Couette flow)."""
    t = _times(duration, sample_rate)
    return Trajectory(t, np.zeros((t.size, 2)), 0.0, angular_speed * _ramp_integral(t, ramp_time))


def translate(
    velocity: tuple[float, float], duration: float, *, start: tuple[float, float] = (0.0, 0.0),
    ramp_time: float = 0.05, sample_rate: float = 1000.0,
) -> Trajectory:
    """The rod moving in a straight line at ``velocity`` [m/s] from ``start`` [m], after a smooth ramp."""
    t = _times(duration, sample_rate)
    s = _ramp_integral(t, ramp_time)
    xy = np.asarray(start, dtype=np.float64)[None, :] + s[:, None] * np.asarray(velocity, dtype=np.float64)[None, :]
    return Trajectory(t, xy, 0.0, 0.0)


def stationary(duration: float, *, position: tuple[float, float] = (0.0, 0.0),
               sample_rate: float = 100.0) -> Trajectory:
    """The rod held still at ``position`` [m] for ``duration`` [s]."""
    t = _times(duration, sample_rate)
    return Trajectory(t, np.broadcast_to(np.asarray(position, dtype=np.float64), (t.size, 2)), 0.0, 0.0)


def through_samples(t: np.ndarray, xy: np.ndarray, z: np.ndarray | float = 0.0, *,
                    rate: float = REPLAY_RATE, where: str = "rod path") -> Trajectory:
    """The rod's path as the arm moved it through sampled poses (a recording's ``t`` [s], ``xy`` [m], ``z`` [m]):
    each coordinate's cubic smoothing spline with its smoothing chosen by generalized cross-validation
    (``diffstir.recording.smoothing``), sampled at ``rate`` [Hz] or at the samples' own rate if that is higher.
    Positions known to every digit give the interpolating spline; jittered ones (an arm's encoder or tracker, σ_p
    of 10-50 µm) the path without the jitter, and a RecordingWarning from ``where`` states the rms jitter removed
    when it exceeds the positions' rounding.

    Replaying the samples along chords makes the rod's velocity jump at every sample, in direction by U h / R on a
    circle of radius R at speed U sampled every h; the fluid's force follows the velocity, so a component read
    along a fixed axis is off by up to that angle times the force (0.04 rad, 2.9 mN mean on the syrup case of
    ``scripts/diagnosis_benchmark.py`` at 100 Hz: ``scripts/replay_gap.py``). A spline through jittered samples
    turns σ_p into velocity noise of order σ_p / h (0.17 m/s peaks on a 0.05 m/s stir at 1 kHz and 20 µm).
    """
    t = np.asarray(t, dtype=np.float64)
    path = smooth_path(t, xy)
    message = path.jitter_message(where)
    if message is not None:
        warn(message)
    dense = t[0] + np.linspace(0.0, t[-1] - t[0], max(t.size, int(math.ceil((t[-1] - t[0]) * rate)) + 1))
    z = np.broadcast_to(np.asarray(z, dtype=np.float64), t.shape)
    return Trajectory(dense, path.position(dense), smoothing_spline(t, z)(dense), 0.0)
