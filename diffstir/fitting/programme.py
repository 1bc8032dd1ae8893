"""The apparent viscosity of every speed window of one programme, from Newtonian simulations of the whole programme.

A programme holds speeds U_k in windows k = 1..K (``speed_windows``), each read at Metzner and Otto's effective shear
rate γ̇_k = k_s U_k / a (a: the rod's radius; k_s measured once, ``effective_shear_rate``, on the first window whose
drag is viscous, ``VISCOUS_SLOPE``). Window k's apparent viscosity η_k is the Newtonian-equivalent viscosity the
behaviour experiment's window fits read (``apparent``): the Newtonian fluid whose simulation of the whole recording,
each window after the stretches before it at the arm's speeds and phases, reads the window's samples. One simulation
of a Newtonian fluid (a rung) reads every window at once, so the rungs form a ladder per window.

1. **Bracket.** Each window's size M̂_k = mean |m_i| is read off its ladder, ln M_k linear in ln η between the two
   rungs that bracket it (extrapolated from the nearest two, at most ``MAX_STEP`` in ln η beyond), with the
   sensor's noise share of |m| added to the simulated side (``magnitude.expected_magnitude``). The rungs start at
   ``START_VISCOSITIES``; while a window's bracket is wider than a factor ``BRACKET``, the windows with the widest
   get a rung at their estimate (a factor √``BRACKET`` beyond a rung already there, towards the wider side),
   ``RUNGS_PER_ROUND`` at a time, up to ``MAX_RUNGS``. The rounds do not depend on how many processes run them, so
   neither do the rungs nor the points.
2. **Fit.** The window's readings are fitted by p(η) + b, the rungs' readings linear in η between the two that
   bracket the estimate and a baseline b [N] with the prior N(0, q²), q the sensor's resolution
   (``apparent.with_baseline``, the window fits' last step, with their errors: the noise's from the residuals and
   N_eff, the simulator's σ_m on p and σ_i on its inertial part p − J, J = d p / d ln η). The size alone takes the
   sensor's offset and drift for drag: at the slowest planned speed a window covers a fifth of a turn, the component
   reading keeps its sign, and the paper sensor's 2 mN offset and 0.5 mN/s drift are 20 % or more of a 0.65 Pa·s
   fluid's 10 mN drag there. The drag is a Stokes part ∝ η on an inertial part that barely changes with η, so it is
   linear in η: its chord in ln η would read J 18 % low to 23 % high within a factor 1.5, and σ_i would take the
   difference for inertia.

Rungs up to the simulator's ``viscosity_cap`` are simulated as configured; thicker ones, up to ``thickest_rung``,
with the implicit shear stress (``SimConfig.viscous_solver``) and the cap raised to ``thickest_rung``: the explicit
step shortens in proportion to the viscosity (1 ms at 20 Pa·s on 2.5 mm cells), the implicit one does not, and the two
read a Newtonian stir alike (docs/validation-closed-forms.md, The implicit shear stress).
A window whose size does not grow with viscosity (a slope d ln M / d ln η ≤ ``MIN_SLOPE``: inertia sets its drag)
is not ``resolvable``, nor is one read at the thickest rung or above it (``capped``: no rung is simulated above it,
where every fluid reads alike, so such a fluid is at least that thick there). A rung whose simulation diverges
(non-finite readings: the implicit step with the last step's pressure can grow unstable at 90-115 Pa·s and
0.16 m/s on 2 ms steps, docs/flow-curve.md) is simulated once more at ``RETRY_STEP`` of the step; diverged again,
it is dropped with a warning and the rung below it becomes the thickest. A rung's
fluid has one viscosity all through the programme, where a thinning fluid was thicker during the slower speeds before
a window: the window's flow carries that history (the bulk rotation the earlier speeds set up) only as far as a
Newtonian fluid of its own apparent viscosity would, as in the window fits.
Reading a flow curve's nodes jointly instead (a tabulated fluid through every window's point, simulated whole) is
ill-posed: each window's drag averages η over a band of shear rates wider than the factor 2 between the planned
speeds, so neighbouring nodes trade viscosity against each other (docs/flow-curve.md).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace

import numpy as np

from ..mpm import SimConfig
from ..parallel import Workers
from ..recording import RecordingError
from .apparent import CAP_TOLERANCE, ViscosityPoint, with_baseline
from .initial import SHEAR_RATE_PROBES, metzner_otto_constant
from .jobs import ReadingJob, mean_readings_on
from .magnitude import expected_magnitude
from .models import FitModel
from .optimise import noise_scale
from .problem import StirProblem, Windows
from .windows import SpeedWindow

#: Newtonian viscosities [Pa·s] of the first rungs: the paper's fluids lie within a decade of them.
START_VISCOSITIES = (0.1, 1.0)
#: A window is read when the rungs that bracket its size lie within this factor of each other.
BRACKET = 1.5
#: Rungs closer than this in ln η count as one [1].
SAME_RUNG = 0.05
#: Most rungs of one programme.
MAX_RUNGS = 8
#: Rungs added in each round of bracketing (two simulations side by side on the 2-core default).
RUNGS_PER_ROUND = 2
#: Largest extrapolation beyond the last rung in ln η [1], and the lowest slope s_k of a resolvable window [1].
MAX_STEP, MIN_SLOPE = 1.5, 0.05
#: Gauss-Newton steps of a window's fit at most, and the step in ln η [1] below which it has converged: a thousandth
#: of the 3 % force error.
GAUSS_NEWTON_STEPS, CONVERGED = 20, 3e-5
#: Slope d ln M / d ln η [1] from which a window's drag counts as viscous, where k_s is measured: at the
#: slowest speed the drag of a thin fluid can sit at the sensor's resolution, where the probes read noise.
VISCOUS_SLOPE = 0.5
#: The most viscous rung by default [Pa·s]: Carbopol microgels and yield-stress pastes read 30-120 Pa·s at the
#: slowest planned speed (docs/accuracy-plan.md).
THICKEST_RUNG = 200.0
#: A rung whose simulation diverges is simulated once more with its ``dt_max`` times this [1].
RETRY_STEP = 0.5
#: Simulations of one programme analysis at most: the rungs and the effective shear rate's four.
PROGRAMME_SIMULATIONS = MAX_RUNGS + SHEAR_RATE_PROBES


@dataclass(frozen=True)
class Rungs:
    """Newtonian ``viscosities`` [Pa·s] (ascending) and each window's simulated ln M [1] at them, ``log_sizes``
    (rungs, windows)."""

    viscosities: np.ndarray
    log_sizes: np.ndarray

    def read(self, target: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per window with measured ln M̂ ``target``: ln η, the slope s = d ln M / d ln η of its bracket, and the
        bracket's width in ln η: inf where extrapolated, except below a flat foot of the ladder (s ≤ ``MIN_SLOPE``:
        the size is the sensor's noise or the inertia, which a thinner rung reads no differently), where it is 0."""
        x = np.log(self.viscosities)
        log_eta, slope, width = [], [], []
        for k, y in enumerate(self.log_sizes.T):
            above = int(np.searchsorted(y, target[k])) if np.all(np.diff(y) > 0) else len(y)
            j = min(max(above, 1), len(y) - 1)
            s = (y[j] - y[j - 1]) / (x[j] - x[j - 1])
            inside = 0 < above < len(y)
            step = (target[k] - y[j - 1]) / max(s, MIN_SLOPE)
            log_eta.append(float(np.clip(x[j - 1] + step, x[0] - MAX_STEP, x[-1] + MAX_STEP)))
            slope.append(float(s))
            flat_foot = above == 0 and s <= MIN_SLOPE
            width.append(float(x[j] - x[j - 1]) if inside else 0.0 if flat_foot else math.inf)
        return np.array(log_eta), np.array(slope), np.array(width)


@dataclass(frozen=True)
class ProgrammeFit:
    """What ``programme_viscosities`` found: the ``points`` (one per window, in order), the Metzner-Otto constant
    ``metzner_otto`` k_s [1], the ``rungs``' viscosities [Pa·s], the ``simulations`` spent, the ``ceiling`` [Pa·s]
    at and above which a window is ``capped``, and the rungs dropped because their simulation ``diverged`` [Pa·s]
    (the ceiling is then the rung below the thinnest of them, else the larger of ``thickest_rung`` and the
    simulator's ``viscosity_cap``)."""

    points: list[ViscosityPoint]
    metzner_otto: float
    rungs: tuple[float, ...]
    simulations: int
    ceiling: float
    diverged: tuple[float, ...] = ()

    def summary(self) -> dict:
        recording = self.points[0].window.recording
        return {"recording": str(recording.path or recording.name or "recording"), "metzner_otto": self.metzner_otto,
                "rungs": list(self.rungs), "simulations": self.simulations, "ceiling": self.ceiling,
                "diverged": list(self.diverged),
                "units": {"rungs": "Pa s", "ceiling": "Pa s", "diverged": "Pa s"},
                "meaning": "rungs: the Newtonian viscosities simulated over the whole programme, every window read "
                           "off them (docs/flow-curve.md); ceiling: the viscosity at which a window reads as "
                           "capped; diverged: rungs dropped because their simulation diverged at either step"}


def programme_viscosities(windows: list[SpeedWindow], config: SimConfig, density: float, *, workers: Workers,
                          model_error: float, inertial_error: float = 0.0, thickest_rung: float = THICKEST_RUNG,
                          stage: str = "programme") -> ProgrammeFit:
    """The apparent viscosity of each of one recording's ``windows`` (module docstring) on the simulation
    ``config`` for a fluid of ``density`` [kg/m³], the simulations run by ``workers``; ``model_error`` σ_m and
    ``inertial_error`` σ_i are the simulator's relative force errors (``fitting.uncertainty``); ``thickest_rung``
    [Pa·s] is the most viscous rung, those above ``config.viscosity_cap`` simulated implicitly."""
    recording = windows[0].recording if windows else None
    if recording is None or any(w.recording is not recording for w in windows):
        raise ValueError("programme: expected the speed windows of one recording")
    end = windows[-1].end
    cap = max(config.viscosity_cap, thickest_rung)  # Pa·s: no rung above it, where every fluid reads alike
    problem = StirProblem(recording, config, density, Windows(windows[0].start, end, end))
    thick_problem = problem.with_config(config.replace(viscous_solver="implicit", viscosity_cap=cap))

    def problem_of(eta: float) -> StirProblem:
        """The whole stir simulated as a rung of viscosity ``eta`` [Pa·s] is: implicitly above the cap."""
        return problem if eta <= config.viscosity_cap else thick_problem
    masks = np.array([(problem.times > w.start) & (problem.times <= w.end) for w in windows])
    noise = noise_scale(problem.measured, recording.sensor.resolution)
    target = np.log([float(np.mean(np.abs(problem.measured[m]))) for m in masks])
    readings: dict[float, np.ndarray] = {}
    dropped: list[float] = []  # Pa·s: rungs whose simulation diverged at either step

    def simulate(viscosities: list[float]) -> Rungs:
        nonlocal cap
        jobs = [ReadingJob(stage, f"rung {eta:.6g}", problem_of(eta), FitModel.named("newtonian", eta=eta))
                for eta in viscosities]
        found = dict(zip(viscosities, workers.map(jobs)))
        diverged = [(eta, job) for eta, job in zip(viscosities, jobs) if not np.all(np.isfinite(found[eta]))]
        retried = [replace(job, problem=job.problem.with_config(job.problem.config.replace(
            dt_max=job.problem.config.dt_max * RETRY_STEP))) for _, job in diverged]
        found.update(zip([eta for eta, _ in diverged], workers.map(retried)))
        for eta, reading in found.items():
            if np.all(np.isfinite(reading)):
                readings[eta] = reading
            else:  # the step diverged at either length: the thinner rungs are the ladder's top
                dropped.append(eta)
                cap = min(cap, max([v for v in readings if v < eta], default=min(viscosities)))
                warnings.warn(f"{stage}: the {eta:.4g} Pa s rung's simulation diverged; windows thicker than "
                              f"{cap:.4g} Pa s are read as at the viscosity cap", RuntimeWarning, stacklevel=2)
        etas = np.array(sorted(readings))
        sizes = [[math.log(float(np.mean(expected_magnitude(readings[eta][m], noise)))) for m in masks]
                 for eta in etas]
        return Rungs(etas, np.array(sizes))

    start = sorted({min(eta, cap) for eta in START_VISCOSITIES})
    rungs = simulate(start if len(start) > 1 else [cap / 10, cap])
    if len(readings) < 2:  # a start rung diverged: one a decade thinner than the one left brackets from below
        rungs = simulate([min(readings, default=cap) / 10])
    if len(readings) < 2:
        raise RecordingError(f"{stage}: the rungs' simulations of {recording.path or recording.name} diverged; "
                             "use a smaller sim.dt_max (s)")
    log_eta, slope, width = rungs.read(target)
    while np.max(width) > math.log(BRACKET) and len(readings) < MAX_RUNGS:
        new: list[float] = []
        for k in np.argsort(-width):
            if len(new) == min(RUNGS_PER_ROUND, MAX_RUNGS - len(readings)) or width[k] <= math.log(BRACKET):
                break
            eta = min(_next_rung(rungs.viscosities, float(log_eta[k])), cap)
            if all(abs(math.log(eta / v)) > SAME_RUNG for v in [*new, *rungs.viscosities]):
                new.append(eta)
        if not new:  # the widest brackets lie above the cap
            break
        rungs = simulate(new)
        log_eta, slope, width = rungs.read(target)
    capped = log_eta >= math.log(cap) - CAP_TOLERANCE
    probe = _probe_window(np.where(capped, 0.0, slope))
    window = windows[probe]
    probe_viscosity = min(float(np.exp(log_eta[probe])), cap)
    probed = StirProblem(recording, problem_of(probe_viscosity).config, density,
                         Windows(window.start, window.end, window.end))
    k_s = metzner_otto_constant(probed, probe_viscosity,
                                evaluate=lambda models: mean_readings_on(workers, stage, probed, models))
    simulations = len(readings) + SHEAR_RATE_PROBES
    points = []
    for k, window in enumerate(windows):
        resolvable = slope[k] > MIN_SLOPE and not capped[k]
        estimate = _waveform_estimate(readings, problem.measured[masks[k]], masks[k], float(log_eta[k]),
                                      recording.sensor.resolution or 0.0, model_error, inertial_error)
        x, log_std, model_log_std, baseline, p = estimate
        points.append(ViscosityPoint(
            window=window, speed=window.speed, measured_shear_rate=k_s * window.speed / recording.rod.radius,
            viscosity=math.exp(x), log_std=log_std if resolvable else math.inf,
            model_log_std=model_log_std if resolvable else math.inf, baseline=baseline, resolvable=bool(resolvable),
            loss=float(np.mean(np.abs(problem.measured[masks[k]] - p))), evaluations=simulations,
            slice_factor=_slice_factor(problem, min(math.exp(x), cap)), capped=bool(capped[k])))
    return ProgrammeFit(points, k_s, tuple(float(v) for v in rungs.viscosities), simulations, float(cap),
                        tuple(sorted(dropped)))


def _next_rung(viscosities: np.ndarray, log_eta: float) -> float:
    """The rung [Pa·s] that narrows the bracket of a window read at ln η: at it, or, where a rung stands there
    already, a factor √``BRACKET`` beyond it towards the farther end of its bracket."""
    x = np.log(viscosities)
    nearest = float(x[np.argmin(np.abs(x - log_eta))])
    if abs(nearest - log_eta) > SAME_RUNG:
        return math.exp(log_eta)
    below, above = x[x < nearest - SAME_RUNG], x[x > nearest + SAME_RUNG]
    gap_below = nearest - below.max() if below.size else math.inf
    gap_above = above.min() - nearest if above.size else math.inf
    return math.exp(nearest + (0.5 if gap_above >= gap_below else -0.5) * math.log(BRACKET))


def _bracket(x: np.ndarray, value: float) -> int:
    """The index j of the segment [x_(j−1), x_j] of ascending ``x`` that holds ``value``, the end one beyond them."""
    return min(max(int(np.searchsorted(x, value)), 1), x.size - 1)


def _slice_factor(problem: StirProblem, eta: float) -> float | None:
    """The slice correction C the rungs' readings carry at viscosity ``eta`` [Pa·s] (``fitting.problem``: the
    recording's mean stir, one C for every window; None in 3-D)."""
    correction = problem.slice_correction(FitModel.named("newtonian", eta=eta).material)
    return None if correction is None else correction.factor


def _probe_window(slope: np.ndarray) -> int:
    """The window k_s is measured on: the first whose size grows with η at least half as fast as η
    (s ≥ ``VISCOUS_SLOPE``: viscous drag), else the one where it grows fastest."""
    viscous = np.flatnonzero(slope >= VISCOUS_SLOPE)
    return int(viscous[0]) if viscous.size else int(np.argmax(slope))


def _waveform_estimate(readings: dict[float, np.ndarray], measured: np.ndarray, mask: np.ndarray, log_eta: float,
                       resolution: float, model_error: float, inertial_error: float
                       ) -> tuple[float, float, float, float, np.ndarray]:
    """A window's ln η, its standard errors from the noise and from the simulator, its baseline b [N] and the
    rungs' readings there [N]: the window's ``measured`` readings [N] fitted by p(η) + b, p linear in η between the
    two rungs that bracket it, p = p_lo + (η − η_lo) (p_hi − p_lo) / (η_hi − η_lo), so that J = d p / d ln η =
    η (p_hi − p_lo) / (η_hi − η_lo) is the local slope of a drag ∝ η on an inertial part. Gauss-Newton steps in
    ln η (``apparent.with_baseline``: b's prior N(0, ``resolution``²)) from the size's estimate ``log_eta``, in the
    bracket each step lands in, until a step moves ln η by less than ``CONVERGED``."""
    etas = np.array(sorted(readings))
    lowest, highest = math.log(etas[0]) - MAX_STEP, math.log(etas[-1]) + MAX_STEP
    for _ in range(GAUSS_NEWTON_STEPS):
        p, per_viscosity = _interpolated(readings, etas, mask, log_eta)
        step = with_baseline(math.exp(log_eta) * per_viscosity, measured - p, log_eta, resolution, p,
                             model_error, inertial_error)
        moved = float(np.clip(step[0], lowest, highest))
        converged = abs(moved - log_eta) < CONVERGED
        log_eta, (log_std, model_log_std, baseline) = moved, step[1:]
        if converged:
            break
    return log_eta, log_std, model_log_std, baseline, _interpolated(readings, etas, mask, log_eta)[0]


def _interpolated(readings: dict[float, np.ndarray], etas: np.ndarray, mask: np.ndarray, log_eta: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The rungs' readings p [N] on ``mask`` at ln η, linear in η between the two of ascending ``etas`` [Pa·s] that
    bracket it (the end two beyond them), and d p / d η [N/(Pa·s)]."""
    j = _bracket(np.log(etas), log_eta)
    low, high = (readings[etas[i]][mask] for i in (j - 1, j))
    per_viscosity = (high - low) / (etas[j] - etas[j - 1])
    return low + (math.exp(log_eta) - etas[j - 1]) * per_viscosity, per_viscosity
