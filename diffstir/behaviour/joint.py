"""One law fitted to every speed at once: the readings of all windows compared with one simulated fluid.

A single speed probes a narrow band of shear rates, so Carreau's and Cross's λ and η_∞ stay unidentifiable
(docs/identification.md); the windows of several speeds together span the band where the law bends. Each law starts
from its fit to the per-speed apparent viscosities (``rheology.fit_flow_curve`` on (γ̇_i, η_i γ̇_i) with weights
1/σ_i²; with no more points than parameters, from ``fitting.initial.initial_model``), or from that curve with its
index n shifted by ``INDEX_SHIFTS`` (``index_starts``), whichever reads the windows closest after scaling its
stress (``screened_starts``), and takes a few Gauss-Newton steps through the simulator (``fitting.fit_model``) on
the readings of all windows. The points' slope is bent by the fitting grid's error at the slow speeds, and the
finite-difference Jacobian through the fast windows' jitter is too noisy to walk far from it: on the 5 mm grid the
power law of the n = 1.1 thickener and of castor oil stopped within 0.03 of the points' index, 0.13 and 0.1 short of
the truth, whose own law read the windows closer (docs/accuracy.md). A law with a yield stress also
starts as a paste (``paste_start``: a share ``PASTE_SHARES`` of the lowest speed's stress is yield stress), and the
start with the lower loss is kept, as ``identify`` does: the per-speed points of a yield-stress fluid barely bend
(``classify``), so their flow curve starts the yield stress near zero, where its logarithmic parameter hardly moves
the readings. The paste's stresses are those of the best joint fit without a yield stress, once it is done, else
the points': the points are Newtonian equivalents, which put a paste's stress at the fastest speed too high. The
pastes and the points' own flow curve are screened (``screened_starts``): each simulated once, its stress scaled by
the least-squares amplitude of its readings on the measured ones, and the one that then reads closest kept. Where
the fitting grid reads every law 20-25 % high, as the 5 mm grid does at 0.3-0.6 m/s, the right shape at the wrong
scale otherwise reads worse than a wrong shape at the right one (docs/accuracy.md). A law with a yield stress
also starts from that best liquid fit itself, with a yield stress of ``TRACE_YIELD_SHARE`` of its lowest stress
(``LIQUID_START_ITERATIONS`` steps): a law that contains the liquid law then ends no worse than it, so that BIC,
not the optimiser, decides whether the yield stress is worth its parameter (on glycerol the Herschel-Bulkley fit
from the other two starts ended at 7.4 mN where the power law reached 5.5, docs/accuracy.md). Each law's best
start then takes ``POLISH_ITERATIONS`` more steps from a fresh Jacobian. Every fit, screen and comparison weighs
each window's residuals by its own scale (``JointProblem``). Uncertainty and selection are those of ``identify`` on
the weighted residuals: the Laplace covariance with N_eff plus the simulator's force error σ_m as an amplitude
error of each window, independent between windows (the power law's index with this interval is the slope test's
second read, ``classify``), and BIC with the best fit's N_eff.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
import torch
from torch import Tensor, nn

from ..fitting import (NO_NUISANCE, YIELD_SHARES, FitJob, FitModel, FitResult, ReadingJob, SpeedWindow, StirProblem,
                       Uncertainty, ViscosityPoint, Windows, bic, fit_simulations, initial_model, laplace,
                       parameter_summary, rank)
from ..mpm import SimConfig
from ..parallel import Workers
from ..rheology import FlowCurve, fit_flow_curve, has_yield_stress, within_bounds

#: Gauss-Newton iterations of each law's best start from a fresh finite-difference Jacobian, after its budget.
#: The Broyden updates that carry the first Jacobian through the budget converge slowly, and laws compared by BIC
#: must each be at its optimum: a power law still short of the noise floor loses to a Herschel-Bulkley fit, one
#: parameter freer, that has reached it, and a power-law fluid reads as a yield stress.
POLISH_ITERATIONS = 2

#: Shifts of a law's index n [1] in its first start screen (``index_starts``): the size by which the 5 mm grid's
#: joint power-law fits stopped short of the truth's index (module docstring), within the trust region's first
#: reach in an index (``fitting.optimise.TRUST_RADIUS``, 0.25).
INDEX_SHIFTS = (-0.15, 0.15)

#: Shares of the lowest speed's stress that a yield-stress law's paste starts give its yield stress [1]: a paste
#: whose flow adds as much again as its yield stress, and a nearly plastic one. Over a factor 8 of shear rate a
#: plastic's stress is nearly flat, and the half-yield start splits it into a yield stress and a low index, far from
#: a plastic's τ_y and n = 1; on readings of a Bingham plastic the nearly plastic start reads closer. Each start
#: costs one simulation; the best of them, stress-scaled, is fitted (``screened_starts``).
PASTE_SHARES = (0.5, 0.9)

#: The yield stress of the start taken from the best liquid fit, as a share of its stress at the lowest speed [1]:
#: small enough that the start reads as the liquid law does, large enough that the logarithmic τ_y still moves the
#: readings when the data ask for it.
TRACE_YIELD_SHARE = 0.01

#: Gauss-Newton iterations of that start: it begins at the liquid law's optimum, so one step says whether the yield
#: stress lowers the loss from there.
LIQUID_START_ITERATIONS = 1


class JointProblem:
    """The windows of several recordings as one problem for ``fitting.fit_model`` (a ``fitting.FitProblem``):
    one simulation per recording, from its first sample to its last window's end, whose readings inside the windows
    are concatenated.

    Each window's residuals count in units of their own scale s_w [N] (``window_scales``; default: all alike):
    the fit minimises Σ_w Σ_i (r_i / s_w)² (robustly), a Gaussian likelihood with a variance per window known up
    to one common factor. The joint fit takes s_w as the misfit of the window's own Newtonian fit
    (``ViscosityPoint.loss``), what a free viscosity per speed leaves and no flow curve can remove: at the fast
    speeds that is mostly the simulation's jitter, readings that move by tens of percent of their misfit when the
    sound speed moves by 0.5 % (docs/accuracy.md), which with one variance for all windows outweighed the slow
    windows, where the laws differ, and decided the law by chance.

    Attributes:
        problems: one ``StirProblem`` per recording; ``masks`` its samples inside a window.
        measured: measured readings in the windows [N]; ``train`` all True (nothing is held out).
        times: their times [s], each on its own recording's clock, recording after recording.
        weights: each sample's weight min_w s_w / s_w [1] (at most 1: the best-fitted window's residuals stay in
            newtons, so the robust cost's noise floor keeps its meaning).
        window_labels: each sample's window, its place in ``windows``.
        recording: the first recording (its sensor's resolution sets the robust loss's noise floor).
        config, density: the simulation settings and the fluid's density [kg/m³] shared by every problem (the
            fit bounds a model by the simulator's limits from them).
    """

    def __init__(self, windows: list[SpeedWindow], config: SimConfig, density: float,
                 window_scales: list[float] | None = None):
        scales = np.ones(len(windows)) if window_scales is None else np.asarray(window_scales, dtype=np.float64)
        if scales.shape != (len(windows),) or not (np.isfinite(scales).all() and (scales > 0).all()):
            raise ValueError(f"behaviour: window scales {scales.tolist()} for {len(windows)} windows; expected one "
                             "misfit > 0 in N per window")
        by_recording: dict[int, list[int]] = {}
        for k, w in enumerate(windows):
            by_recording.setdefault(id(w.recording), []).append(k)
        self.config, self.density = config, float(density)
        self.problems, self.masks, sample_scales, labels = [], [], [], []
        for group in by_recording.values():
            start, end = min(windows[k].start for k in group), max(windows[k].end for k in group)
            problem = StirProblem(windows[group[0]].recording, config, density, Windows(start, end, end))
            inside = np.array([(problem.times > windows[k].start) & (problem.times <= windows[k].end) for k in group])
            mask = inside.any(axis=0)
            self.problems.append(problem)
            self.masks.append(mask)
            sample_scales.append((scales[group] @ inside)[mask])  # windows do not overlap
            labels.append(np.asarray(group)[inside.argmax(axis=0)][mask])
        self.recording = self.problems[0].recording
        self.measured = np.concatenate([p.measured[m] for p, m in zip(self.problems, self.masks)])
        self.times = np.concatenate([p.times[m] for p, m in zip(self.problems, self.masks)])
        self.train = np.ones(self.measured.size, dtype=bool)
        self.weights = scales.min() / np.concatenate(sample_scales)
        self.window_labels = np.concatenate(labels)

    def loss(self, predicted: np.ndarray, train: bool = True) -> float | None:
        """The paper's loss, mean |measured − predicted| [N], over every window (None for the held-out part)."""
        return float(np.mean(np.abs(self.measured - predicted))) if train else None

    def cost(self, predicted: np.ndarray) -> float:
        """The rms of the weighted residuals, sqrt(mean (w (measured − predicted))²) [N]: what the fit minimises
        and the laws are compared on."""
        return float(np.sqrt(np.mean((self.weights * (self.measured - predicted)) ** 2)))

    def frozen(self, material: nn.Module) -> "JointProblem":
        """Each recording's problem with the sound speed ``material`` gets held fixed (``StirProblem.frozen``)."""
        joint = copy.copy(self)
        joint.problems = [p.frozen(material) for p in self.problems]
        joint.config = joint.problems[0].config
        return joint

    def slice_sigma(self, material: nn.Module) -> float:
        """The largest relative 1-σ uncertainty [1] of the slice corrections (``StirProblem.slice_correction``)
        of the recordings' problems for ``material``; 0 in 3-D."""
        corrections = [p.slice_correction(material) for p in self.problems]
        return max((c.sigma for c in corrections if c is not None), default=0.0)

    def simulate(self, material: nn.Module) -> Tensor:
        """Simulated readings [N] in every window, recording after recording."""
        return torch.cat([p.simulate(material)[torch.as_tensor(m)] for p, m in zip(self.problems, self.masks)])


@dataclass
class JointFit:
    """Laws fitted to all speeds: ``fits`` and ``uncertainty`` by law, ``bic``, the ``selected`` law by BIC, and
    each law's ``cost`` [N], the rms of its weighted residuals (``JointProblem.cost``)."""

    fits: dict[str, FitResult]
    uncertainty: dict[str, Uncertainty]
    bic: dict[str, float]
    selected: str
    cost: dict[str, float]

    def summary(self) -> dict:
        laws = {name: {**parameter_summary(fit.model, fit.theta, self.uncertainty[name]), "loss": fit.loss,
                       "weighted_rms": self.cost[name], "bic": self.bic[name],
                       "evaluations": fit.evaluations, "seconds": fit.seconds}
                for name, fit in self.fits.items()}
        return {"selected": self.selected, "ranking": rank(self.bic), "laws": laws,
                "criterion": "bic over the readings of every window, each window's residuals in units of its own "
                             "Newtonian fit's loss (weighted_rms [N]: the rms of the weighted residuals)"}

    def power_law_slope(self) -> tuple[float, float] | None:
        """The power law's slope d ln η / d ln γ̇ = n − 1 [1] and the standard error of n [1] (its Laplace
        covariance, ``joint_fit``), or None where the power law was not fitted."""
        if "power_law" not in self.fits:
            return None
        fit = self.fits["power_law"]
        j = fit.model.names.index("n")
        std = float(np.sqrt(self.uncertainty["power_law"].covariance[j, j]))
        return float(fit.model.si_of_theta(fit.theta)[j]) - 1.0, std

    def yield_shares(self, shear_rate: float) -> dict[str, float]:
        """Each yield-stress law's share of its stress at ``shear_rate`` [1/s] carried by its yield stress,
        τ_y / (η(γ̇) γ̇) [1]."""
        shares = {}
        for name, fit in self.fits.items():
            if has_yield_stress(name):
                shares[name] = yield_share(fit.model, shear_rate, fit.theta)
        return shares


def yield_share(model: FitModel, shear_rate: float, theta: np.ndarray | None = None) -> float:
    """The share of a yield-stress law's stress at ``shear_rate`` [1/s] carried by its yield stress,
    τ_y / (η(γ̇) γ̇) [1], at θ (default: the model's current parameters)."""
    theta = model.theta() if theta is None else theta
    eta, _ = model.viscosity(np.array([shear_rate]), theta)
    tau_y = model.si_of_theta(theta)[model.names.index("tau_y")]
    return float(tau_y / (eta[0] * shear_rate))


def joint_simulations(name: str, iterations: int) -> int:
    """The joint simulations (each one of every recording) ``joint_fit`` is expected to spend on law ``name``
    with ``iterations``: its start screen (``index_starts``), its first fit, for a yield-stress law the paste
    screen, the paste's fit and the start from the best liquid fit, and the polish."""
    model = FitModel.named(name)
    count = (1 + len(INDEX_SHIFTS) if "n" in model.names else 1) + fit_simulations(model.size, iterations, 2)
    if has_yield_stress(name):
        count += (len(PASTE_SHARES) + 1 + fit_simulations(model.size, iterations, 2)
                  + fit_simulations(model.size, LIQUID_START_ITERATIONS, 2))
    return count + fit_simulations(model.size, POLISH_ITERATIONS, 2)


def joint_fit(points: list[ViscosityPoint], shear_rates: np.ndarray, config: SimConfig, density: float,
              models: list[str], *, iterations: int = 5, workers: int = 1, model_error: float = 0.0,
              inertial_error: float = 0.0, report: Callable[[tuple], None] | None = None) -> JointFit:
    """Fit each law in ``models`` to the readings of every window of ``points``, whose effective shear rates
    [1/s] are ``shear_rates``, at once (module docstring); the laws side by side in ``workers`` processes. Each
    law's covariance holds the simulator's relative force error ``model_error`` σ_m as an error of each window's
    amplitude and ``inertial_error`` σ_i as one of its inertial part, independent between windows, as the points'
    intervals do (``fitting.uncertainty.laplace``).
    ``report`` receives the fits' events (``fitting.jobs``), whose keys start with the law's name."""
    if not models:
        raise ValueError("behaviour.joint_models is empty; name at least one law of diffstir.rheology.LAWS")
    problem = JointProblem([p.window for p in points], config, density, [p.loss for p in points])
    g = np.asarray(shear_rates, dtype=np.float64)
    eta = np.array([p.viscosity for p in points])
    w = 1.0 / np.array([p.total_log_std for p in points]) ** 2
    curve = FlowCurve(g, eta * g)
    middle = int(np.argsort(g)[g.size // 2])
    points_start = {}
    for name in models:
        model = FitModel.named(name)  # validates the name
        if g.size > model.size:
            model = FitModel(fit_flow_curve(name, curve, weights=w / w.max()).law.float())
        else:
            model = initial_model(name, float(eta[middle]), float(g[middle]), yield_share=YIELD_SHARES[-1])
        points_start[name] = model
    pivot = float(np.exp(np.mean(np.log(g))))
    with Workers(workers, report=report or (lambda event: None)) as pool:
        starts = screened_starts(pool, problem, {name: index_starts(model, pivot)
                                                 for name, model in points_start.items()})
        # a copy: a fit in this process moves its model, and a screen that kept no start returns the points' own
        first = [FitJob("joint", f"{name}/start0", problem, starts[name].model.copy(), iterations, "lm",
                        NO_NUISANCE) for name in models]
        best = {job.model.name: fit for job, fit in zip(first, pool.map(first))}
        liquid = _stress_reference(problem, best, g)
        reference = curve if liquid is None else liquid
        yielding = [name for name in models if has_yield_stress(name)]
        candidates = {name: {**{f"paste{share:g}": paste_start(name, reference, share) for share in PASTE_SHARES},
                             "points": points_start[name]} for name in yielding}
        pastes = [FitJob("joint", f"{name}/start1", problem, screened.model, iterations, "lm", NO_NUISANCE)
                  for name, screened in screened_starts(pool, problem, candidates).items()]
        if liquid is not None:
            pastes += [FitJob("joint", f"{name}/start2", problem, paste_start(name, liquid, TRACE_YIELD_SHARE),
                              LIQUID_START_ITERATIONS, "lm", NO_NUISANCE) for name in yielding]
        for job, fit in zip(pastes, pool.map(pastes)):
            if problem.cost(fit.predicted) < problem.cost(best[job.model.name].predicted):
                best[job.model.name] = fit
        polish = [FitJob("joint-polish", name, problem, fit.model, POLISH_ITERATIONS, "lm", NO_NUISANCE)
                  for name, fit in best.items()]
        fits = {job.key: replace(fit, history=best[job.key].history + fit.history, seconds=best[job.key].seconds
                                 + fit.seconds, evaluations=best[job.key].evaluations + fit.evaluations)
                for job, fit in zip(polish, pool.map(polish))}
    weights = problem.weights
    residuals = {n: weights * (f.predicted - problem.measured) for n, f in fits.items()}
    uncertainty = {n: laplace(f.model, f.theta, weights[:, None] * f.jacobian, residuals[n],
                              readings=weights * f.predicted,
                              model_error=math.hypot(model_error, problem.slice_sigma(f.model.material)),
                              windows=problem.window_labels,
                              viscous_readings=weights * (f.jacobian @ f.model.stress_direction()),
                              inertial_error=inertial_error) for n, f in fits.items()}
    best = min(residuals, key=lambda n: float(residuals[n] @ residuals[n]))
    n_effective = uncertainty[best].effective_samples
    bics = {n: bic(r, fits[n].model.size, n_effective) for n, r in residuals.items()}
    return JointFit(fits, uncertainty, bics, rank(bics)[0], {n: problem.cost(f.predicted) for n, f in fits.items()})


def index_starts(model: FitModel, shear_rate: float) -> dict[str, FitModel]:
    """``model`` (label ``points``) and, for a law with an index n, the law with n shifted by each of
    ``INDEX_SHIFTS`` (clipped to its bounds; label ``n+0.15`` ...), its stress at ``shear_rate`` [1/s] kept. A shift
    that leaves no positive viscosity there (a Carreau curve with η∞ above η0, whose viscosity the shift drives
    to its floor of 0) gives no start."""
    starts = {"points": model}
    if "n" not in model.names:
        return starts
    params = model.params_si()
    rate = np.array([shear_rate])
    eta = float(model.viscosity(rate)[0][0])
    for shift in INDEX_SHIFTS:
        shifted = FitModel.named(model.name, **within_bounds(model.name, {**params, "n": params["n"] + shift}))
        eta_shifted = float(shifted.viscosity(rate)[0][0])
        if eta > 0 and eta_shifted > 0 and math.isfinite(eta / eta_shifted):
            starts[f"n{shift:+g}"] = shifted.stress_scaled(eta / eta_shifted)
    return starts


def paste_start(name: str, curve: FlowCurve, yield_share: float = 0.5) -> FitModel:
    """A yield-stress law ``name`` started as a paste from the flow curve ``curve``: τ_y the share ``yield_share``
    [1] of the stress at the lowest shear rate, the rest of each point's stress (at least a tenth of it)
    τ_i − τ_y = k γ̇_iⁿ by least squares in logarithms, or for Bingham's law η_p γ̇_i [SI]."""
    if not 0.0 < yield_share < 1.0:
        raise ValueError(f"yield_share must lie in (0, 1), got {yield_share}")
    order = np.argsort(curve.shear_rate)
    rate, stress = curve.shear_rate[order], curve.stress[order]
    tau_y = yield_share * float(stress[0])
    excess = np.maximum(stress - tau_y, 0.1 * stress)
    if name == "bingham":
        params = {"tau_y": tau_y, "eta_p": float(np.exp(np.mean(np.log(excess / rate))))}
    else:
        n, log_k = np.polyfit(np.log(rate), np.log(excess), 1)
        params = {"tau_y": tau_y, "k": float(np.exp(log_k)), "n": float(n)}
    return FitModel.named(name, **within_bounds(name, params))


@dataclass(frozen=True)
class ScreenedStart:
    """The start a screen kept: its ``label``, the ``amplitude`` c [1] its stress was scaled by, the weighted rms
    residual [N] of the scaled readings c p (``JointProblem.cost``), and the scaled ``model``."""

    label: str
    amplitude: float
    rms: float
    model: FitModel


def screened_starts(pool: Workers, problem: JointProblem,
                    candidates: dict[str, dict[str, FitModel]]) -> dict[str, ScreenedStart]:
    """Each law's best start among its ``candidates`` (law name → label → model): each simulated once on
    ``problem`` (side by side in ``pool``), read as if its readings p scaled with its stress, as a viscous drag's
    do, by the weighted least-squares amplitude c = ⟨w m, w p⟩ / ⟨w p, w p⟩ on the measured readings m (w the
    problem's ``weights``), and kept where Σ w² (m − c p)² is least, its stress scaled by c
    (``FitModel.stress_scaled``). A candidate whose simulation fails is passed
    over; a law all of whose candidates fail keeps its first, unscaled."""
    jobs = [(name, label, model) for name, starts in candidates.items() for label, model in starts.items()]
    readings = pool.map([ReadingJob("joint", f"{name}/{label}", problem, model) for name, label, model in jobs])
    measured, w = problem.measured, problem.weights
    best: dict[str, ScreenedStart] = {}
    for (name, label, model), p in zip(jobs, readings):
        norm = float((w * p) @ (w * p))
        if not (np.isfinite(p).all() and norm > 0):
            continue
        c = float((w * p) @ (w * measured)) / norm
        if not c > 0:
            continue
        rms = problem.cost(c * p)
        if name not in best or rms < best[name].rms:
            best[name] = ScreenedStart(label, c, rms, model.stress_scaled(c))
    for name, starts in candidates.items():
        if name not in best:
            label, model = next(iter(starts.items()))
            best[name] = ScreenedStart(label, 1.0, float("nan"), model)
    return best


def _stress_reference(problem: JointProblem, fits: dict[str, FitResult], shear_rate: np.ndarray) -> FlowCurve | None:
    """The stress η γ̇ [Pa] at ``shear_rate`` [1/s] of the law without a yield stress among ``fits`` that fits
    ``problem`` best (None if there is none): what the readings of every speed say the stress is, where the
    per-speed points are Newtonian equivalents."""
    liquids = {name: fit for name, fit in fits.items() if not has_yield_stress(name)}
    if not liquids:
        return None
    fit = min(liquids.values(), key=lambda f: problem.cost(f.predicted))
    eta, _ = fit.model.viscosity(shear_rate, fit.theta)
    return FlowCurve(shear_rate, eta * shear_rate)
