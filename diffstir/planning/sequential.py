"""The next segment of a stir, chosen from what the stir so far has told (the sequential mode, docs/planning.md).

The stir so far is its window points (γ̇_k [1/s], η_k [Pa·s], σ_k of ln η_k), as the flow-curve analysis reads
them (``diffstir-fit experiment=flow_curve``, report.json's ``points``). Each law the analysis fitted to them
(``behaviour.joint_models``; the prior's laws where it fitted none) is fitted again (``fitting.fit_points``), so
the stir's family and confidence are the report's, and weighted by its Schwarz weight
w_a = exp(−BIC_a / 2) / Σ_l exp(−BIC_l / 2). A next segment at speed U adds one steady window, whose point the
window model predicts for each law at its fit (``information.window_points``, at the stir's own k_s). The segment
is scored as the plan scores a programme, in nats, each term averaged over the laws by w_a:

- the information gain about law a's parameters, ½ log det(𝟙 + Λ_a^(−½) I_U Λ_a^(−½)) / k_a, with Λ_a = P_a +
  Jᵀ W J the precision after the stir so far (the prior's box P_a and the points' information at the fit) and I_U
  the new window's;
- the evidence: every law refitted to the points with law a's predicted point added, each rival's ΔBIC against
  a counted up to ``design.DECISIVE_DELTA_BIC``, / 2, averaged over the rivals.

The stir is decided when the family of the best law (``fitting.law_family`` over the points' shear rates) holds a
Schwarz weight of at least ``DECIDED``, as the flow-curve analysis states its confidence
(``Classification.with_law_families``); otherwise its next segment is the speed of the highest score per second of
stirring among those whose segment still fits the budget: a slow speed's stir lasts longer (below), and the time it
takes is the budget's, which another stir could have spent (information per unit cost, as cost-aware sequential
designs weigh it). The segment is a stir of its own from rest: the analysis that plans it takes minutes, in which the
rod rests and the fluid stops, so each step is a recording, and the analysis reads all of them together. From rest
is also how the plan's window model is calibrated. A recording must span one stirring period (``recording
.validate``), about a turn of the circle, so a slow speed's stir lasts longer than the plan's segment
(``shortest_stir``) and costs the budget that much more.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..fitting import Z95, PointsFit, fit_points, law_family, schwarz_weights
from ..lab.programme import stirring_programme
from ..recording import stirring_frequency
from ..recording.validate import MIN_DURATION
from .calibration import Calibration
from .design import DECISIVE_DELTA_BIC, PlanSettings
from .information import Window, window_points
from .prior import Prior

#: Schwarz weight [1] of the leading family at which the stir is decided: a rival family ~10 behind in BIC.
DECIDED = 0.99

#: The first stir's speeds [m/s]: a factor 4 apart, so that the flow-curve analysis has two resolved speeds.
FIRST_SPEEDS = (0.02, 0.08)


def first_stir(settings: PlanSettings, speeds: tuple[float, ...] = FIRST_SPEEDS) -> dict:
    """The sequential mode's first stir as a ``conf/lab/programme`` mapping: ``speeds`` [m/s] from rest, each for
    an equal share of one plan segment (``budget`` / ``max_segments``) on ``settings``' circle, ramped as the
    arm allows for the fastest."""
    segment = settings.budget / settings.max_segments
    return {"radius": settings.radius, "ramp_time": settings.arm.ramp_time(max(speeds), settings.min_ramp),
            "start_angle": 0.0, "segments": [{"speed": u, "duration": segment / len(speeds)} for u in speeds]}


@dataclass(frozen=True)
class StirSoFar:
    """A stir's window points: ``speeds`` [m/s], ``shear_rates`` [1/s], ``viscosity`` [Pa·s] and ``log_std``, the
    standard error of each ln η [1]; ``elapsed`` [s], the length of its recordings together; ``laws``, the laws
    the flow-curve analysis fitted to the points (None: the prior's)."""

    speeds: tuple[float, ...]
    shear_rates: tuple[float, ...]
    viscosity: tuple[float, ...]
    log_std: tuple[float, ...]
    elapsed: float
    laws: tuple[str, ...] | None = None

    @classmethod
    def from_report(cls, summary: dict) -> "StirSoFar":
        """The points a flow-curve report classified (``Behaviour.summary()``, report.json), the standard error of
        ln η from each 95 % interval, ln(hi / lo) / (2 Z95), and the laws its joint fit holds; the stir's length,
        the sum over its recordings of the last window's end (a window is labelled ``<recording>@<start>-<end>s``).
        """
        ends: dict[str, float] = {}
        for p in summary["points"]:
            recording = p["window"].rsplit("@", 1)[0]
            ends[recording] = max(ends.get(recording, 0.0), float(p["end"]))
        points = [p for p in summary["points"] if p["classified"]]
        laws = tuple((summary.get("joint_fit") or {}).get("laws", {})) or None
        return cls(tuple(p["speed"] for p in points), tuple(p["shear_rate"] for p in points),
                   tuple(p["viscosity"] for p in points),
                   tuple(math.log(p["viscosity_ci95"][1] / p["viscosity_ci95"][0]) / (2 * Z95) for p in points),
                   sum(ends.values()), laws)

    @property
    def rate_per_speed(self) -> float:
        """γ̇_k / U_k [1/m] of the stir's points, k_s / a: the same for every point (one k_s, a rod of radius a)."""
        return float(np.mean(np.array(self.shear_rates) / np.array(self.speeds)))

    def fits(self, laws: tuple[str, ...], extra: tuple[float, float, float] | None = None) -> dict[str, PointsFit]:
        """Each law fitted to the points, with ``extra`` (γ̇ [1/s], η [Pa·s], σ of ln η [1]) added."""
        rates, eta, sigma = (list(v) for v in (self.shear_rates, self.viscosity, self.log_std))
        if extra is not None:
            rates, eta, sigma = rates + [extra[0]], eta + [extra[1]], sigma + [extra[2]]
        return {name: fit_points(name, rates, eta, sigma) for name in laws}


@dataclass(frozen=True)
class NextSegment:
    """What the stir so far calls for: whether its family is ``decided`` (``family`` at Schwarz weight
    ``confidence``; None and 0 before its points span two shear rates), and otherwise the next stir (``speed``
    [m/s] for ``duration`` [s], its ramp ``ramp_time`` [s] from rest included; None when the budget left holds
    none) with its ``score`` [nats], and every candidate speed's score [nats] and stir's length [s] (``scores``,
    ``durations``)."""

    decided: bool
    family: str | None
    confidence: float
    speed: float | None
    duration: float
    ramp_time: float
    score: float | None
    scores: dict[float, float]
    durations: dict[float, float]

    @property
    def rates(self) -> dict[float, float]:
        """Each candidate's score per second of its stir [nats/s], by which the next stir is chosen."""
        return {u: score / self.durations[u] for u, score in self.scores.items()}

    def programme(self, radius: float) -> dict:
        """The next stir as a ``conf/lab/programme`` mapping on a circle of ``radius`` [m]."""
        return {"radius": radius, "ramp_time": self.ramp_time, "start_angle": 0.0,
                "segments": [{"speed": self.speed, "duration": self.duration}]}

    def to_dict(self) -> dict:
        return {"decided": self.decided, "family": self.family, "confidence": self.confidence,
                "next": None if self.speed is None else {"speed": self.speed, "duration": self.duration,
                                                         "ramp_time": self.ramp_time, "score": self.score,
                                                         "rate": self.rates[self.speed]},
                "candidates": {f"{u:g}": {"score": s, "duration": self.durations[u], "rate": self.rates[u]}
                               for u, s in self.scores.items()},
                "units": {"speed": "m/s", "duration": "s", "ramp_time": "s", "score": "nats", "rate": "nats/s"}}


def family_weights(so_far: StirSoFar, fits: dict[str, PointsFit], weights: dict[str, float]
                   ) -> tuple[str | None, dict[str, float]]:
    """The family of the best law over the points' shear rates and each family's share of the laws' Schwarz
    ``weights``; no family, and no shares, before the points span two shear rates (one point: every law passes
    through it)."""
    rates = np.array(so_far.shear_rates)
    band = (float(rates.min()), float(rates.max()))
    if not band[1] > band[0]:
        return None, {}
    middle = float(np.exp(np.mean(np.log(rates))))
    families = {name: law_family(fit.model, fit.theta, fit.uncertainty, band, middle)["class"]
                for name, fit in fits.items()}
    shares: dict[str, float] = {}
    for name, w in weights.items():
        shares[families[name]] = shares.get(families[name], 0.0) + w
    return families[max(weights, key=weights.get)], shares


def next_segment(so_far: StirSoFar, calibration: Calibration, prior: Prior | None = None,
                 settings: PlanSettings | None = None) -> NextSegment:
    """Whether ``so_far`` is decided and, if not, its best next stir (module docstring): a speed of ``settings``'
    levels from rest for the plan's segment length (``budget`` / ``max_segments``) or, where a recording needs
    longer, its ``shortest_stir``, within the budget left, on ``calibration``'s rig; the stir's laws (``prior``'s
    where it names none) scored against ``prior``'s box."""
    prior, settings = prior or Prior(), settings or PlanSettings()
    fits = so_far.fits(so_far.laws or prior.laws)
    weights = schwarz_weights({name: fit.bic for name, fit in fits.items()})
    family, shares = family_weights(so_far, fits, weights)
    confidence = shares.get(family, 0.0)
    segment = settings.budget / settings.max_segments
    left = settings.budget - so_far.elapsed
    if confidence >= DECIDED:
        return NextSegment(True, family, confidence, None, segment, 0.0, None, {}, {})
    own = dataclasses.replace(calibration, shear_rate_factor=so_far.rate_per_speed * calibration.rod_radius)
    reference_rate = float(np.exp(np.mean(np.log(so_far.shear_rates))))
    sigma = np.array(so_far.log_std)
    precisions = {}  # Λ_a: the prior's box precision plus the points' information at law a's fit
    for name, fit in fits.items():
        jacobian = fit.model.viscosity(np.array(so_far.shear_rates), fit.theta)[1] / sigma[:, None]
        precisions[name] = np.diag(prior.precision(name, reference_rate)) + jacobian.T @ jacobian
    scores, durations = {}, {}
    for speed in settings.levels():
        ramp = settings.arm.ramp_time(speed, settings.min_ramp)
        duration = shortest_stir(speed, segment, ramp, settings)
        if not duration <= left * (1 + 1e-9):
            continue
        samples = int((duration - ramp - settings.settle_time) * settings.sample_rate)
        if samples >= settings.min_window * settings.sample_rate:
            durations[speed] = duration
            scores[speed] = _score(so_far, fits, weights, precisions, Window(speed, samples), own, settings)
    if not scores:  # the budget left holds no valid stir with its ramp, settling and a window
        return NextSegment(False, family, confidence, None, segment, 0.0, None, {}, {})
    speed = max(scores, key=lambda u: scores[u] / durations[u])
    ramp = settings.arm.ramp_time(speed, settings.min_ramp)
    return NextSegment(False, family, confidence, speed, durations[speed], ramp, scores[speed], scores, durations)


def shortest_stir(speed: float, least: float, ramp_time: float, settings: PlanSettings) -> float:
    """The shortest stir [s] from rest at ``speed`` [m/s] on ``settings``' circle, of at least ``least`` [s] and in
    steps of 0.1 s, whose recording spans one stirring period as a recording must (``recording.validate``: at least
    ``MIN_DURATION`` and 1 / f, f the frequency ``stirring_frequency`` estimates from the path); inf where no stir
    within ``settings.budget`` does."""
    for tenths in range(math.ceil(least * 10 - 1e-9), math.floor(settings.budget * 10 + 1e-9) + 1):
        duration = tenths / 10
        path = stirring_programme([{"speed": speed, "duration": duration}], radius=settings.radius,
                                  ramp_time=min(ramp_time, duration), sample_rate=settings.sample_rate)
        frequency = stirring_frequency(path.t, path.xy[:, 0], path.xy[:, 1])
        if frequency > 0 and duration >= max(MIN_DURATION, 1.0 / frequency):
            return duration
    return math.inf


def _score(so_far: StirSoFar, fits: dict[str, PointsFit], weights: dict[str, float],
           precisions: dict[str, np.ndarray], window: Window, calibration: Calibration, settings: PlanSettings
           ) -> float:
    """The window's expected information gain plus evidence [nats], averaged over the laws by their ``weights``,
    each law's gain against its precision after the points (``precisions``); a law under which the window reads no
    viscosity (its drag at the noise or inertial floor) gains nothing from it and keeps the evidence of the points
    so far."""
    score = 0.0
    for name, fit in fits.items():
        (point,) = window_points([window], fit.model, calibration, settings.errors, fit.theta)
        gain, refits = 0.0, fits
        if math.isfinite(point.viscosity_error):
            new = np.outer(point.gradient, point.gradient) / point.log_error**2
            precision = precisions[name]
            gain = 0.5 * (np.linalg.slogdet(precision + new)[1] - np.linalg.slogdet(precision)[1]) / fit.model.size
            refits = so_far.fits(tuple(fits), (point.shear_rate, point.viscosity, point.viscosity_error))
        rivals = [min(refits[b].bic - refits[name].bic, DECISIVE_DELTA_BIC) / 2.0 for b in refits if b != name]
        score += weights[name] * (gain + (float(np.mean(rivals)) if rivals else 0.0))
    return float(score)
