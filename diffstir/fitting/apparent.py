"""The apparent viscosity of one constant-speed window: a Newtonian fit through the simulator, read at the
window's measured effective shear rate.

The window's readings are fitted by the Newtonian law (``diffstir.fitting``: a Newtonian ladder for the start,
a few Gauss-Newton steps). A force sensor keeps a baseline b [N] (offset and slow drift left after the dry-run
subtraction), which in a short window looks like part of the drag: a 2 mN offset on a 10 mN drag moves η by
20 %. b is a nuisance parameter of each window with the prior b ~ N(0, q²), q the sensor's resolution [N] (what a
dry-run subtraction can leave; none for a recording without one), estimated with ln η in a last Gauss-Newton step
on the fit's Jacobian J and residuals r:

    [ω AᵀA + diag(0, 1/q²)] (Δ ln η, b) = ω Aᵀ r,   A = [J, 1],   ω = N_eff / (N s²),

whose inverse matrix is the covariance; s² = RSS/(N − 2) and N_eff (``fitting.uncertainty``) come from the
residuals r − A (Δ ln η, b) the step leaves, by passes from r until ω settles (a baseline is not noise). Where
the reading cannot tell a baseline from the drag, the interval of ln η widens.

The simulator's own force error (``fitting.uncertainty``), a relative error σ_m of the simulated readings p and a
relative error σ_i of their inertial part p − J (J = dp/d ln η, the readings' viscous part), moves ln η by the same
step's response to them, (Δ ln η, b) = C ω Aᵀ (σ_m p) and C ω Aᵀ (σ_i (p − J)) with C the covariance above, in
quadrature: about σ_m / e and σ_i (1 − e) / e for a reading whose viscous share is e. It is reported apart from the
noise's error (``model_log_std``), because it does not average out over windows: where the drag is set by inertia
(e → 0 at high Reynolds numbers) the viscosity is not measured, whatever the noise, and that window's interval says
so.

The Newtonian-equivalent viscosity η_N is the fluid's apparent viscosity at the window's Metzner-Otto effective
shear rate γ̇_eff = k_s U / a [1/s] (U the rod's speed, a its radius; k_s measured with the power-law probe of
``fitting.initial.effective_shear_rate``). The simulation runs from the recording's first sample to the
window's end, so a later window of a programme pays for the stretches before it. Its acoustic time step is that of
the whole recording's fastest motion, min(cfl Δx / (c + u_max), dt_max) (``recording_config``): the simulator
picks the step from the simulated span's top speed, and an early, slow window simulated with a longer step than a
later one reads a few per cent differently from the same fluid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ..mpm import SimConfig
from ..recording import Recording
from .initial import LADDER_VISCOSITIES, SHEAR_RATE_PROBES, ViscosityLadder, effective_shear_rate
from .models import FitModel
from .optimise import fit_model
from .problem import StirProblem, Windows
from .progress import Progress, fit_simulations
from .uncertainty import MODEL_FORCE_ERROR, Z95, checked_model_error, effective_samples, force_error
from .windows import SpeedWindow

#: Ladder around a previous window's viscosity: a factor 4 each way brackets a change of speed by 2-4 for any
#: flow index between 0 and 2.
LADDER_FACTOR = 4.0

#: Passes of the baseline step at most, and the relative change of its noise weight ω that ends them: a baseline
#: of several q on a window whose drag is nearly constant settles in about five.
NOISE_PASSES, NOISE_CONVERGED = 20, 1e-6

#: A Newtonian fit within this of ln ``viscosity_cap`` [1] (0.1 % in η) ends at the cap, its upper bound.
CAP_TOLERANCE = 1e-3


@dataclass(frozen=True)
class ViscosityPoint:
    """The apparent viscosity of one window.

    Attributes:
        window: where it was measured.
        speed: the rod's mean speed U [m/s].
        measured_shear_rate: the window's effective shear rate γ̇_eff [1/s] as measured by the power-law probe.
        viscosity: the Newtonian-equivalent viscosity η_N [Pa·s].
        log_std: standard error of ln η_N from the reading's noise and baseline [1].
        model_log_std: standard error of ln η_N from the simulator's relative force errors σ_m and σ_i [1] (module
            docstring); common to windows of similar Reynolds number.
        baseline: the sensor's baseline in the window [N] (a nuisance parameter, module docstring).
        resolvable: whether the reading's level lies above that of the lowest informative ladder probe (a thinner
            fluid's drag is set by inertia, not viscosity), and the fit is below the simulator's viscosity cap.
        capped: whether the Newtonian fit ends at the simulator's ``viscosity_cap`` [Pa·s], above which the reading
            no longer responds to η: the fluid is at least that thick here, and the window is not resolvable.
        loss: the paper's loss of the Newtonian fit, mean |ΔF| [N].
        evaluations: forward simulations spent.
        slice_factor: the slice's correction C of the fitted fluid (``fitting.problem``: F = F' h C; None in 3-D).
    """

    window: SpeedWindow
    speed: float
    measured_shear_rate: float
    viscosity: float
    log_std: float
    model_log_std: float
    baseline: float
    resolvable: bool
    loss: float
    evaluations: int
    slice_factor: float | None = None
    capped: bool = False

    @property
    def metzner_otto(self) -> float:
        """The window's Metzner-Otto constant k_s = γ̇_eff a / U [1] (a: the rod's radius [m])."""
        return self.measured_shear_rate * self.window.recording.rod.radius / self.speed

    @property
    def total_log_std(self) -> float:
        """Standard error of ln η_N from the noise and the simulator together [1]."""
        return math.hypot(self.log_std, self.model_log_std)

    @property
    def ci95(self) -> tuple[float, float]:
        """95 % interval of η_N [Pa·s] from both errors, symmetric in ln η."""
        half = Z95 * self.total_log_std
        return self.viscosity * math.exp(-half), self.viscosity * math.exp(half)

    def summary(self) -> dict:
        return {"window": self.window.label, "start": self.window.start, "end": self.window.end,
                "speed": self.speed, "measured_shear_rate": self.measured_shear_rate,
                "metzner_otto": self.metzner_otto, "viscosity": self.viscosity,
                "viscosity_ci95": list(self.ci95), "log_std": self.log_std,
                "model_log_std": self.model_log_std, "baseline": self.baseline,
                "resolvable": self.resolvable, "capped": self.capped,
                "loss": self.loss, "evaluations": self.evaluations, "slice_factor": self.slice_factor,
                "units": {"speed": "m/s", "measured_shear_rate": "1/s", "metzner_otto": "1", "viscosity": "Pa s",
                          "baseline": "N", "loss": "N"}}


def window_simulations(guessed: bool, iterations: int) -> int:
    """The simulations ``window_viscosity`` is expected to spend: the ladder's probes (two around a ``guessed``
    viscosity, else one per ladder rung), the Newtonian fit of ``iterations`` and the effective shear rate's
    probes."""
    ladder = 2 if guessed else len(LADDER_VISCOSITIES)
    return ladder + fit_simulations(1, iterations, 2) + SHEAR_RATE_PROBES


def window_viscosity(window: SpeedWindow, config: SimConfig, density: float, *, guess: float | None = None,
                     iterations: int = 3, model_error: float = MODEL_FORCE_ERROR, inertial_error: float = 0.0,
                     on_evaluation: Callable[[float | None], None] | None = None) -> ViscosityPoint:
    """The apparent viscosity of ``window`` (see the module docstring) on the simulation ``config`` for a fluid of
    ``density`` [kg/m³]. ``guess`` [Pa·s] (a neighbouring window's viscosity) shortens the ladder to two probes a
    factor ``LADDER_FACTOR`` either side; without it the full ladder (one probe per decade) is simulated.
    ``iterations``: Gauss-Newton iterations of the Newtonian fit. ``model_error``: the relative 1-σ error σ_m of
    ``config``'s simulated force, ``inertial_error`` the relative 1-σ error σ_i of its inertial part
    (``fitting.uncertainty``; 0 leaves either out). ``on_evaluation(loss)`` is called
    after every simulation, with the fit's loss [N] where the simulation is the fit's, else None."""
    checked_model_error(model_error, "model_error")
    checked_model_error(inertial_error, "inertial_error")
    config = recording_config(config, window.recording)
    problem = StirProblem(window.recording, config, density, Windows(window.start, window.end, window.end))
    evaluations = 0

    def count(*_):
        nonlocal evaluations
        evaluations += 1
        if on_evaluation is not None:
            on_evaluation(None)

    def fit_evaluation(_name, _count, loss):
        if on_evaluation is not None:
            on_evaluation(loss)

    if guess is None:
        ladder = ViscosityLadder.simulate(problem, on_evaluation=count)
    else:  # no thicker than the cap: the simulator holds none, and a capped window's guess may lie far above it
        guess = min(guess, config.viscosity_cap)
        ladder = ViscosityLadder.simulate(problem, (guess / LADDER_FACTOR, guess * LADDER_FACTOR), on_evaluation=count)
    fit = fit_model(problem, FitModel.named("newtonian", eta=ladder.estimate(problem)), max_iterations=iterations,
                    on_evaluation=fit_evaluation)
    evaluations += fit.evaluations
    train = problem.train
    correction = problem.slice_correction(fit.model.material)
    log_eta, log_std, model_log_std, baseline = with_baseline(
        fit.jacobian[train, 0], (problem.measured - fit.predicted)[train], fit.theta[0],
        window.recording.sensor.resolution or 0.0, fit.simulated_readings[train],
        force_error(model_error, correction), inertial_error)
    eta = math.exp(log_eta)
    capped = bool(fit.theta[0] >= math.log(config.viscosity_cap) - CAP_TOLERANCE)
    rate = effective_shear_rate(problem, min(eta, config.viscosity_cap), on_evaluation=count)
    return ViscosityPoint(window=window, speed=window.speed, measured_shear_rate=rate, viscosity=eta,
                          log_std=log_std, model_log_std=model_log_std, baseline=baseline,
                          resolvable=ladder.resolves(float(np.mean(np.abs(problem.measured)))) and not capped,
                          loss=fit.loss, evaluations=evaluations,
                          slice_factor=None if correction is None else correction.factor, capped=capped)


@dataclass
class WindowsJob:
    """The apparent viscosities of one recording's ``windows`` in order, each window's ladder started from the
    viscosity before it (``window_viscosity``); a job for ``parallel.Workers`` whose events are each
    simulation, ``("evaluation", stage, window label, 0, loss or None)``, and each window's end,
    ``("window", stage, window label)``."""

    stage: str
    key: str
    windows: list[SpeedWindow]
    config: SimConfig
    density: float  # kg/m³
    iterations: int
    model_error: float
    inertial_error: float = 0.0

    @property
    def priority(self) -> tuple[bool, float]:
        """The recording simulated longest first."""
        return True, sum(w.end for w in self.windows)

    def run(self, report) -> list[ViscosityPoint]:
        points: list[ViscosityPoint] = []
        for window in self.windows:
            def evaluation(loss, label=window.label):
                report(("evaluation", self.stage, label, 0, loss))

            points.append(window_viscosity(window, self.config, self.density,
                                           guess=points[-1].viscosity if points else None,
                                           iterations=self.iterations, model_error=self.model_error,
                                           inertial_error=self.inertial_error, on_evaluation=evaluation))
            report(("window", self.stage, window.label))
        return points


def window_event(tracker: Progress, event: tuple) -> None:
    """A ``WindowsJob``'s event counted against its window's task."""
    kind, _stage, label, *data = event
    if kind == "evaluation":
        tracker.evaluation(label, label, data[1])
    elif kind == "window":
        tracker.finished(label)


def recording_config(config: SimConfig, recording: Recording) -> SimConfig:
    """``config`` with ``dt_max`` lowered to the acoustic step cfl Δx / (c + u_max) [s] of the recording's fastest
    rod speed u_max [m/s] (the acoustic limit of ``StirringSimulator.time_step``)."""
    u_max = float(np.max(np.linalg.norm(recording.velocity(), axis=1)))
    return replace(config, dt_max=min(config.dt_max, config.cfl * config.dx / (config.sound_speed + u_max)))


def with_baseline(jacobian: np.ndarray, residuals: np.ndarray, log_eta: float, resolution: float,
                  readings: np.ndarray, model_error: float, inertial_error: float = 0.0
                  ) -> tuple[float, float, float, float]:
    """ln η, its standard errors from the noise and from the simulator, and the baseline b [N], from the
    Gauss-Newton step with the baseline's prior (module docstring): ``jacobian`` d reading / d ln η [N],
    ``residuals`` measured − fitted [N], ``log_eta`` the fit's ln η, ``resolution`` q [N] (0: no baseline),
    ``readings`` the simulated readings p [N], ``model_error`` their relative error σ_m [1] and
    ``inertial_error`` the relative error σ_i of their inertial part p − J [1]."""
    design = np.column_stack([jacobian, np.ones_like(jacobian)])
    keep = np.array([1.0, 1.0 if resolution > 0 else 0.0])
    weight = _noise_weight(residuals, 1 + int(keep[1]))
    for _ in range(NOISE_PASSES):  # the noise's variance from the residuals the step leaves: b is not noise
        precision = weight * design.T @ design
        if resolution > 0:
            precision[1, 1] += 1.0 / resolution**2
        else:
            precision[1, :], precision[:, 1], precision[1, 1] = 0.0, 0.0, 1.0  # b held at 0
        rhs = weight * design.T @ residuals * keep
        try:
            covariance = np.linalg.inv(precision)
        except np.linalg.LinAlgError:  # a reading that does not change with η: nothing to estimate
            return log_eta, math.inf, math.inf, 0.0
        previous, weight = weight, _noise_weight(residuals - design @ (covariance @ rhs), 1 + int(keep[1]))
        if abs(weight - previous) <= NOISE_CONVERGED * weight:
            break
    weight = previous  # the one the covariance was computed with
    step = covariance @ rhs
    shift = covariance @ (weight * design.T @ readings * keep)  # d(ln η, b) per unit relative error of p
    inertial = covariance @ (weight * design.T @ (readings - jacobian) * keep)  # ... of p's inertial part
    return (log_eta + float(step[0]), math.sqrt(max(float(covariance[0, 0]), 0.0)),
            math.hypot(model_error * float(shift[0]), inertial_error * float(inertial[0])), float(step[1]))


def _noise_weight(residuals: np.ndarray, estimated: int) -> float:
    """ω = N_eff / (N s²) [1/N²] of ``residuals`` [N] left by a fit of ``estimated`` parameters,
    s² = RSS / (N − ``estimated``)."""
    n = residuals.size
    variance = float(residuals @ residuals) / max(n - estimated, 1)
    return min(effective_samples(residuals), float(n)) / n / max(variance, 1e-300)
