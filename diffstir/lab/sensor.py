"""A force sensor model for the virtual lab: what a real sensor makes of the fluid's force on the rod.

The true horizontal force F(t) [N] on the rod, on the simulation's uniform time grid, goes through (in this order)

1. the recording's sensor mode (component / tangential / magnitude, ``diffstir.recording.sensor_reading_np``),
2. gain error:        y = (1 + g) x                                    g [1]
3. first-order lag:   τ dy/dt = x − y, exact for input held over each step: y_k = a y_{k−1} + (1 − a) x_k,
                      a = exp(−Δt/τ)                                   τ [s]
4. dead band:         y = 0 for |x| ≤ d, x − d sign(x) beyond          d [N]
5. baseline offset and slow drift: y + b0 + r t + W(t), W a random walk with increments N(0, σ_w² Δt)
                                                                       b0 [N], r [N/s], σ_w [N/√s]
6. sampling at ``sample_rate`` [Hz] (linear interpolation of the dense signal at t_k = t_0 + k / f_s),
7. white noise:       y_k + N(0, σ²)                                   σ [N]
8. quantisation:      q round(y / q)                                   q = resolution [N]
9. one-sided reading: max(0, y) (a compression-only sensor)
10. dead start:       y_k = 0 for t_k − t_0 < t_dead (a sensor that wakes late reads zero until then)  t_dead [s]

The rod's recorded position goes through the arm's encoder or tracker: p_k = q_p round((p(t_k) + N(0, σ_p²)) / q_p)
per axis, σ_p [m] the position jitter and q_p [m] the resolution it is written to; the recorded time is the rig's
clock, t_k + t_origin, t_origin [s] the clock's value at the programme's start (a rig's uptime, a Unix time).

Each step is a plain numpy function, so each can be checked against its definition.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.signal import lfilter

from diffstir.errors import is_number, is_whole
from diffstir.recording import SensorSpec
from diffstir.recording.format import SENSOR_MODES
from diffstir.recording.sensor import sensor_reading_np


def first_order_lag(x: np.ndarray, dt: float, time_constant: float) -> np.ndarray:
    """y with τ dy/dt = x − y on samples ``x`` spaced ``dt`` [s], ``time_constant`` τ [s]; y_0 = x_0.

    y_k = a y_{k−1} + (1 − a) x_k, a = exp(−dt/τ): exact for x held constant over (t_{k−1}, t_k]. τ = 0: y = x.
    """
    x = np.asarray(x, dtype=np.float64)
    if time_constant == 0 or x.size == 0:
        return x.copy()
    a = math.exp(-dt / time_constant)
    return lfilter([1.0 - a], [1.0, -a], x, zi=[a * x[0]])[0]


def dead_band(x: np.ndarray, width: float) -> np.ndarray:
    """Dead zone of half-width ``width`` [N]: 0 for |x| ≤ width, x − width sign(x) beyond."""
    x = np.asarray(x, dtype=np.float64)
    return np.sign(x) * np.maximum(np.abs(x) - width, 0.0)


def quantise(x: np.ndarray, resolution: float) -> np.ndarray:
    """Round to the nearest multiple of ``resolution`` [N] (0: unchanged); −0 is written as 0. The multiple is
    rounded to 12 decimals (or 3 below the resolution's), so that it is written as 0.0802, not 0.08020000000000001."""
    x = np.asarray(x, dtype=np.float64)
    if resolution == 0:
        return x.copy()
    decimals = max(12, math.ceil(-math.log10(resolution)) + 3)
    return np.round(resolution * np.round(x / resolution), decimals) + 0.0


def one_sided(x: np.ndarray) -> np.ndarray:
    """max(0, x): a compression-only sensor."""
    return np.maximum(np.asarray(x, dtype=np.float64), 0.0)


@dataclass(frozen=True)
class SensorModel:
    """The force sensor of a virtual rig; see the module docstring for the equations.

    Attributes:
        mode, axis, one_sided: what the reading means, as in the recording format (``SensorSpec``).
        sample_rate: f_s [Hz].
        resolution: q [N], the quantisation step (0: none); written to the recording as ``sensor.resolution``.
        noise_std: σ [N], white noise per sample.
        lag_time: τ [s], first-order lag.
        dead_band: d [N], half-width of the dead zone.
        drift_rate: r [N/s], linear baseline drift.
        drift_walk: σ_w [N/√s], random-walk baseline drift.
        gain_error: g [1], relative calibration error (also scales the density block's readings).
        offset: b0 [N], baseline offset left after the dry-run subtraction (cancels in the density's G − R).
        density_hold: [s], how long each static density reading is averaged (its noise is σ / sqrt(f_s hold)).
        stated_time_constant: [s], the response time the recording's sensor block states (what a calibration of
            this sensor found; None: not stated). It can differ from ``lag_time``, which is what the sensor does.
        dead_start: t_dead [s], how long after the first sample the sensor reads 0 before it wakes.
        position_jitter: σ_p [m], white noise per sample and axis on the recorded rod position (encoder, tracker).
        position_resolution: q_p [m], the step the recorded positions are rounded to (0: none).
        time_origin: t_origin [s], the rig clock's value at the programme's start, added to the recorded times.
        density_repeats: how many times each density reading (G and R) is taken; more than 1 writes the list.
    """

    mode: str = "tangential"
    axis: tuple[float, float] | None = None
    one_sided: bool = False
    sample_rate: float = 100.0
    resolution: float = 0.005
    noise_std: float = 0.0
    lag_time: float = 0.0
    dead_band: float = 0.0
    drift_rate: float = 0.0
    drift_walk: float = 0.0
    gain_error: float = 0.0
    offset: float = 0.0
    density_hold: float = 2.0
    stated_time_constant: float | None = None
    dead_start: float = 0.0
    position_jitter: float = 0.0
    position_resolution: float = 0.0
    time_origin: float = 0.0
    density_repeats: int = 1

    def __post_init__(self) -> None:
        if self.mode not in SENSOR_MODES:
            raise ValueError(f"sensor.mode = {self.mode!r}; expected one of {', '.join(SENSOR_MODES)}")
        if self.axis is not None:
            object.__setattr__(self, "axis", tuple(float(a) for a in self.axis))
            if len(self.axis) != 2 or abs(math.hypot(*self.axis) - 1.0) > 1e-3:
                raise ValueError(f"sensor.axis = {self.axis!r}; expected a horizontal unit vector [1, 1]")
        if self.mode == "component" and self.axis is None:
            raise ValueError("sensor.axis is missing; mode component needs a horizontal unit vector")
        if not (is_number(self.sample_rate) and self.sample_rate > 0):
            raise ValueError(f"sensor.sample_rate = {self.sample_rate!r}; expected a positive rate in Hz")
        for name, unit in (("resolution", "N"), ("noise_std", "N"), ("lag_time", "s"), ("dead_band", "N"),
                           ("drift_walk", "N/s^0.5"), ("density_hold", "s"), ("dead_start", "s"),
                           ("position_jitter", "m"), ("position_resolution", "m"), ("time_origin", "s")):
            value = getattr(self, name)
            if not (is_number(value) and value >= 0):
                raise ValueError(f"sensor.{name} = {value!r}; expected a number >= 0 in {unit}")
        for name, unit in (("drift_rate", "N/s"), ("offset", "N")):
            if not is_number(getattr(self, name)):
                raise ValueError(f"sensor.{name} = {getattr(self, name)!r}; expected a finite number in {unit}")
        stated = self.stated_time_constant
        if stated is not None and not (is_number(stated) and stated >= 0):
            raise ValueError(f"sensor.stated_time_constant = {stated!r}; expected null or a number >= 0 in s")
        if not is_whole(self.density_repeats, 1):
            raise ValueError(f"sensor.density_repeats = {self.density_repeats!r}; expected a whole number >= 1")
        if not (is_number(self.gain_error) and self.gain_error > -1):
            raise ValueError(f"sensor.gain_error = {self.gain_error!r}; expected a relative error > -1 (1)")

    def spec(self) -> SensorSpec:
        """The recording's ``sensor`` block: mode, axis, one_sided, resolution [N] (None if 0), sample_rate [Hz],
        time_constant [s] (the stated one)."""
        return SensorSpec(mode=self.mode, axis=self.axis if self.mode == "component" else None,
                          one_sided=self.one_sided, resolution=self.resolution or None, sample_rate=self.sample_rate,
                          time_constant=self.stated_time_constant)

    def as_dict(self) -> dict:
        """Every setting, SI, for the truth file."""
        return asdict(self)

    def sample_times(self, start: float, stop: float) -> np.ndarray:
        """t_k = start + k / f_s [s] within [start, stop]."""
        n = int(math.floor((stop - start) * self.sample_rate + 1e-9)) + 1
        return start + np.arange(n) / self.sample_rate

    def read(self, times: np.ndarray, force_xy: np.ndarray, velocity_xy: np.ndarray, sample_times: np.ndarray,
             rng: np.random.Generator) -> np.ndarray:
        """The sensor's readings [N] at ``sample_times`` [s] of the true force ``force_xy`` [N] (S, 2) on a rod
        moving at ``velocity_xy`` [m/s] (S, 2), both at the uniform ``times`` [s] (S,)."""
        times = np.asarray(times, dtype=np.float64)
        steps = np.diff(times)
        if times.size < 2 or not np.allclose(steps, steps[0], rtol=1e-6, atol=0):
            raise ValueError("SensorModel.read: times [s] must be uniform with at least 2 samples")
        dt = float(steps[0])
        mode = SensorSpec(mode=self.mode, axis=self.axis)
        x = sensor_reading_np(force_xy, velocity_xy, mode)
        x = first_order_lag((1.0 + self.gain_error) * x, dt, self.lag_time)
        x = dead_band(x, self.dead_band)
        walk = np.concatenate([[0.0], np.cumsum(rng.normal(0.0, self.drift_walk * math.sqrt(dt), times.size - 1))])
        x = x + self.offset + self.drift_rate * (times - times[0]) + walk
        y = np.interp(sample_times, times, x)
        y = y + rng.normal(0.0, self.noise_std, y.size) if self.noise_std > 0 else y
        y = quantise(y, self.resolution)
        y = one_sided(y) if self.one_sided else y
        return np.where(sample_times - sample_times[0] < self.dead_start, 0.0, y)

    def positions(self, xy: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The recorded rod positions [m] (K, 2) of the true ones ``xy`` [m] (K, 2): jitter σ_p, then rounding to
        q_p."""
        xy = np.asarray(xy, dtype=np.float64)
        if self.position_jitter > 0:
            xy = xy + rng.normal(0.0, self.position_jitter, xy.shape)
        return quantise(xy, self.position_resolution)

    def static_reading(self, force: float, rng: np.random.Generator) -> float:
        """A held, averaged reading [N] of a constant axial ``force`` [N]: gain, offset, the noise averaged over
        ``density_hold`` seconds, quantised to the resolution."""
        samples = max(1.0, self.density_hold * self.sample_rate)
        noisy = (1.0 + self.gain_error) * force + self.offset + rng.normal(0.0, self.noise_std / math.sqrt(samples))
        return float(quantise(np.array([noisy]), self.resolution)[0])
