"""Fitting one model to a recording: Levenberg-Marquardt-type steps on θ with a finite-difference Jacobian of the
simulated readings (a handful of parameters, so k + 1 forward simulations per iteration and no reverse pass), or
the paper's plain gradient descent (Adam on the reverse-mode gradient of the paper's loss).

Each Gauss-Newton iteration reuses the Jacobian through Broyden updates (see ``_BroydenJacobian``), so an
iteration costs one forward simulation after the first.

The paper's loss is L = mean_i |F_measured(t_i) - F_simulated(t_i)| [N] over the fitted samples. The default
optimiser minimises the robust ``soft_l1`` cost sum_i 2 s² (sqrt(1 + (r_i/s)²) - 1), least squares for residuals
within the scale s and the paper's L1 loss for those far beyond it, where s is the robust size of the residuals
at the start (``residual_scale``), each residual first multiplied by its sample's weight (``problem.weights``
[1]: one for a single recording, each window's own scale for the behaviour app's joint fit; the Adam optimiser
keeps the paper's unweighted loss), with dogleg steps in a rectangular trust region inside the bounds
(scipy.optimize.least_squares, ``dogbox``) whose first size is ``TRUST_RADIUS`` per parameter.

The Gauss-Newton fit stops when it has converged in the statistical sense (``Convergence``): once the next
Gauss-Newton step, δ = -J⁺ r on the robustly weighted residuals, is under ``CONVERGED_STEP`` of every parameter's
standard error from the residuals, no further simulation can move the answer by a visible part of its interval;
otherwise it stops on its budget of evaluations.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch
from scipy import optimize

from ..errors import SimulationError
from ..mpm import SimConfig
from .models import FitModel
from .nuisance import NO_NUISANCE, SensorNuisance, lag_response
from .parameters import MaterialParameters
from .problem import FitProblem
from .uncertainty import laplace

#: The optimisers of ``fit_model``: trust-region Gauss-Newton on the soft-L1 cost, and the paper's Adam.
OPTIMIZERS = ("lm", "adam")

#: Smallest step in θ that updates the Broyden Jacobian: 100 float32 ulps of a relative change; a smaller step
#: cannot change the simulation's float32 parameters, so its secant carries no information.
MIN_SECANT_STEP = 100 * float(np.finfo(np.float32).eps)

#: The first trust region, per parameter scale: a factor e in a log-scaled parameter, 0.25 in an index.
TRUST_RADIUS = {"log": 1.0, "linear": 0.25}

#: Finite-difference steps in θ: 5 % relative change of a log-scaled parameter, 0.02 of a dimensionless index.
FD_STEP = {"log": 0.05, "linear": 0.02}

#: A Broyden update needs a step of at least this fraction of ``FD_STEP`` in some parameter: a secant's error is
#: the readings' noise between nearby viscosities over the step, which a simulation whose number of steps jumps
#: with η makes large for short steps. On the fine stage (a fixed step, the viscous stress in substeps) the 3 Pa·s
#: lab fluid's d ln p / d ln η over steps of 6.4e-4 to 0.05 in ln η is within 2 % of central differences
#: (``scripts/secant_noise.py``, docs/accuracy-2d.md).
SECANT_FRACTION = 0.2

#: The Gauss-Newton fit has converged once its next step is under this many standard errors in every parameter:
#: an estimate that far off its optimum still holds the truth in 94.9 % of 95 % intervals (a normal estimate
#: biased by 0.1 σ: Φ(1.96 − 0.1) − Φ(−1.96 − 0.1)).
CONVERGED_STEP = 0.1


@dataclass
class FitResult:
    """One model fitted to one recording.

    Attributes:
        model: the model at the fitted θ.
        theta: fitted θ, (k,).
        predicted: the readings at every compared sample [N], (M,) (fitted and held-out): the simulated ones
            through the fitted sensor nuisances.
        jacobian: d predicted / d θ at the fit, the nuisances held [N], (M, k).
        loss: the paper's loss, mean |measured - simulated| over the fitted samples [N].
        holdout_loss: the same over the held-out samples [N] (None without any).
        history: one entry per accepted evaluation: {"evaluation", "loss", "theta"}.
        evaluations: forward simulations spent.
        seconds: wall time spent [s].
        message: what stopped the optimiser.
        converged: the optimiser stopped on its tolerances, not on its budget of evaluations.
        sensor: the fitted sensor nuisances, SI by name (``nuisance.UNITS``; empty when none were fitted).
        simulated: the simulated readings p before the sensor nuisances [N], (M,) (None: same as predicted).
    """

    model: FitModel
    theta: np.ndarray
    predicted: np.ndarray
    jacobian: np.ndarray
    loss: float
    holdout_loss: float | None
    history: list[dict] = field(default_factory=list)
    evaluations: int = 0
    seconds: float = 0.0
    message: str = ""
    converged: bool = False
    sensor: dict[str, float] = field(default_factory=dict)
    simulated: np.ndarray | None = None

    @property
    def simulated_readings(self) -> np.ndarray:
        """p [N], (M,): the simulated readings before the sensor nuisances."""
        return self.predicted if self.simulated is None else self.simulated


class Readings:
    """Simulated readings of a model as a function of θ, cached by θ, counting forward simulations.

    ``on_evaluation(model_name, evaluations, loss)`` is called after every simulation (progress bars, logs).
    A θ whose simulation blows up (``FloatingPointError``) reads NaN, which the trust-region optimiser rejects
    as a step (it shrinks its region); the starting θ must simulate (``fit_model`` raises otherwise).
    """

    def __init__(self, problem: FitProblem, model: MaterialParameters,
                 on_evaluation: Callable[[str, int, float], None] | None = None):
        self.problem, self.model, self.on_evaluation = problem, model, on_evaluation
        self.cache: dict[bytes, np.ndarray] = {}
        self.evaluations = 0
        self.failures: list[str] = []

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        key = np.asarray(theta, dtype=np.float64).tobytes()
        if key not in self.cache:
            self.model.set_theta(theta)
            try:
                with torch.no_grad():
                    reading = self.problem.simulate(self.model.material).double().cpu().numpy()
            except FloatingPointError as error:
                self.failures.append(str(error))
                reading = np.full(len(self.problem.measured), np.nan)
            self.cache[key] = reading
            self.evaluations += 1
            if self.on_evaluation is not None:
                self.on_evaluation(self.model.name, self.evaluations, self.problem.loss(self.cache[key]))
        return self.cache[key]

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        """Forward differences d readings / d θ, (M, k); steps point inwards at an upper bound, and backwards where
        the forward step's simulation diverged."""
        theta = np.asarray(theta, dtype=np.float64)
        base = self(theta)
        columns = []
        for j, scale in enumerate(self.model.scales):
            h = FD_STEP[scale] * (-1.0 if theta[j] + FD_STEP[scale] > self.model.upper[j] else 1.0)
            shifted = theta.copy()
            shifted[j] += h
            column = (self(shifted) - base) / h
            if not np.isfinite(column).all():
                shifted[j] = theta[j] - h
                column = (base - self(shifted)) / h
            columns.append(column)
        self.model.set_theta(theta)
        return np.stack(columns, axis=1)


class _BroydenJacobian:
    """The Jacobian by forward differences at the first point, then by Broyden's rank-one updates from each step's
    change of readings, J += (Δf - J Δθ) Δθᵀ / (Δθᵀ Δθ): one forward simulation per iteration instead of k + 1.
    The final Jacobian, used for the uncertainty, is this matrix or one recomputed by finite differences
    (``fit_model``'s ``recompute_jacobian``).

    Steps shorter than ``min_step`` [θ units] in every parameter from the last update's point leave it unchanged
    (``SECANT_FRACTION``).

    A coarser simulation's Jacobian ``initial`` comes with that simulation's readings ``initial_readings`` at the
    same θ. Its forces differ from this one's mostly by a factor (a coarse grid under-resolves the viscous layers
    around the rod and reads less drag than the fine grid), and a Jacobian too small by that factor sends
    the first step too far, so the first matrix is s J_coarse with s = f·g / g·g, the least-squares ratio of this
    simulation's readings f to the coarse ones g (output space mapping; kept unscaled unless s > 0)."""

    def __init__(self, readings: Readings, initial: np.ndarray | None = None,
                 initial_readings: np.ndarray | None = None, min_step: np.ndarray | float = MIN_SECANT_STEP):
        self.readings = readings
        self.min_step = np.maximum(min_step, MIN_SECANT_STEP)
        self.theta: np.ndarray | None = None
        self.value: np.ndarray | None = initial
        self.initial_readings = initial_readings
        self.scale = 1.0

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        theta = np.asarray(theta, dtype=np.float64)
        f = self.readings(theta)
        if self.value is None:
            self.value = self.readings.jacobian(theta)
        elif self.theta is None and self.initial_readings is not None:
            g = self.initial_readings
            ratio = float(f @ g) / float(g @ g) if float(g @ g) > 0.0 else math.nan
            if math.isfinite(ratio) and ratio > 0.0:
                self.scale = ratio
                self.value = ratio * self.value
        elif self.theta is not None:
            step = theta - self.theta
            if not np.any(np.abs(step) >= self.min_step):
                return self.value  # too short: the base point stays, so that short steps add up to a long one
            self.value = self.value + np.outer(f - self.f - self.value @ step, step) / (step @ step)
        self.theta, self.f = theta.copy(), f
        return self.value


class Convergence:
    """Whether a Gauss-Newton fit of ``model`` has converged (module docstring): the step δ = -J⁺ r to its linear
    model's optimum, clipped into the bounds, is under ``CONVERGED_STEP`` of every parameter's standard error.

    r [N] and J [N per θ unit] are weighted as the soft-L1 cost of scale ``scale`` [N] weighs them, each sample by
    the square root of the cost's weight (1 + (r/s)²)^(-1/2), so that δ vanishes where the cost's gradient does.
    The standard errors are ``uncertainty.laplace``'s from these residuals alone, without the simulator's own
    error, which would widen them: the stricter test."""

    def __init__(self, model: MaterialParameters, scale: float):
        self.model, self.scale = model, scale

    def __call__(self, theta: np.ndarray, residuals: np.ndarray, jacobian: np.ndarray) -> bool:
        weight = (1.0 + (residuals / self.scale) ** 2) ** -0.25
        weighted_jacobian, weighted = weight[:, None] * jacobian, weight * residuals
        step = np.linalg.lstsq(weighted_jacobian, -weighted, rcond=None)[0]
        step = np.clip(theta + step, self.model.lower, self.model.upper) - theta
        error = laplace(self.model, theta, weighted_jacobian, weighted).standard_error()
        return bool(np.all(np.abs(step) <= CONVERGED_STEP * error))


def residual_scale(residuals: np.ndarray, noise: float) -> float:
    """The soft-L1 cost's scale [N]: the robust size 1.4826 median |r| of the residuals at the start, at least the
    reading's noise. Residuals within it are fitted by least squares, larger ones (spikes) by L1. At the noise
    scale instead, every residual an imperfect model leaves counts as an outlier: the cost is L1 throughout, its
    Gauss-Newton model has no curvature, and each step runs to the edge of the trust region."""
    return max(1.4826 * float(np.median(np.abs(residuals))), noise)


def noise_scale(measured: np.ndarray, resolution: float | None) -> float:
    """Robust noise level of a reading [N]: 1.4826 MAD of first differences / sqrt(2), at least the
    quantisation noise resolution/sqrt(12)."""
    mad = 1.4826 * np.median(np.abs(np.diff(measured) - np.median(np.diff(measured)))) / math.sqrt(2.0)
    floor = (resolution or 0.0) / math.sqrt(12.0)
    return max(mad, floor, 1e-12)


def baseline_shear_modulus_limit(config: SimConfig, density: float, dt: float, sound_speed: float) -> float:
    """The stiffest corotated baseline [Pa] stable at its fixed step ``dt`` [s] with the held ``sound_speed``
    [m/s]: the viscous number 2 d μ Δt² / (ρ Δx²) within ``viscous_safety`` times what the acoustic number
    c Δt / Δx leaves of 1 (0 where it leaves nothing)."""
    room = max(1.0 - sound_speed * dt / config.dx, 0.0)
    return config.viscous_safety * room * density * config.dx ** 2 / (2 * config.dim * dt ** 2)


def stable_baseline_start(problem: FitProblem, model: FitModel, steps: int = 40) -> None:
    """Lower the corotated baseline's starting μ [Pa] to the stiffest one that the sound speed it sets itself
    (``StirringSimulator.sound_speed``, then held through the fit) leaves stable at its step
    (``baseline_shear_modulus_limit``), no lower than its bound; unchanged where its start is stable. A stiffer μ
    raises the sound speed and so lowers the limit: the largest stable ln μ is found by bisection. SimulationError
    where even the bound is unstable."""
    def stable(log_mu: float) -> bool:
        trial = FitModel.named("corotated", dt=model.dt, shear_modulus=math.exp(log_mu))
        c = problem.simulator(trial.material).sound_speed(problem.trajectory)
        return math.exp(log_mu) <= baseline_shear_modulus_limit(problem.config, problem.density, model.dt, c)

    low, high = float(model.lower[0]), float(model.theta()[0])
    if stable(high):
        return
    if not stable(low):
        raise SimulationError(
            f"corotated: no shear modulus down to its bound {math.exp(low):.3g} Pa is stable at the baseline's "
            f"step dt = {model.dt:.3g} s on sim.dx = {problem.config.dx} m; fit without the baseline "
            "(baseline=false) or with a smaller sim.cfl")
    for _ in range(steps):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if stable(middle) else (low, middle)
    model.set_theta(np.array([low]))


def fit_model(problem: FitProblem, model: MaterialParameters, *, max_iterations: int = 6, optimizer: str = "lm",
              learning_rate: float = 0.05, initial_jacobian: np.ndarray | None = None,
              initial_readings: np.ndarray | None = None, recompute_jacobian: bool | None = None,
              on_evaluation: Callable[[str, int, float], None] | None = None,
              on_iteration: Callable[[MaterialParameters, int, float, np.ndarray], None] | None = None,
              sensor: SensorNuisance = NO_NUISANCE) -> FitResult:
    """Fit ``model`` (starting from its current θ) to ``problem``'s fitted samples.

    Args:
        max_iterations: Jacobian evaluations (``lm``) or gradient steps (``adam``).
        optimizer: ``"lm"`` (trust-region Gauss-Newton on the soft-L1 cost, the default) or ``"adam"`` (the
            paper's gradient descent on its L1 loss, reverse mode through the simulator).
        learning_rate: Adam's step in θ.
        initial_jacobian: d readings / d θ (M, k) from a coarser simulation of the same samples (coarse-to-fine):
            the first Broyden matrix, and, updated by Broyden steps, the Jacobian reported at the end, so that
            no finite differences are spent at this resolution.
        initial_readings: that coarser simulation's readings [N] at the starting θ, (M,): the coarse Jacobian is
            scaled by the ratio of this simulation's readings to them (``_BroydenJacobian``).
        recompute_jacobian: report the Jacobian recomputed by forward differences at the fit (k simulations); False
            reports the Broyden matrix updated along the fit's steps. None: recomputed unless ``initial_jacobian``
            is given.
        sensor: the sensor nuisances profiled out at every θ (``nuisance``; ``lm`` only).
        on_evaluation: called after each forward simulation with (model name, count, loss [N]).
        on_iteration: called after each iteration with (model, iteration, loss [N], θ), e.g. to checkpoint.
    """
    start = time.perf_counter()
    if model.is_baseline and problem.config.fixed_sound_speed is None:
        stable_baseline_start(problem, model)
    if problem.config.fixed_sound_speed is None:  # one sound speed for the whole fit (``FitProblem.frozen``)
        problem = problem.frozen(model.material)
    cfg = problem.config
    if model.name == "newtonian":  # above the simulator's viscosity cap [Pa·s] the reading stops responding to η
        model.upper[0] = min(model.upper[0], math.log(cfg.viscosity_cap))
    elif model.is_baseline:
        mu_max = baseline_shear_modulus_limit(cfg, problem.density, model.dt, cfg.fixed_sound_speed)
        model.upper[0] = min(model.upper[0], math.log(max(mu_max, 1e-12)))
    if sensor.fitted and optimizer != "lm":
        raise ValueError(f"fit.sensor_nuisance = {list(sensor.fitted)} needs fit.optimizer = lm (it is profiled out "
                         "of the Gauss-Newton steps); set fit.sensor_nuisance = [] for the paper's Adam")
    readings = Readings(problem, model, on_evaluation)
    train = problem.train
    times = problem.times if sensor.fitted else None  # sample times [s], needed by the lag only
    measured = problem.measured[train]
    weights = problem.weights[train]
    history: list[dict] = []
    profiles: dict[bytes, dict[str, float]] = {}

    def reading(theta: np.ndarray) -> tuple[np.ndarray, dict[str, float]]:
        """The reading [N] at θ through the sensor nuisances profiled there, and their values."""
        p = readings(theta)
        if not np.isfinite(p).all():  # a blown-up trial step: rejected by the optimiser
            return p, {}
        key = np.asarray(theta, dtype=np.float64).tobytes()
        if key not in profiles:
            profiles[key] = sensor.profile(p, problem.measured, times, train)
        return sensor.apply(p, times, profiles[key]), profiles[key]

    def record(theta: np.ndarray, loss: float) -> None:
        history.append({"evaluation": readings.evaluations, "loss": loss, "theta": [float(t) for t in theta]})
        if on_iteration is not None:
            on_iteration(model, len(history), loss, theta)

    theta0 = np.clip(model.theta(), model.lower, model.upper)
    if not np.isfinite(readings(theta0)).all():
        raise SimulationError(f"{model.name}: the fit's starting point does not simulate: {readings.failures[-1]}")
    if optimizer == "lm":
        scale = residual_scale(weights * (reading(theta0)[0][train] - measured),
                               noise_scale(problem.measured, problem.recording.sensor.resolution))

        def residuals(step):
            return weights * (reading(theta0 + step)[0][train] - measured)

        broyden = _BroydenJacobian(readings, initial_jacobian, initial_readings,
                                   min_step=SECANT_FRACTION * np.array([FD_STEP[s] for s in model.scales]))
        converged_at = Convergence(model, scale)
        jacobians: dict[bytes, np.ndarray] = {}

        def jacobian(step):
            theta = theta0 + step
            jac = broyden(theta)
            y, values = reading(theta)
            record(theta, problem.loss(y))
            key = np.asarray(step).tobytes()
            jacobians[key] = weights[:, None] * sensor.projected(lag_response(jac, times, values.get("lag", 0.0)),
                                                                 readings(theta), times, values, train)
            return jacobians[key]

        def stop_when_converged(intermediate_result):
            step = intermediate_result.x
            if converged_at(theta0 + step, residuals(step), jacobians[np.asarray(step).tobytes()]):
                raise StopIteration

        # in steps from the start, so the first trust region is TRUST_RADIUS whatever θ's units (the dogbox
        # method's box starts at the size of x0 in x_scale units, or 1 at x0 = 0)
        radius = np.array([TRUST_RADIUS[s] for s in model.scales])
        solution = optimize.least_squares(residuals, np.zeros_like(theta0), jac=jacobian,
                                          bounds=(model.lower - theta0, model.upper - theta0), method="dogbox",
                                          loss="soft_l1", f_scale=scale, max_nfev=max_iterations, x_scale=radius,
                                          callback=stop_when_converged)
        best, message, converged = theta0 + solution.x, solution.message, solution.status > 0
        if solution.status == -2:
            message, converged = f"the next Gauss-Newton step is under {CONVERGED_STEP} standard errors", True
    elif optimizer == "adam":
        best, message = _adam(problem, model, readings, theta0, max_iterations, learning_rate, record)
        converged = False
    else:
        raise ValueError(f"fit.optimizer = {optimizer!r}; choose from {', '.join(OPTIMIZERS)}")
    # the optimiser's own θ, not one read back from the float32 parameters: the readings there are cached, and a
    # rounding-sized step would otherwise cost a simulation and a degenerate Broyden update
    theta = np.clip(np.asarray(best, dtype=np.float64), model.lower, model.upper)
    model.set_theta(theta)
    predicted, values = reading(theta)
    if recompute_jacobian is None:
        recompute_jacobian = initial_jacobian is None
    jac = readings.jacobian(theta) if recompute_jacobian or optimizer != "lm" else broyden(theta)
    return FitResult(model=model, theta=theta, predicted=predicted,
                     jacobian=lag_response(jac, times, values.get("lag", 0.0)), loss=problem.loss(predicted),
                     holdout_loss=problem.loss(predicted, train=False),
                     history=history, evaluations=readings.evaluations, seconds=time.perf_counter() - start,
                     message=str(message), converged=bool(converged), sensor=dict(values),
                     simulated=readings(theta) if sensor.fitted else None)


def _adam(problem: FitProblem, model: FitModel, readings: Readings, theta0: np.ndarray, iterations: int,
          learning_rate: float, record) -> tuple[np.ndarray, str]:
    """The paper's optimiser: Adam on θ with the reverse-mode gradient of mean |measured - simulated|."""
    theta = torch.tensor(theta0, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([theta], lr=learning_rate)
    measured = torch.as_tensor(problem.measured[problem.train])
    train = torch.as_tensor(problem.train)
    best, best_loss = theta0.copy(), math.inf
    for _ in range(iterations):
        model.set_theta(theta.detach().numpy())
        # the law's raw parameters follow θ through the bounded map; chain d loss/d raw into d loss/d θ
        loss = (problem.simulate(model.material)[train].double() - measured).abs().mean()
        params = list(model.material.parameters())
        grads = torch.autograd.grad(loss, params)
        readings.evaluations += 1
        theta_grad = model.theta_gradient(grads)
        opt.zero_grad()
        theta.grad = torch.as_tensor(theta_grad)
        value = float(loss.detach())
        if value < best_loss:
            best, best_loss = theta.detach().numpy().copy(), value
        record(theta.detach().numpy(), value)
        opt.step()
        with torch.no_grad():
            theta.copy_(torch.clamp(theta, torch.as_tensor(model.lower), torch.as_tensor(model.upper)))
    return best, f"{iterations} Adam steps"

