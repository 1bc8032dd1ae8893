"""The Newtonian viscosity whose simulated reading has the recording's size: one statistic fitted, not the
waveform, for fluids whose drag is mostly inertial.

The paper's loss compares readings sample by sample. Where the drag is mostly inertia (thin fluids: Re = ρ U 2a / η
≳ 20 at the default stir) the reading's waveform is set by added mass and the wake, which the fitting grid draws
differently from a finer grid or a real cup, by more than the viscous part of the force moves it: on the lab's
0.05 Pa·s fluid the loss's minimum lies 30 % low, while the fitting grid's mean |reading| is within 1.4 % of the
truth's (docs/accuracy.md). So the estimate matches the size alone:

    M(η) = mean_train E|p_i(η) + ε_i| = mean_train |m_i|,   ε_i ~ N(0, σ²),
    E|p + ε| = p erf(p / (σ √2)) + σ √(2/π) exp(−p² / (2σ²))      (mean of a folded normal),

with m the measured and p the simulated readings [N] on the fitted samples and σ the sensor's noise
(``optimise.noise_scale``): the noise's own share of mean |m| (σ √(2/π) where the reading crosses zero) is added to
the simulated side instead of being read as viscosity. The root is found by secant steps in ln η on ln M.

Its 95 % interval is the set of viscosities whose simulated statistic lies within 1.96 σ of the measured one in
ln M, found by the same secant steps on each side (two to four more simulations),

    σ² = var(mean |m|) / M² + σ_m² + (σ_i (1 − s))²,   var(mean |m|) = mean_i Var|p_i + ε_i| / N,
    Var|p + ε| = p² + σ² − (E|p + ε|)²,

the sensor's white noise averaged over the N fitted samples, σ_m the simulator's relative force error, and σ_i the
relative error of the reading's inertial part, which is the share 1 − s of M with s = d ln M / d ln η at η̂ (for
M = M_i + M_v with M_v ∝ η, s = M_v / M), as in the waveform fit's intervals (``uncertainty.laplace``). Where
the reading stops growing with η (the inertial floor of thin fluids) an end is not found and the interval is open
there; where the slope at η̂ puts an end beyond a factor e^``MAX_STEP`` it is left open without a search. The
estimate **resolves** the viscosity when both ends are found within a factor ``RESOLVED_FACTOR`` of η̂:
at the default stir the fitting grid's d ln M / d ln η is about 0.2 from 0.035 to 0.07 Pa·s and 0.06 from 0.0125 to
0.025 Pa·s (``scripts/loss_scan.py``, docs/accuracy.md), so σ_m = 3 % alone spans ±0.3 in ln η at 0.05 Pa·s and
resolves nothing much below it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import special

from ..report_files import finite_or_none
from .models import FitModel
from .optimise import Readings, noise_scale
from .problem import StirProblem
from .uncertainty import Z95

#: The 95 % interval of a resolved estimate lies within this factor of it, each way.
RESOLVED_FACTOR = 2.0
#: The secant stops when ln M is this close to the measured ln M [1]: a tenth of the 3 % force error.
TOLERANCE = 3e-3
#: Most simulations the secant spends after the first.
MAGNITUDE_STEPS = 5
#: The first step in ln η when no slope is known [1], and the largest step the secant takes.
FIRST_STEP, MAX_STEP = 0.5, 1.5
#: The slope at the root is a secant over at least this step in ln η [1]: shorter ones are inside the float32
#: simulation's noise (docs/accuracy.md, ``scripts/secant_noise.py``).
MIN_SECANT = 0.05


def expected_magnitude(readings: np.ndarray, noise: float) -> np.ndarray:
    """E|p + ε| [N] per sample for simulated readings p [N] under Gaussian noise of std ``noise`` [N]."""
    p = np.abs(np.asarray(readings, dtype=np.float64))
    return p * special.erf(p / (noise * math.sqrt(2.0))) + noise * math.sqrt(2.0 / math.pi) * np.exp(
        -0.5 * (p / noise) ** 2)


def magnitude_variance(readings: np.ndarray, noise: float) -> float:
    """var(mean |p + ε|) [N²] over the samples of ``readings`` p [N] under Gaussian noise of std ``noise`` [N]:
    mean_i (p_i² + σ² − (E|p_i + ε|)²) / N."""
    p = np.asarray(readings, dtype=np.float64)
    return float(np.mean(p**2 + noise**2 - expected_magnitude(p, noise) ** 2)) / p.size


@dataclass(frozen=True)
class MagnitudeEstimate:
    """η̂ [Pa·s] with its 95 % interval (an end is 0 or inf where it was not found), d ln M / d ln η [1] at η̂, the
    measured statistic M [N], its relative standard error σ [1] (noise, σ_m and σ_i), whether the estimate resolves
    the viscosity, and the simulations spent."""

    viscosity: float
    ci95: tuple[float, float]
    slope: float
    measured: float
    relative_error: float
    resolved: bool
    simulations: int

    def summary(self) -> dict:
        return {"viscosity": self.viscosity, "ci95": [finite_or_none(v) for v in self.ci95], "resolved": self.resolved,
                "log_slope": finite_or_none(self.slope), "mean_abs_reading": self.measured,
                "relative_error": self.relative_error, "simulations": self.simulations,
                "units": {"viscosity": "Pa s", "mean_abs_reading": "N"},
                "method": "Newtonian viscosity whose simulated mean |reading| (sensor noise folded in) matches the "
                          "recording's; 95 % interval by simulation"}


def magnitude_estimate(problem: StirProblem, start: float, model_error: float, *, inertial_error: float = 0.0,
                       on_evaluation=None) -> MagnitudeEstimate:
    """The Newtonian viscosity [Pa·s] whose simulated mean |reading| matches ``problem``'s, from ``start``
    [Pa·s], with the simulator's relative force error ``model_error`` σ_m and the relative error ``inertial_error``
    σ_i of the reading's inertial part in its interval (module docstring)."""
    train = problem.train
    measured = problem.measured[train]
    noise = noise_scale(problem.measured, problem.recording.sensor.resolution)
    size = float(np.mean(np.abs(measured)))
    if not size > 0:
        source = problem.recording.path or problem.recording.name
        raise ValueError(f"{source}: the force column's fitted samples have a mean |reading| of {size} N; a stir's "
                         "reading must move for its size to give a viscosity")
    target = math.log(size)
    model = FitModel.named("newtonian", eta=start)
    readings = Readings(problem, model, on_evaluation)
    bounds = (float(model.lower[0]), float(model.upper[0]))
    points: dict[float, float] = {}

    def log_m(x: float) -> float:
        if x not in points:
            simulated = float(np.mean(expected_magnitude(readings(np.array([x]))[train], noise)))
            points[x] = math.log(simulated) if simulated > 0 else math.nan  # NaN: the simulation diverged
        return points[x]

    x_hat, found = _solve(log_m, target, math.log(start), FIRST_STEP, bounds, points)
    if len(points) == 1:  # the start was the root: one more simulation for the slope there
        log_m(float(np.clip(x_hat + 2 * MIN_SECANT, *bounds)))
    slope = _slope_at(points, x_hat)
    p = readings(np.array([x_hat]))[train]
    mean_variance = magnitude_variance(p, noise)
    inertial_share = 1.0 - min(max(slope, 0.0), 1.0)
    sigma = math.sqrt(mean_variance / math.exp(2.0 * target) + model_error**2 + (inertial_error * inertial_share) ** 2)
    first = Z95 * sigma / slope if slope > 0 else math.inf
    ends = [0.0, math.inf]
    if found and first <= MAX_STEP:  # else the ends lie beyond a factor e^MAX_STEP: open, not searched
        for k, side in enumerate((-1.0, 1.0)):
            x, ok = _solve(log_m, target + side * Z95 * sigma, x_hat + side * first, side * first, bounds, points)
            ends[k] = math.exp(x) if ok else ends[k]
    eta = math.exp(x_hat)
    resolved = found and eta / RESOLVED_FACTOR <= ends[0] and ends[1] <= eta * RESOLVED_FACTOR
    return MagnitudeEstimate(viscosity=eta, ci95=(ends[0], ends[1]), slope=slope, measured=math.exp(target),
                             relative_error=sigma, resolved=bool(resolved), simulations=readings.evaluations)


def _solve(log_m, target: float, x0: float, step: float, bounds: tuple[float, float], points: dict
           ) -> tuple[float, bool]:
    """ln η where ``log_m`` (ln M of ln η, caching into ``points``) reaches ``target``, by secant steps from ``x0``
    (the first over the nearest simulated point, or of size ``step`` without one); (x, whether it was reached
    within ``TOLERANCE``)."""
    x, tried = float(np.clip(x0, *bounds)), []
    for _ in range(MAGNITUDE_STEPS + 1):
        y = log_m(x)
        if not math.isfinite(y):
            break  # the simulation diverged (``optimise.Readings``): no further that way
        if abs(y - target) < TOLERANCE:
            return x, True
        tried.append(x)
        slope = (y - points[tried[-2]]) / (x - tried[-2]) if len(tried) > 1 else _slope_at(points, x)
        move = (target - y) / slope if slope > 0 else math.copysign(abs(step), target - y)
        x_new = float(np.clip(x + np.clip(move, -MAX_STEP, MAX_STEP), *bounds))
        if x_new == x:
            break  # at a bound of the Newtonian law
        x = x_new
    finite = [p for p in points if math.isfinite(points[p])]
    if not finite:
        return x0, False
    closest = min(finite, key=lambda p: abs(points[p] - target))
    return closest, abs(points[closest] - target) < TOLERANCE


def _slope_at(points: dict[float, float], x: float) -> float:
    """d ln M / d ln η at ``x`` from the simulated ``points`` (ln η → ln M): the secant from the nearest to the
    nearest of those at least ``MIN_SECANT`` from it (NaN without one); simulations that diverged are left out."""
    ordered = sorted((p for p in points if math.isfinite(points[p])), key=lambda p: abs(p - x))
    apart = [p for p in ordered[1:] if abs(p - ordered[0]) >= MIN_SECANT] if ordered else []
    return (points[apart[0]] - points[ordered[0]]) / (apart[0] - ordered[0]) if apart else math.nan
