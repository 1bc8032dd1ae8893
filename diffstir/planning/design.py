"""The stirring programme that tells a fluid's law best: a search over speed steps within the arm's limits.

A candidate programme stirs on one circle at S ascending speeds from a grid of levels, the time budget split evenly
between them, each segment long enough for its ramp, ``settle_time`` and a ``min_window`` steady window (the
behaviour experiment's shortest, ``behaviour.settings``). The arm's limits bound the levels: |U| ≤ ``max_speed``
and the centripetal acceleration U² / r ≤ ``max_acceleration``; the cosine ramp between two speeds, whose largest
acceleration is π ΔU / (2 t_ramp), lasts at least π ΔU_max / (2 ``max_acceleration``). Each candidate is scored by
the information gain per parameter (``planning.information``) plus the evidence it is expected to give between
the laws, both in nats and averaged over the prior's laws and draws (robust over the prior), and the best one is
the plan (``Planner.best``). The programme stirs up from rest in one direction: under the apparent-viscosity model
a window's information depends on its speed only, so reversals and pauses add none to a generalized-Newtonian law
(they do to thixotropy and elasticity, which no law here has).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import ConfigError, is_number, is_whole
from ..fitting import INERTIAL_FORCE_ERROR, MODEL_FORCE_ERROR, checked_model_error
from ..lab.programme import Segment
from ..rig import Rig
from .calibration import Calibration
from .information import (Window, WindowErrors, expected_delta_bic, fisher_information, information_gain,
                          predicted_intervals, window_points)
from .prior import Prior

#: ΔBIC [1] from which a rival law is ruled out very strongly (Kass and Raftery 1995): a pair counts in the
#: criterion up to it, so pairs every programme decides, or none can, do not tip the choice.
DECISIVE_DELTA_BIC = 10.0

#: Candidates, the best by information gain, whose expected evidence is computed (each costs 96 rival fits).
SHORTLIST = 8


@dataclass(frozen=True)
class ArmLimits:
    """What the arm may do: ``max_speed`` [m/s] and ``max_acceleration`` [m/s²] of the rod's axis, and the least
    ``clearance`` [m] between the rod and the cup's wall (conf/hardware/arm)."""

    max_speed: float = 0.25
    max_acceleration: float = 2.0
    clearance: float = 0.005

    def __post_init__(self) -> None:
        for name, unit in (("max_speed", "m/s"), ("max_acceleration", "m/s^2"), ("clearance", "m")):
            value = getattr(self, name)
            if not (is_number(value) and value > 0):
                raise ConfigError(f"plan.arm.{name} = {value!r}; expected a positive number in {unit}")

    def fastest(self, radius: float) -> float:
        """The fastest speed [m/s] on a circle of ``radius`` [m]: min(max_speed, √(max_acceleration · radius))."""
        return min(self.max_speed, math.sqrt(self.max_acceleration * radius))

    def ramp_time(self, step: float, least: float) -> float:
        """The cosine ramp [s] over a speed step ``step`` [m/s], at least ``least`` [s]."""
        return max(least, math.pi * abs(step) / (2.0 * self.max_acceleration))


@dataclass(frozen=True)
class PlanSettings:
    """How a plan is searched and what it assumes of the sensor and the simulator.

    Attributes:
        budget: the programme's length [s].
        speeds: candidate speed levels [m/s].
        radius: the circle of the rod's axis [m].
        max_segments: the most speed steps.
        min_ramp: the shortest ramp between speeds [s].
        settle_time: left out after each ramp before the window starts [s].
        min_window: the shortest steady window [s].
        baseline_speed: the single-speed stir the plan is compared with [m/s].
        noise, resolution: the sensor's 1-σ noise and resolution [N].
        sample_rate: the sensor's rate [Hz].
        model_error, inertial_error: σ_m and σ_i, as ``fit.model_error`` and ``fit.inertial_error``.
        density: the fluid's density [kg/m³] (its inertia).
    """

    budget: float = 8.0
    speeds: tuple[float, ...] = (0.01, 0.02, 0.04, 0.08, 0.16)
    radius: float = 0.015
    max_segments: int = 4
    min_ramp: float = 0.2
    settle_time: float = 0.2
    min_window: float = 0.3
    baseline_speed: float = 0.05
    noise: float = 0.003
    resolution: float = 0.005
    sample_rate: float = 100.0
    model_error: float = MODEL_FORCE_ERROR
    inertial_error: float = INERTIAL_FORCE_ERROR
    density: float = 1000.0
    arm: ArmLimits = field(default_factory=ArmLimits)

    def __post_init__(self) -> None:
        object.__setattr__(self, "speeds", tuple(sorted(float(u) for u in self.speeds)))
        for name, unit in (("budget", "s"), ("radius", "m"), ("min_ramp", "s"), ("settle_time", "s"),
                           ("min_window", "s"), ("baseline_speed", "m/s"), ("sample_rate", "Hz"),
                           ("density", "kg/m^3")):
            value = getattr(self, name)
            if not (is_number(value) and value > 0):
                raise ConfigError(f"plan.{name} = {value!r}; expected a positive number in {unit}")
        for name in ("noise", "resolution"):
            value = getattr(self, name)
            if not (is_number(value) and value >= 0):
                raise ConfigError(f"plan.{name} = {value!r}; expected a non-negative force in N")
        if not (self.speeds and all(is_number(u) and u > 0 for u in self.speeds)):
            raise ConfigError(f"plan.speeds = {list(self.speeds)!r}; expected positive speeds in m/s")
        if not is_whole(self.max_segments, 1):
            raise ConfigError(f"plan.max_segments = {self.max_segments!r}; expected a whole number of at least 1")
        checked_model_error(self.model_error, "plan.model_error")
        checked_model_error(self.inertial_error, "plan.inertial_error")

    @property
    def errors(self) -> WindowErrors:
        return WindowErrors(self.noise, self.resolution, self.model_error, self.inertial_error)

    def check_rig(self, rig: Rig) -> None:
        """A ConfigError unless the circle keeps the rod ``arm.clearance`` from the wall, a speed is allowed and
        the budget holds a segment: checked before the rig's calibration simulates anything."""
        widest = rig.cup.radius - rig.rod.radius - self.arm.clearance
        if not self.radius <= widest:
            raise ConfigError(f"plan.radius = {self.radius} m; the rod stays {self.arm.clearance} m clear of the "
                              f"wall only on circles up to {widest:.4g} m in this cup")
        if not self.levels():
            raise ConfigError(f"plan.speeds = {list(self.speeds)} m/s; none is within the arm's limit "
                              f"{self.arm.fastest(self.radius):.3g} m/s on a {self.radius} m circle")
        if not candidates(self):
            raise ConfigError(f"plan.budget = {self.budget} s leaves no segment room for its ramp, "
                              f"{self.settle_time} s of settling and a {self.min_window} s window")

    def levels(self) -> tuple[float, ...]:
        """The candidate speeds [m/s] the arm allows on the circle."""
        return tuple(u for u in self.speeds if u <= self.arm.fastest(self.radius) * (1 + 1e-9))


@dataclass(frozen=True)
class Programme:
    """Speeds [m/s] held in turn for ``duration`` [s] each on a circle of ``radius`` [m], with ``ramp_time`` [s]."""

    speeds: tuple[float, ...]
    duration: float
    radius: float
    ramp_time: float

    @classmethod
    def through(cls, speeds: tuple[float, ...], settings: PlanSettings) -> "Programme":
        """``speeds`` [m/s] in turn from rest on ``settings``' circle, its budget split evenly, with the ramp the
        largest step needs within the arm's acceleration."""
        steps = np.diff(np.concatenate([[0.0], speeds]))
        ramp = settings.arm.ramp_time(float(np.max(np.abs(steps))), settings.min_ramp)
        return cls(tuple(speeds), settings.budget / len(speeds), settings.radius, ramp)

    def fits(self, settings: PlanSettings) -> bool:
        """Whether each segment holds its ramp, ``settle_time`` and a ``min_window`` window."""
        return self.duration >= self.ramp_time + settings.settle_time + settings.min_window

    def segments(self) -> list[Segment]:
        return [Segment(speed=u, duration=self.duration) for u in self.speeds]

    def windows(self, settings: PlanSettings) -> list[Window]:
        steady = self.duration - self.ramp_time - settings.settle_time
        return [Window(u, int(steady * settings.sample_rate)) for u in self.speeds]

    def to_dict(self) -> dict:
        """The programme as ``conf/lab/programme`` writes it (``diffstir-synth lab/programme=...``)."""
        return {"radius": self.radius, "ramp_time": self.ramp_time, "start_angle": 0.0,
                "segments": [{"speed": u, "duration": self.duration} for u in self.speeds]}


def candidates(settings: PlanSettings) -> list[Programme]:
    """Every ascending choice of 1 to ``max_segments`` levels whose segments fit ramp, settling and window."""
    levels = settings.levels()
    counts = range(1, min(settings.max_segments, len(levels)) + 1)
    programmes = [Programme.through(speeds, settings) for count in counts
                  for speeds in itertools.combinations(levels, count)]
    return [p for p in programmes if p.fits(settings)]


@dataclass(frozen=True)
class Assessment:
    """What a programme is expected to tell: the mean information gain per parameter over the prior (``gain``,
    nats), the expected evidence per pair of laws (``discrimination``, nats, ``Planner.discrimination``), each law's
    mean gain (``law_gains``), each law's predicted 95 % intervals and identifiability at the prior's central fluid
    (``intervals``: law, parameter, ``ci95`` in SI units and ``identifiable``), its windows' shear rates [1/s]
    (``shear_rates``), and the mean expected ΔBIC of each rival law against each true one over the true law's draws
    (``evidence[true][rival]``)."""

    programme: Programme
    gain: float
    discrimination: float
    law_gains: dict[str, float]
    intervals: dict[str, dict[str, dict]]
    shear_rates: list[float]
    evidence: dict[str, dict[str, float]]

    @property
    def score(self) -> float:
        """The criterion [nats]: ``gain`` + ``discrimination``."""
        return self.gain + self.discrimination

    def open_pairs(self) -> list[tuple[str, str]]:
        """(true, rival) pairs whose expected ΔBIC is below ``DECISIVE_DELTA_BIC``: the rival is not ruled out
        very strongly."""
        return [(a, b) for a, row in self.evidence.items() for b, d in row.items() if d < DECISIVE_DELTA_BIC]

    def to_dict(self) -> dict:
        return {"programme": self.programme.to_dict(), "score": self.score, "gain_per_parameter": self.gain,
                "discrimination_per_pair": self.discrimination, "law_gains": self.law_gains,
                "predicted_ci95": self.intervals, "shear_rates": self.shear_rates,
                "expected_delta_bic": self.evidence, "open_pairs": [list(p) for p in self.open_pairs()],
                "units": {"score": "nats", "gain_per_parameter": "nats", "discrimination_per_pair": "nats",
                          "shear_rates": "1/s", "radius": "m", "ramp_time": "s", "speed": "m/s", "duration": "s"}}


class Planner:
    """Scores programmes for a calibrated rig (``planning.calibration``) against a prior."""

    def __init__(self, calibration: Calibration, prior: Prior, settings: PlanSettings):
        self.calibration, self.prior, self.settings = calibration, prior, settings
        self.reference_rate = calibration.shear_rate(math.sqrt(settings.levels()[0] * settings.levels()[-1]))
        self.draws = {name: prior.draw(name, self.reference_rate) for name in prior.laws}
        self.precision = {name: prior.precision(name, self.reference_rate) for name in prior.laws}
        self._evidence: dict[Programme, dict[str, dict[str, np.ndarray]]] = {}

    def gain(self, programme: Programme) -> tuple[float, dict[str, float]]:
        """The mean information gain per parameter over the laws, and each law's mean over its draws."""
        windows = programme.windows(self.settings)
        law_gains = {}
        for name, draws in self.draws.items():
            gains = [information_gain(fisher_information(window_points(windows, m, self.calibration,
                                                                       self.settings.errors)), self.precision[name])
                     for m in draws]
            law_gains[name] = float(np.mean(gains))
        return float(np.mean(list(law_gains.values()))), law_gains

    def evidence(self, programme: Programme) -> dict[str, dict[str, np.ndarray]]:
        """The expected ΔBIC [1] of each rival law against each true one, one per draw of the true law
        (``information.expected_delta_bic``): ``[true][rival]``, computed once per programme."""
        if programme not in self._evidence:
            windows, errors = programme.windows(self.settings), self.settings.errors
            self._evidence[programme] = {
                a: {b: np.array([expected_delta_bic(truth, self.draws[b][0].copy(), self.draws[b], windows,
                                                    self.calibration, errors) for truth in self.draws[a]])
                    for b in self.prior.laws if b != a} for a in self.prior.laws}
        return self._evidence[programme]

    def discrimination(self, programme: Programme) -> float:
        """The expected evidence between the laws [nats]: the mean over (true, rival) pairs and the true law's
        draws of min(ΔBIC, ``DECISIVE_DELTA_BIC``) / 2, ΔBIC / 2 being the log Bayes factor (Schwarz); 0 with a
        single law."""
        values = [np.minimum(d, DECISIVE_DELTA_BIC) / 2.0 for row in self.evidence(programme).values()
                  for d in row.values()]
        return float(np.mean(values)) if values else 0.0

    def assess(self, programme: Programme) -> Assessment:
        """The programme's gain, discrimination, predicted intervals, shear rates and expected evidence
        (``Assessment``)."""
        windows = programme.windows(self.settings)
        gain, law_gains = self.gain(programme)
        errors = self.settings.errors
        intervals = {}
        for name in self.prior.laws:
            central = self.prior.central(name, self.reference_rate)
            intervals[name] = predicted_intervals(
                central, fisher_information(window_points(windows, central, self.calibration, errors)))
        evidence = {a: {b: float(np.mean(d)) for b, d in row.items()} for a, row in self.evidence(programme).items()}
        rates = [self.calibration.shear_rate(u) for u in programme.speeds]
        return Assessment(programme, gain, self.discrimination(programme), law_gains, intervals, rates, evidence)

    def best(self) -> Programme:
        """Of the ``SHORTLIST`` candidates of the highest gain, the one of the highest gain + discrimination (the
        fewest segments among equals)."""
        gains = {p: self.gain(p)[0] for p in candidates(self.settings)}
        ranked = sorted(gains, key=lambda p: (gains[p], -len(p.speeds)), reverse=True)
        return max(ranked[:SHORTLIST], key=lambda p: (gains[p] + self.discrimination(p), -len(p.speeds)))
