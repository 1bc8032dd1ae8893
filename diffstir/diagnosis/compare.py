"""Fitting every candidate extension and comparing them fairly.

Sensor candidates (and ``none``) are fitted on the base reading as a function of the law's viscosity scale s,
p(ln s) (``ScaleReadings``): linearised, p0 + (d p/d ln s) ln s, while |ln s| stays within ``ANCHOR_RANGE``, and
re-anchored on a simulation of the law at the fitted scale when the fit leaves it: an effect that biased the
identification, such as a dead band that took a quarter off the viscosity, is then fitted on the simulator's
reading, not on a linearisation 5 mN (1.7 noise levels) off it (docs/diagnosis.md); physics candidates
start from the base law with the extension at a typical strength (the best of several where the candidate offers
several, ``screened_start``), take a forward-difference Jacobian (k + 1 simulations) and a few trust-region
Gauss-Newton steps with Broyden updates (``diffstir.fitting.fit_model``, soft-L1 cost at the starting residuals'
scale, as the identification), and as many again at the simulator's sound speed of where they moved when it
changed (``refrozen``). Each fit gets the Laplace covariance of its
parameters with the effective sample size (``diffstir.fitting.uncertainty``).

Comparison by BIC with one effective sample size N_eff for all candidates (that of the candidate with the smallest
RSS, whose residual is closest to the noise): BIC = N_eff ln(RSS/N) + k ln N_eff, k counting the viscosity scale
and the extension's parameters, so an extra parameter must buy ln N_eff (≈ 5) of fit. Verdict, on the Kass and
Raftery (1995) scale of ΔBIC ≈ 2 ln(Bayes factor):

* ``none`` when the base law's residual passes for noise (``base.residual_test``: not both larger than the noise
  and structured), whatever the BIC: a real but immaterial effect (a millisecond of lag that a long, precise
  recording resolves) is not worth naming;
* ``none`` unless the best candidate beats the base law by ΔBIC > ``EVIDENCE`` = 10 ("very strong") and
  explains most of the mismatch: (RSS_none − RSS_best) / (RSS_none − N σ²) ≥ ``EXPLAINED`` = 1/2, the share of the
  residual's variance above the noise that the extension removes;
* ``ambiguous`` when another candidate is within ``DISTINCT`` = 6 of the best ("strong" evidence needed to
  tell two effects apart), or could be: a physics fit stopped by its budget of simulations, not by convergence,
  is judged by the lower of its BIC and the BIC of the RSS one more Gauss-Newton step promises on its last
  Jacobian (``CandidateFit.reachable_rss``), so that a candidate is not ruled out only because its fit was cut
  short (``diagnose`` first gives such contenders a second budget);
* otherwise the best candidate.

A physics fit stopped by its budget gets a second one (``second_budget``) where that could change the verdict: the
contenders above, the best with them, and the best alone when it has the evidence (ΔBIC > ``EVIDENCE``) and only
the share it explains, which a fit cut short understates, keeps it from being named.

The score of a candidate is BIC − BIC(none) (negative: the data favour the extension); its probability is the BIC
weight exp(−BIC/2) / Σ exp(−BIC/2) over the candidates.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from ..errors import SimulationError
from ..fitting import Readings, bic, bic_of_rss, effective_samples, fit_model, laplace, parameter_uncertainty
from ..parallel import Workers
from .base import residual_test, simulated_reading
from .candidates import (PHYSICS_CANDIDATES, SCALE, SENSOR_CANDIDATES, YIELD_SUMMARY, CachedReplay, Context,
                         Parametrisation, PhysicsModel, SensorCandidate, scaled_law, yield_model)

EVIDENCE = 10.0  # ΔBIC against the base law for an effect to be named
DISTINCT = 6.0   # ΔBIC between the best two for them to be told apart
EXPLAINED = 0.5  # share of the residual variance above the noise that the named effect must remove
#: How far in ln s from a simulated scale a sensor candidate's base reading is trusted [1]. At ln s = 0.19 the
#: linearised reading p0 + (d p/d ln s) ln s was off the simulation by 5 mN, about a tenth of the reading (castor
#: oil with a dead band, docs/diagnosis.md): the identification's sound speed is held fixed, the truth's follows
#: the viscosity, and the column is a Broyden secant. Within 0.05 of an anchor the reading is that simulation's to
#: first order in ln s.
ANCHOR_RANGE = 0.05
#: Simulations a sensor candidate may spend re-anchoring its base reading at the scale it fitted.
REANCHORS = 2
#: Relative change of the simulator's sound speed [1] (``SimConfig.compressibility``) beyond which a physics fit
#: goes on at the sound speed of its current parameters (``refrozen``): 1 % in c, 2 % in a viscous fit's η.
SOUND_SPEED_TOLERANCE = 0.01

NONE = SensorCandidate("none", (), lambda p, ctx, v: p, lambda ctx: [{}], "nothing (the residual is noise)")


@dataclass
class CandidateFit:
    """One candidate fitted to the recording.

    Attributes:
        name, kind: the candidate (``sensor``, ``physics``) .
        summary: what it models, in words.
        params, units, standard_error, ci95: fitted values (SI), units, standard errors and 95 % intervals (null
            for a parameter the recording does not determine, ``fitting.parameter_uncertainty``); identifiable:
            whether the recording determines each parameter; correlations: of the identifiable parameters' θ.
        law: the fluid's law after the fit (name and SI parameters).
        predicted: readings [N] at the compared samples.
        loss: mean |measured − predicted| [N]; rss: Σ (measured − predicted)² [N²].
        size: fitted parameters (viscosity scale included).
        simulations, seconds: cost of the fit.
        note: why it was not fitted (None when it was).
        warning: why the fit is less trustworthy than its interval says (None when it is not).
        theta, jacobian: the fitted θ (k,) and d predicted / d θ there [N] (M, k), to resume a fit from.
        converged: the fit stopped on its tolerances, not on its budget of simulations.
        reachable_rss: the RSS [N²] one more Gauss-Newton step promises, min ‖r − J δ‖² within the bounds
            (r the residual, J the Jacobian); the RSS itself when the fit converged.
    """

    name: str
    kind: str
    summary: str
    params: dict = field(default_factory=dict)
    units: dict = field(default_factory=dict)
    standard_error: dict = field(default_factory=dict)
    ci95: dict = field(default_factory=dict)
    identifiable: dict = field(default_factory=dict)
    correlations: dict = field(default_factory=dict)
    law: dict = field(default_factory=dict)
    predicted: np.ndarray | None = None
    loss: float = math.nan
    rss: float = math.nan
    size: int = 0
    simulations: int = 0
    seconds: float = 0.0
    note: str | None = None
    warning: str | None = None
    theta: np.ndarray | None = None
    jacobian: np.ndarray | None = None
    converged: bool = True
    reachable_rss: float = math.nan


def _law_after(law, values: dict) -> dict:
    scaled = scaled_law(law, values["viscosity_scale"])
    return {"name": scaled.name, "params": scaled.parameters_si(), "units": dict(scaled.units)}


def _finish(fit: CandidateFit, model, theta: np.ndarray, jacobian: np.ndarray, ctx: Context) -> CandidateFit:
    residual = ctx.measured - fit.predicted
    known = parameter_uncertainty(model, theta, laplace(model, theta, jacobian, -residual))  # r = predicted − measured
    fit.standard_error, fit.ci95, fit.identifiable, fit.correlations = (
        known["standard_error"], known["ci95"], known["identifiable"], known["correlations"])
    fit.loss, fit.rss = float(np.mean(np.abs(residual))), float(residual @ residual)
    fit.size = model.size
    fit.theta, fit.jacobian = np.asarray(theta, dtype=np.float64), jacobian
    fit.reachable_rss = fit.rss if fit.converged else reachable_rss(residual, jacobian, theta, model)
    return fit


def reachable_rss(residual: np.ndarray, jacobian: np.ndarray, theta: np.ndarray, model) -> float:
    """min ‖r − J δ‖² [N²] over steps δ that keep θ + δ within the model's bounds: what one more Gauss-Newton
    step on the linearised readings promises (optimistic where the readings curve)."""
    step = optimize.lsq_linear(jacobian, residual, bounds=(model.lower - theta, model.upper - theta + 1e-12))
    rest = residual - jacobian @ step.x
    return float(min(rest @ rest, residual @ residual))


class ScaleReadings:
    """The base law's reading at viscosity scale s = e^u [N], (M,), for the sensor candidates.

    Known exactly at u = 0 (p0, with slope d p/d u, ``ctx.scale_column``) and at the anchors simulated so far.
    ``model(anchor)`` is the reading used around an anchor u_a: the linearisation p0 + c u for u_a = 0, otherwise
    the quadratic through p0 with slope c at 0 and through p(u_a), p0 + c u + q u² with
    q = (p(u_a) − p0 − c u_a)/u_a²: exact at u_a, and for a Newtonian drag p0 e^u off by e^ξ u² |u − u_a| / 6.

    Args:
        ctx: the diagnosis's context.
        simulate: the base law's reading at a scale s [N] (a simulation); None: linearised only.
    """

    def __init__(self, ctx: Context, simulate: Callable[[float], np.ndarray] | None = None):
        self.ctx, self.simulate = ctx, simulate
        self.anchors: dict[float, np.ndarray] = {0.0: ctx.base_reading}
        self.simulations = 0

    def model(self, anchor: float) -> Callable[[float], np.ndarray]:
        p0, c = self.ctx.base_reading, self.ctx.scale_column
        if anchor == 0.0:
            return lambda u: p0 + c * u
        q = (self.anchors[anchor] - p0 - c * anchor) / anchor**2
        return lambda u: p0 + c * u + q * u * u

    @staticmethod
    def covers(anchor: float, u: float) -> bool:
        """Whether ``model(anchor)`` is trusted at u: within ``ANCHOR_RANGE`` of the anchor."""
        return abs(u - anchor) <= ANCHOR_RANGE

    def anchor_at(self, u: float) -> float:
        """Simulate the law at s = e^u (once per u, rounded to 1e-3) and return the anchor."""
        u = round(float(u), 3)
        if u not in self.anchors:
            self.anchors[u] = np.asarray(self.simulate(math.exp(u)), dtype=np.float64)
            self.simulations += 1
        return u


def fit_sensor(candidate: SensorCandidate, ctx: Context, readings: ScaleReadings | None = None) -> CandidateFit:
    """Fit a sensor candidate (or ``none``) and the viscosity scale on the base reading ``readings`` (default: the
    linearised one), re-anchoring it at most ``REANCHORS`` times where the fitted scale leaves its range."""
    started = time.perf_counter()
    fit = CandidateFit(candidate.name, "sensor" if candidate.params else "none", candidate.summary)
    reason = candidate.applies(ctx)
    if reason is not None:
        fit.note = reason
        return fit
    readings = readings if readings is not None else ScaleReadings(ctx)
    simulations = readings.simulations
    par = Parametrisation((SCALE,) + candidate.params)
    anchor = 0.0
    for round_ in range(REANCHORS + 1):
        base = readings.model(anchor)

        def predict(theta, base=base):
            values = par.values_of(theta)
            return candidate.reading(base(math.log(values["viscosity_scale"])), ctx, values)

        best = None
        for start in candidate.starts(ctx):
            theta0 = np.clip(par.theta_of({"viscosity_scale": 1.0, **start}), par.lower, par.upper)
            sol = optimize.least_squares(lambda t: predict(t) - ctx.measured, theta0, bounds=(par.lower, par.upper),
                                         method="trf", loss="soft_l1", f_scale=ctx.noise, x_scale="jac")
            if best is None or sol.cost < best.cost:
                best = sol
        u = math.log(par.values_of(best.x)["viscosity_scale"])
        if readings.covers(anchor, u) or readings.simulate is None or round_ == REANCHORS:
            break
        anchor = readings.anchor_at(u)
    theta = best.x
    steps = 1e-6 * np.maximum(np.abs(theta), 1e-2)
    jacobian = np.stack([(predict(theta + h * e) - predict(theta - h * e)) / (2 * h)
                         for h, e in zip(steps, np.eye(theta.size))], axis=1)
    values = par.values_of(theta)
    fit.params, fit.units, fit.predicted = values, par.units, predict(theta)
    fit.law = _law_after(ctx.law, values)
    fit.simulations = readings.simulations - simulations
    fit.seconds = time.perf_counter() - started
    if not readings.covers(anchor, u):
        fit.warning = (f"the viscosity scale {values['viscosity_scale']:.3g} is outside the range where the base "
                       f"reading is known (ln s within {ANCHOR_RANGE} of a simulated scale); refit the law "
                       "(identification) and diagnose again")
    return _finish(fit, par, theta, jacobian, ctx)


def fit_physics(name: str, ctx: Context, problem, *, max_iterations: int,
                resume: CandidateFit | None = None) -> CandidateFit:
    """Fit a physics candidate (``PHYSICS_CANDIDATES`` or ``yield_stress``) through the simulator; with
    ``resume`` (an earlier fit of the same candidate), go on from its θ and Jacobian with ``max_iterations`` more
    evaluations."""
    started = time.perf_counter()
    if name == "yield_stress":
        model = yield_model(ctx.law, ctx)
        fit, starts = CandidateFit(name, "physics", YIELD_SUMMARY), []
        if model is None:
            fit.note = f"the base law ({ctx.law.name}) already has a yield stress"
            return fit
    else:
        candidate = PHYSICS_CANDIDATES[name]
        model = PhysicsModel(candidate, ctx.law, ctx)
        fit, starts = CandidateFit(name, "physics", candidate.summary), candidate.starts(ctx.law, ctx)
    if resume is not None:
        model.set_theta(resume.theta)
    replay = CachedReplay(problem.frozen(model.material), model)  # its Jacobian and fit share one sound speed
    if resume is None:
        if len(starts) > 1:
            model.set_theta(screened_start(Readings(replay, model), [model.theta_of(v) for v in starts],
                                           ctx.measured, model.lower[0], model.upper[0]))
            replay = refrozen(replay, problem, model)
        jacobian0 = Readings(replay, model).jacobian(model.theta())
    else:
        jacobian0 = resume.jacobian
    result = fit_model(replay, model, max_iterations=max_iterations, initial_jacobian=jacobian0)
    moved = refrozen(replay, problem, model)
    if moved is not replay:  # the fit left its sound speed's tolerance: go on at the sound speed of where it is
        result = fit_model(moved, model, max_iterations=max_iterations, initial_jacobian=result.jacobian)
        replay = moved
    values = model.params_si()
    fit.params, fit.units, fit.predicted = values, dict(model.units), result.predicted
    if name == "yield_stress":
        fit.law = {"name": model.name, "params": values, "units": dict(model.units)}
    else:
        fit.law = _law_after(ctx.law, values)
    fit.simulations = replay.simulations + (0 if resume is None else resume.simulations)
    fit.seconds = time.perf_counter() - started + (0.0 if resume is None else resume.seconds)
    fit.converged = result.converged
    return _finish(fit, model, result.theta, result.jacobian, ctx)


def refrozen(replay: CachedReplay, problem, model) -> CachedReplay:
    """``replay``, or a new one frozen at the sound speed of ``model``'s current material where that differs from
    ``replay``'s by more than ``SOUND_SPEED_TOLERANCE`` (``StirProblem.frozen``): the simulator raises c with the
    viscosity (c ∝ √η when viscous), and a reading simulated at another viscosity's c is off by a structured
    residual (castor oil's concealed slip at its truth: 2.54 mN of loss at its own c, 3.11 mN at the c of the
    identified viscosity, 13 % lower, so c 7 % lower; docs/diagnosis.md)."""
    frozen = problem.frozen(model.material)
    if abs(frozen.config.fixed_sound_speed / replay.problem.config.fixed_sound_speed - 1.0) <= SOUND_SPEED_TOLERANCE:
        return replay
    return CachedReplay(frozen, model, replay.simulations)


def screened_start(readings: Callable[[np.ndarray], np.ndarray], starts: list[np.ndarray], measured: np.ndarray,
                   lower: float, upper: float) -> np.ndarray:
    """The best of a physics candidate's starts θ (θ[0] = ln s, the viscosity scale): each simulated once
    (``readings(θ)`` [N]) and rescaled as if its reading were proportional to s, as a Stokes drag is, by the
    least-squares factor c = ⟨m, p⟩ / ⟨p, p⟩ on the measured readings m [N] (ln s + ln c clipped to
    [``lower``, ``upper``]); the one of least Σ (m − c p)² wins, with its rescaled θ."""
    best, best_rss = None, math.inf
    for theta in starts:
        reading = readings(theta)
        norm = float(reading @ reading)
        if not np.isfinite(reading).all() or norm == 0.0:
            continue
        factor = float(measured @ reading) / norm
        log_scale = float(np.clip(theta[0] + math.log(factor), lower, upper)) if factor > 0 else theta[0]
        factor = math.exp(log_scale - theta[0])
        rest = measured - factor * reading
        if rest @ rest < best_rss:
            best, best_rss = np.concatenate([[log_scale], theta[1:]]), float(rest @ rest)
    if best is None:
        raise SimulationError("diagnose: no start of the physics candidate simulates (each became non-finite or "
                              "read no force); try a smaller sim.cfl or sim.viscous_safety")
    return best


@dataclass
class PhysicsJob:
    """A physics candidate's fit (``fit_physics``) as a job for ``diffstir.parallel.Workers``; ``key`` is its name."""

    key: str
    ctx: Context
    problem: object
    max_iterations: int
    resume: CandidateFit | None = None
    stage: str = "diagnose"
    priority: tuple = (False, 1)

    def run(self, report) -> CandidateFit:
        return fit_physics(self.key, self.ctx, self.problem, max_iterations=self.max_iterations, resume=self.resume)


def fit_candidates(names: list[str], ctx: Context, problem, *, max_iterations: int = 3, on_fit=None,
                   workers: int = 1, resume: dict[str, CandidateFit] | None = None) -> dict[str, CandidateFit]:
    """Fit every named candidate, in ``names``' order; ``on_fit(fit)`` is called after each. The physics
    candidates, each a few simulations, run side by side in ``workers`` processes; with ``resume`` (earlier fits
    by name) a physics candidate goes on from its earlier fit (``fit_physics``)."""
    fits = {}
    readings = ScaleReadings(ctx, lambda s: simulated_reading(problem, scaled_law(ctx.law, s)))
    for name in names:
        if name == "none":
            fits[name] = fit_sensor(NONE, ctx, readings)
        elif name in SENSOR_CANDIDATES:
            fits[name] = fit_sensor(SENSOR_CANDIDATES[name], ctx, readings)
        else:
            continue
        if on_fit is not None:
            on_fit(fits[name])
    physics = [PhysicsJob(name, ctx, problem, max_iterations, (resume or {}).get(name))
               for name in names if name not in fits]
    with Workers(workers, report=lambda event: None) as pool:
        for job in physics:
            pool.submit(job)
        for job, fit in pool.completed():
            fits[job.key] = fit
            if on_fit is not None:
                on_fit(fit)
    return {name: fits[name] for name in names}


def second_budget(fits: dict[str, CandidateFit], verdict: str, evidence: dict) -> list[str]:
    """The physics candidates whose fits, cut short by their budget, get a second one before the verdict is final
    (``evidence`` and ``verdict`` as ``rank`` gives them): the contenders a further step could bring within
    ``DISTINCT`` of the best, and the best when contended, or when it is unconverged with ΔBIC > ``EVIDENCE``
    and explains less than ``EXPLAINED`` of the mismatch, the only rule that keeps it from being named."""
    best = evidence["best"]
    contenders = list(evidence["unconverged_contenders"]) if verdict != "none" else []
    short = fits[best].kind == "physics" and not fits[best].converged
    immaterial_only = (verdict == "none" and evidence["residual_test"]["needed"]
                       and evidence["gain_over_none"] > EVIDENCE and evidence["explained"] < EXPLAINED)
    return contenders + ([best] if short and (contenders or immaterial_only) else [])


def rank(fits: dict[str, CandidateFit], measured: np.ndarray, noise: float) -> tuple[list[dict], str, dict]:
    """The ranking (best first), the verdict and the evidence behind it (see the module docstring), for fits to
    the readings ``measured`` [N] of noise level ``noise`` [N]."""
    fitted = {k: f for k, f in fits.items() if f.note is None}
    best_rss = min(fitted, key=lambda k: fitted[k].rss)
    n_eff = effective_samples(measured - fitted[best_rss].predicted)
    bics = {k: bic(measured - f.predicted, f.size, n_eff) for k, f in fitted.items()}
    reachable = {k: min(bics[k], bic_of_rss(f.reachable_rss, measured.size, f.size, n_eff))
                 for k, f in fitted.items()}
    lowest = min(bics.values())
    weights = {k: math.exp(-(b - lowest) / 2) for k, b in bics.items()}
    total = sum(weights.values())
    order = sorted(fitted, key=lambda k: bics[k])
    none_loss = fitted["none"].loss
    ranking = [{"effect": k, "score": bics[k] - bics["none"], "bic": bics[k], "probability": weights[k] / total,
                "params": fitted[k].params, "units": fitted[k].units, "standard_error": fitted[k].standard_error,
                "ci95": fitted[k].ci95, "identifiable": fitted[k].identifiable,
                "correlations": fitted[k].correlations, "law": fitted[k].law,
                "loss_before": none_loss, "loss_after": fitted[k].loss, "parameters": fitted[k].size,
                "simulations": fitted[k].simulations, "seconds": fitted[k].seconds, "warning": fitted[k].warning,
                "converged": fitted[k].converged, "reachable_score": reachable[k] - bics["none"]}
               for k in order]
    ranking += [{"effect": k, "score": None, "note": f.note} for k, f in fits.items() if f.note is not None]
    best = order[0]
    runner = next((k for k in order[1:] if k != "none"), None)
    gain = bics["none"] - bics[best]
    separation = bics[runner] - bics[best] if runner is not None else math.inf
    # within DISTINCT of the best, or could be: a fit cut short whose next step promises that much
    tied = [k for k in order if k != "none" and reachable[k] - bics[best] < DISTINCT]
    contenders = [k for k in tied if k != best and bics[k] - bics[best] >= DISTINCT]
    test = residual_test(measured - fitted["none"].predicted, noise)
    excess = fitted["none"].rss - measured.size * noise**2
    explained = (fitted["none"].rss - fitted[best].rss) / excess if excess > 0 else 0.0
    if not test["needed"] or best == "none" or gain <= EVIDENCE or explained < EXPLAINED:
        verdict = "none"
    elif len(tied) > 1:
        verdict = "ambiguous"
    else:
        verdict = best
    evidence = {"best": best, "runner_up": runner, "gain_over_none": gain, "separation": separation,
                "explained": explained, "effective_samples": n_eff, "residual_test": test,
                "thresholds": {"evidence": EVIDENCE, "distinct": DISTINCT, "explained": EXPLAINED},
                "tied": tied if verdict == "ambiguous" else [],
                "unconverged_contenders": {k: reachable[k] - bics[best] for k in contenders}}
    return ranking, verdict, evidence

