"""One law fitted to every speed at once: the readings of all windows compared with one simulated fluid.

A single speed probes a narrow band of shear rates, so Carreau's and Cross's λ and η_∞ stay unidentifiable
(docs/identification.md); the windows of several speeds together span the band where the law bends. Each law
starts from its fit to the per-speed apparent viscosities (``rheology.fit_flow_curve`` on (γ̇_i, η_i γ̇_i) with
weights 1/σ_i²; with no more points than parameters, from ``identify.initial.initial_model``) and takes a few
Gauss-Newton steps through the simulator (``identify.fit_model``) on the readings of all windows. Uncertainty and
selection are those of ``identify``: the Laplace covariance with N_eff, BIC with the best fit's N_eff.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor, nn

from ..identify import FitModel, FitResult, StirProblem, Windows
from ..identify.jobs import FitJob
from ..identify.initial import initial_model
from ..identify.nuisance import NO_NUISANCE
from ..identify.selection import bic, rank
from ..identify.uncertainty import Uncertainty, laplace
from ..mpm import SimConfig
from ..parallel import Workers
from ..rheology import FlowCurve, fit_flow_curve
from .apparent import ViscosityPoint
from .windows import SpeedWindow


class JointProblem:
    """The windows of several recordings as one problem for ``identify.fit_model``: one simulation per recording,
    from its first sample to its last window's end, whose readings inside the windows are concatenated.

    Attributes:
        problems: one ``StirProblem`` per recording; ``masks`` its samples inside a window.
        measured: measured readings in the windows [N]; ``train`` all True (nothing is held out).
        recording: the first recording (its sensor's resolution sets the robust loss's noise floor).
        config, density: the simulation settings and the fluid's density [kg/m³] shared by every problem (the
            fit bounds a model by the simulator's limits from them).
    """

    def __init__(self, windows: list[SpeedWindow], config: SimConfig, density: float):
        by_recording: dict[int, list[SpeedWindow]] = {}
        for w in windows:
            by_recording.setdefault(id(w.recording), []).append(w)
        self.config, self.density = config, float(density)
        self.problems, self.masks = [], []
        for group in by_recording.values():
            start, end = min(w.start for w in group), max(w.end for w in group)
            problem = StirProblem(group[0].recording, config, density, Windows(start, end, end))
            self.problems.append(problem)
            self.masks.append(np.any([(problem.times > w.start) & (problem.times <= w.end) for w in group], axis=0))
        self.recording = self.problems[0].recording
        self.measured = np.concatenate([p.measured[m] for p, m in zip(self.problems, self.masks)])
        self.train = np.ones(self.measured.size, dtype=bool)

    def loss(self, predicted: np.ndarray, train: bool = True) -> float | None:
        """The paper's loss, mean |measured − predicted| [N], over every window (None for the held-out part)."""
        return float(np.mean(np.abs(self.measured - predicted))) if train else None

    def frozen(self, material: nn.Module) -> "JointProblem":
        """Each recording's problem with the sound speed ``material`` gets held fixed (``StirProblem.frozen``)."""
        joint = copy.copy(self)
        joint.problems = [p.frozen(material) for p in self.problems]
        joint.config = joint.problems[0].config
        return joint

    def simulate(self, material: nn.Module) -> Tensor:
        """Simulated readings [N] in every window, recording after recording."""
        return torch.cat([p.simulate(material)[torch.as_tensor(m)] for p, m in zip(self.problems, self.masks)])


@dataclass
class JointFit:
    """Laws fitted to all speeds: ``fits`` and ``uncertainty`` by law, ``bic``, the ``selected`` law by BIC."""

    fits: dict[str, FitResult]
    uncertainty: dict[str, Uncertainty]
    bic: dict[str, float]
    selected: str

    def summary(self) -> dict:
        laws = {name: {"params": fit.model.params_si(), "units": fit.model.units,
                       "ci95": {k: [_finite(lo), _finite(hi)] for k, (lo, hi) in self.uncertainty[name].ci95.items()},
                       "identifiable": self.uncertainty[name].identifiable, "loss": fit.loss, "bic": self.bic[name],
                       "evaluations": fit.evaluations, "seconds": fit.seconds}
                for name, fit in self.fits.items()}
        return {"selected": self.selected, "ranking": rank(self.bic), "laws": laws,
                "criterion": "bic over the readings of every window"}


def joint_fit(points: list[ViscosityPoint], shear_rates: np.ndarray, config: SimConfig, density: float,
              models: list[str], *, iterations: int = 3, workers: int = 1) -> JointFit:
    """Fit each law in ``models`` to the readings of every window of ``points``, whose effective shear rates
    [1/s] are ``shear_rates``, at once (module docstring); the laws side by side in ``workers`` processes."""
    if not models:
        raise ValueError("behaviour.joint_models is empty; name at least one law of diffstir.rheology.LAWS")
    problem = JointProblem([p.window for p in points], config, density)
    g = np.asarray(shear_rates, dtype=np.float64)
    eta = np.array([p.viscosity for p in points])
    w = 1.0 / np.array([p.total_log_std for p in points]) ** 2
    curve = FlowCurve(g, eta * g)
    middle = int(np.argsort(g)[g.size // 2])
    jobs = []
    for name in models:
        model = FitModel.named(name)  # validates the name
        if g.size > model.size:
            model = FitModel(fit_flow_curve(name, curve, weights=w / w.max()).law.float())
        else:
            model = initial_model(name, float(eta[middle]), float(g[middle]))
        jobs.append(FitJob("joint", name, problem, model, iterations, "lm", NO_NUISANCE))
    with Workers(workers, report=lambda event: None) as pool:
        fits = dict(zip(models, pool.map(jobs)))
    residuals = {n: f.predicted - problem.measured for n, f in fits.items()}
    uncertainty = {n: laplace(f.model, f.theta, f.jacobian, residuals[n]) for n, f in fits.items()}
    best = min(residuals, key=lambda n: float(residuals[n] @ residuals[n]))
    n_effective = uncertainty[best].effective_samples
    bics = {n: bic(r, fits[n].model.size, n_effective) for n, r in residuals.items()}
    return JointFit(fits, uncertainty, bics, rank(bics)[0])


def _finite(value: float) -> float | None:
    return value if np.isfinite(value) else None
