"""A recording replayed in the simulator: which samples are fitted, which are held out, and what the sensor would
have read for a given fluid.

The simulation always starts from the settled fluid at the recording's first sample (the rod at rest there) and
runs to the end of the held-out window; later samples are not simulated. The fitted window starts where the sensor
wakes (``dead_start``), and the simulation still starts at the first sample: the flow the live readings see has
developed over the dead stretch. A 2-D slice gives a force per unit length
F' [N/m]; the rod in the recording's cup feels F = F' h C [N], h the rod's immersion and C = F_3D / (F'_2D h) the
slice's correction for the recording's rig (``diffstir.slice_correction``, from the 3-D finite-element reference:
the tip, the fluid below it and the free surface), at the flow index and Reynolds number the simulated fluid has at
the stir's shear rate U/a. C's own relative uncertainty joins the simulator's force error in every interval.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Protocol, Self, runtime_checkable

import numpy as np
import torch
from torch import Tensor, nn

from ..mpm import SimConfig, StirringSimulator
from ..recording import Recording, RecordingError
from ..recording.resample import resample_force
from ..recording.sensor import sensor_history_at, sensor_reading
from ..rig import Cup, Rig, Rod
from ..slice_correction import MOVING_SHARE, SliceCorrection, stir_correction, stir_scales
from ..trajectory import Trajectory, through_samples

#: Headroom above the fluid for the simulated cup [m]: the paper's cup is 16.5 cm tall and filled to 13 cm.
CUP_HEADROOM = 0.035

#: The chance [1] below which a constant leading stretch of readings is not a live sensor's: a live reading of
#: noise σ stays within the resolution's half-step of a value with a chance erf(q / (2 sqrt(2) σ)) per sample, and
#: a stretch of readings that would do so by this chance or less, while the rod moves, is a sensor not yet awake.
DEAD_START_CHANCE = 1e-3


@dataclass(frozen=True)
class DeadStart:
    """A sensor that wakes late: its readings hold one value from the first sample to ``until`` [s] (the last such
    sample, on the recording's clock) while the rod moves (``dead_start``). ``detected`` False: ``until`` is the
    first sample's time."""

    detected: bool
    until: float
    silent: str | None = None

    def summary(self) -> dict:
        """The report's ``dead_start``: {"detected", "until_s"} [s]."""
        return {"detected": self.detected, "until_s": self.until}

    def require_signal(self) -> None:
        """Raise ``RecordingError`` when the reading holds one value throughout: the sensor recorded no force."""
        if self.silent is not None:
            raise RecordingError(self.silent)


def dead_start(rec: Recording) -> DeadStart:
    """The leading stretch in which ``rec``'s reading holds its first value while the rod moves, when a live sensor
    would not do so (``DEAD_START_CHANCE``).

    The reading holds a value while it stays within half a resolution step q/2 of it (exactly, without a stated
    resolution). The stretch is a dead start when a live reading, with the noise level σ of the readings after it
    (1.4826 MAD of second differences / sqrt(6), at least q/sqrt(12)), would hold the value over its samples at
    which the rod moves (faster than ``MOVING_SHARE`` of its top speed) with a chance below ``DEAD_START_CHANCE``,
    and when it is more than twice as long as any later stretch that holds one value: a one-sided sensor reads
    zero while the force points away from it, every stirring period for as long, the first time a little longer
    while the force rises from rest. A reading that holds one value throughout has no dead start; ``silent`` then
    names the file and the ``force`` column for ``DeadStart.require_signal``.
    """
    force, t = rec.force, rec.t
    step = rec.sensor.resolution or 0.0
    tolerance = step / 2.0  # N
    changed = np.flatnonzero(np.abs(force - force[0]) > tolerance)
    if changed.size == 0:
        return DeadStart(detected=False, until=float(t[0]),
                         silent=f"{rec.source('csv')}: column 'force' reads {force[0]:g} N throughout"
                                + (f" (within its resolution of {step:g} N)" if step else "")
                                + "; the sensor recorded no force")
    woke = int(changed[0])  # the first live sample
    speed = np.linalg.norm(rec.velocity(), axis=1)
    moving = int(np.count_nonzero(speed[:woke] > MOVING_SHARE * speed.max())) if speed.max() > 0 else 0
    live = force[woke:]
    d2 = np.diff(live, 2) if live.size > 2 else np.zeros(1)
    noise = max(1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6.0), step / math.sqrt(12.0))
    if tolerance == 0.0:
        hold = 0.0  # a live reading does not repeat a value exactly
    elif noise == 0.0:
        hold = 1.0
    else:
        hold = math.erf(tolerance / (math.sqrt(2.0) * noise))
    chance = hold ** moving if moving else 1.0
    detected = chance < DEAD_START_CHANCE and 2 * _longest_hold(live, tolerance) < woke
    return DeadStart(detected=detected, until=float(t[woke - 1]) if detected else float(t[0]))


def _longest_hold(readings: np.ndarray, tolerance: float) -> int:
    """The most consecutive ``readings`` [N] that stay within ``tolerance`` [N] of the first of them."""
    longest, first = 0, 0
    for k in range(1, readings.size + 1):
        if k == readings.size or abs(readings[k] - readings[first]) > tolerance:
            longest, first = max(longest, k - first), k
    return longest


@dataclass(frozen=True)
class Windows:
    """Time windows [s] of a fit, on the recording's clock: samples in (start, split] are fitted, samples in
    (split, end] are held out to judge over-fitting. ``dead_start``: the sensor's dead start the windows follow
    (None: not looked for)."""

    start: float
    split: float
    end: float
    dead_start: DeadStart | None = None

    @classmethod
    def of(cls, rec: Recording, fit_seconds: float | None, holdout_fraction: float) -> "Windows":
        """``fit_seconds`` [s] of the recording from the end of the sensor's dead start (``dead_start``; the first
        sample without one), all of it after that when None, clipped to the recording's end; the last
        ``holdout_fraction`` of it is held out."""
        if not 0.0 <= holdout_fraction < 1.0:
            raise ValueError(f"fit.holdout_fraction = {holdout_fraction}; expected a fraction in [0, 1)")
        if fit_seconds is not None and not fit_seconds > 0:
            raise ValueError(f"fit.window = {fit_seconds}; expected a positive duration in s (or null for all)")
        dead = dead_start(rec)
        start = dead.until
        end = float(rec.t[-1]) if fit_seconds is None else min(float(rec.t[-1]), start + float(fit_seconds))
        return cls(start=start, split=end - holdout_fraction * (end - start), end=end, dead_start=dead)


@runtime_checkable
class FitProblem(Protocol):
    """What ``fit_model``, ``Readings`` and the uncertainty read of a problem: measured readings on compared
    samples, the simulated readings for a material, and the simulation settings. ``StirProblem`` (one recording),
    ``behaviour.joint.JointProblem`` (windows of several recordings) and ``diagnosis.candidates.CachedReplay`` (a
    candidate's replay, cached by its θ) implement it.

    Attributes:
        config: the simulator's resolution and numerics.
        density: the fluid's density [kg/m³].
        recording: the (first) recording; its sensor's resolution [N] sets the robust loss's noise floor.
        times: each compared sample's time [s], (M,).
        measured: the measured readings [N], (M,).
        train: which samples are fitted, (M,) bool; the others are held out.
        weights: each sample's residual weight [1], (M,).
    """

    config: SimConfig
    density: float
    recording: Recording
    times: np.ndarray
    measured: np.ndarray
    train: np.ndarray
    weights: np.ndarray

    def loss(self, predicted: np.ndarray, train: bool = True) -> float | None:
        """The paper's loss, mean |measured − predicted| [N], over the fitted (or held-out) samples; None when
        there are none."""
        ...

    def simulate(self, material: nn.Module) -> Tensor:
        """Simulated readings [N] at the compared samples for ``material``, (M,)."""
        ...

    def frozen(self, material: nn.Module) -> Self:
        """This problem with the sound speed ``material`` gets (``SimConfig.compressibility``) held fixed; itself
        when its sound speed is fixed already."""
        ...


def rig_from_recording(rec: Recording) -> Rig:
    """The simulated rig of a recording's geometry (cylindrical rod, no-slip walls)."""
    fill = rec.cup.resolved_fill_height()
    return Rig(cup=Cup(radius=rec.cup.radius, fill_height=fill, height=fill + CUP_HEADROOM),
               rod=Rod(radius=rec.rod.radius, immersion_depth=rec.rod.immersion_depth))


def trajectory_from_recording(rec: Recording, end: float | None = None) -> Trajectory:
    """The rod's recorded path up to ``end`` [s] (one sample past it, so that interpolation covers it), replayed
    along the smooth curve through the samples (``trajectory.through_samples``), not along their chords."""
    last = rec.t.size if end is None else min(rec.t.size, int(np.searchsorted(rec.t, end, side="right")) + 1)
    z = 0.0 if rec.z is None else rec.z[:last]
    return through_samples(rec.t[:last], np.stack([rec.x[:last], rec.y[:last]], axis=-1), z, where=rec.source("csv"))


class StirProblem:
    """Simulated sensor readings of a recording for any fluid, and the measured readings they are compared with.

    Args:
        recording: the recording.
        config: the simulator's resolution and numerics.
        density: the fluid's density [kg/m³].
        windows: the fitted and held-out samples (default: the whole recording, nothing held out, whatever it
            reads: a blank recording replays its rod path).
        max_samples: at most this many measured samples are compared (evenly thinned; the force is resampled
            from the simulation, so thinning loses nothing the simulation resolves).
        corrected: a 2-D slice's force is F'_2D h C (False: F'_2D h, the paper's extruded slice).
    """

    def __init__(self, recording: Recording, config: SimConfig, density: float, windows: Windows | None = None,
                 *, max_samples: int = 2000, corrected: bool = True):
        self.recording = recording
        self.corrected = bool(corrected)
        self.config = config
        self.density = float(density)
        self.windows = windows or Windows(float(recording.t[0]), float(recording.t[-1]), float(recording.t[-1]))
        self.max_samples = max_samples
        self.rig = rig_from_recording(recording)
        self.trajectory = trajectory_from_recording(recording, self.windows.end)
        self.slice_length = self.rig.rod.immersion_depth if config.dim == 2 else 1.0  # m, or 1 in 3-D
        t = recording.t
        inside = np.flatnonzero((t > self.windows.start) & (t <= self.windows.end))
        if inside.size < 8:
            raise RecordingError(f"{recording.source('csv')}: only {inside.size} samples in the fit window "
                                 f"({self.windows.start:g}, {self.windows.end:g}] s; a fit needs at least 8")
        stride = max(1, int(np.ceil(inside.size / max_samples)))
        self.index = inside[::stride]
        self.times = t[self.index]
        self.measured = recording.force[self.index]
        self.velocity = recording.velocity()[self.index]  # m/s, (M, 2)
        self.train = self.times <= self.windows.split
        self.weights = np.ones(self.measured.shape[0])  # [1] per sample: every residual counts alike (``fit_model``)
        if self.train.sum() < 8:
            raise RecordingError(f"{recording.source('csv')}: only {int(self.train.sum())} samples before the "
                                 f"held-out split at {self.windows.split:g} s; shorten fit.holdout_fraction")
        self.stir_speed, self.orbit_radius = stir_scales(  # m/s, m
            np.stack([recording.x[self.index], recording.y[self.index]], axis=1)[self.train],
            self.velocity[self.train])
        try:  # a rig outside the correction's domain is refused here, before any simulation
            self.slice_correction()
        except ValueError as err:
            raise RecordingError(f"{recording.source('yaml')}: {err}") from None

    def slice_correction(self, material: nn.Module | None = None) -> SliceCorrection | None:
        """C = F_3D / (F'_2D h) of this recording's rig (``diffstir.slice_correction``) for the flow ``material``
        makes at the stir's shear rate U/a: its local flow index n = 1 + d ln η / d ln γ̇ and Reynolds number
        ρ U 2a / η there (``flow_state``); n = 1, Re = 0 without a material or for one that is not a rheology law.
        None in 3-D, where nothing is sliced, and for an uncorrected problem (``corrected``)."""
        if self.config.dim != 2 or not self.corrected:
            return None
        return stir_correction(self.rig, material, self.density, self.stir_speed, self.orbit_radius)

    def loss(self, predicted: np.ndarray, train: bool = True) -> float | None:
        """The paper's loss, mean |measured - predicted| [N], over the fitted (or the held-out) samples; None when
        there are no such samples. ``predicted`` [N] holds a reading for every compared sample."""
        mask = self.train if train else ~self.train
        return float(np.mean(np.abs(self.measured[mask] - predicted[mask]))) if mask.any() else None

    def mean_reading(self, readings: np.ndarray | None = None) -> float:
        """Mean |reading| [N] over the fitted samples of ``readings`` (one per compared sample; default: the
        measured ones): what the Newtonian ladder compares."""
        readings = self.measured if readings is None else readings
        return float(np.mean(np.abs(readings[self.train])))

    def with_config(self, config: SimConfig) -> "StirProblem":
        """The same recording, samples and density, simulated with ``config``."""
        return StirProblem(self.recording, config, self.density, self.windows, max_samples=self.max_samples,
                           corrected=self.corrected)

    def frozen(self, material: nn.Module) -> "StirProblem":
        """This problem with the sound speed that ``material`` gets (``SimConfig.compressibility``) held fixed: a
        fit's evaluations then simulate the same bulk modulus and, below the viscous limit, the same number of
        steps, so that its readings vary smoothly with the parameters (a sound speed that followed them changed the
        step count, and finite-difference Jacobians over 1e-3 in ln η read noise). The fluid still settles at the
        least sound speed, as it does unheld (``SimConfig.rollout_sound_speed``): ``material`` reads here what it
        reads in ``self``."""
        if self.config.fixed_sound_speed is not None:
            return self
        c = self.simulator(material).sound_speed(self.trajectory)
        return self.with_config(replace(self.config, rollout_sound_speed=c))

    def simulator(self, material: nn.Module) -> StirringSimulator:
        """The simulator of this recording's rig for a material (a rheology law or a material module)."""
        return StirringSimulator(material, self.rig, self.config, density=self.density)

    def simulate(self, material: nn.Module) -> Tensor:
        """Simulated readings [N] at ``self.times`` for ``material``; differentiable when grad is enabled.

        The simulated force is interpolated linearly to the recording's times (samples in the first half step,
        before the first mid-step force, take that first force) and read through the recording's sensor mode;
        when the sensor block states a ``time_constant``, the sensor's response acts on the simulated force at
        every simulation step, before the sampling (``recording.sensor.sensor_history_at``).
        """
        result = self.simulator(material)(self.trajectory)
        sim_times = result.times.detach().cpu().numpy()
        at = np.clip(self.times, sim_times[0], sim_times[-1])
        correction = self.slice_correction(material)
        scale = self.slice_length * (1.0 if correction is None else correction.factor)
        force, spec = result.force[:, :2] * scale, self.recording.sensor
        if spec.time_constant:  # the sensor responds to the force at every step, not only at its samples
            return sensor_history_at(self.recording, sim_times, force, at)
        force = resample_force(sim_times, force, at)
        velocity = torch.as_tensor(self.velocity, dtype=force.dtype, device=force.device)
        return sensor_reading(force, velocity, spec)
