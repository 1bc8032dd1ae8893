"""The result of identifying a recording: every law's fit, its uncertainty, the selection; a ``Report`` (its
JSON ``summary()``, markdown ``report()`` and plots, ``fitting.report``)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..recording import Recording
from ..report_files import Report, interval_summary
from ..slice_correction import MOVING_SHARE
from .family import law_family
from .models import FitModel
from .nuisance import UNITS
from .optimise import FitResult
from .parameters import ParameterSet
from .problem import StirProblem
from .report import markdown, plot_all
from .selection import averaged_interval, bic_weights
from .uncertainty import Uncertainty, log_viscosity_interval


def parameter_uncertainty(model: ParameterSet, theta: np.ndarray, uncertainty: Uncertainty) -> dict:
    """How well a fitted parameter set is known, SI by name, as a report states it: ``standard_error`` (the delta
    method's, value × σ_θ for a log-scaled parameter, σ_θ for an index), ``ci95`` ([lower, upper], an open end
    null), ``identifiable`` and ``at_bound``; a parameter the recording does not determine has null standard error
    and interval, whatever numbers the covariance holds. ``correlations``: the correlation coefficients of the
    identifiable parameters' θ (log values of log-scaled ones), by pair, [1]."""
    values = model.si_of_theta(theta)
    se_theta = np.sqrt(np.diag(uncertainty.covariance))
    identifiable = uncertainty.identifiable
    standard_error = {name: (float(se_theta[j] * (values[j] if scale == "log" else 1.0))
                             if identifiable[name] else None)
                      for j, (name, scale) in enumerate(zip(model.names, model.scales))}
    seen = [j for j, name in enumerate(model.names) if identifiable[name]]
    correlations = {model.names[j]: {model.names[i]: float(uncertainty.covariance[j, i] / se_theta[j] / se_theta[i])
                                     for i in seen if i != j} for j in seen}
    return {"standard_error": standard_error, "ci95": interval_summary(uncertainty.ci95, identifiable),
            "identifiable": dict(identifiable), "at_bound": dict(uncertainty.at_bound), "correlations": correlations}


def parameter_summary(model: FitModel, theta: np.ndarray, uncertainty: Uncertainty) -> dict:
    """A fitted model's parameters as a report states them: ``params`` (SI values), ``units`` and
    ``parameter_uncertainty``'s standard errors, intervals, flags and correlations."""
    return {"params": model.params_si(), "units": dict(model.units),
            **parameter_uncertainty(model, theta, uncertainty)}


@dataclass
class Identification(Report):
    """Everything :func:`identify` found: ``summary()`` (report.json), ``report()`` (report.md), ``plots(out)``
    (forces.png, flow_curves.png, losses.png), ``write(out)`` all of them."""

    recording: Recording
    problem: StirProblem
    density: dict
    fits: dict[str, FitResult]
    uncertainty: dict[str, Uncertainty]
    effective_shear_rate: float
    selection: dict
    resolvable: dict
    seconds: float
    preliminary: dict
    model_error: float = 0.0
    inertial_error: float = 0.0
    refined: dict | None = None
    magnitude: dict | None = None

    @property
    def selected(self) -> FitResult:
        return self.fits[self.selection["selected"]]

    def apparent_viscosity(self, name: str) -> dict:
        """η at zero shear and at the effective shear rate [Pa·s] with 95 % intervals, for model ``name``."""
        fit, unc = self.fits[name], self.uncertainty[name]
        eta, lo, hi = log_viscosity_interval(fit.model, fit.theta, unc.covariance, self.effective_shear_rate)
        return {"zero_shear": fit.model.zero_shear_viscosity(), "effective_shear_rate": self.effective_shear_rate,
                "at_effective_shear_rate": float(eta[0]), "at_effective_shear_rate_ci95": [float(lo[0]), float(hi[0])],
                "refined": self.refined}

    def selected_apparent_viscosity(self, apparent: dict[str, dict]) -> dict:
        """The selected law's ``apparent_viscosity`` with the selection's uncertainty in its interval: the laws'
        estimates at the effective shear rate weighted by their BIC evidence (``fitting.selection``). ``apparent``
        holds every model's ``apparent_viscosity`` by name. The selected law's own interval is kept as
        ``selected_law_ci95``, the weights as ``law_weights``. A law selected by another criterion that the BIC
        rules out very strongly keeps its own interval."""
        name = self.selection["selected"]
        own = apparent[name]
        laws = [n for n, fit in self.fits.items() if not fit.model.is_baseline]
        weights = bic_weights({n: self.selection["bic"][n] for n in laws})
        if weights[name] > 0.0:
            estimates = {n: (apparent[n]["at_effective_shear_rate"], *apparent[n]["at_effective_shear_rate_ci95"])
                         for n in laws if weights[n] > 0.0}
            lower, upper = averaged_interval(estimates, weights)
        else:  # selected by another criterion against the BIC's very strong evidence: its own interval
            lower, upper = own["at_effective_shear_rate_ci95"]
            weights = {n: float(n == name) for n in laws}
        return {**own, "at_effective_shear_rate_ci95": [float(lower), float(upper)],
                "selected_law_ci95": own["at_effective_shear_rate_ci95"],
                "law_weights": {n: w for n, w in weights.items() if w > 0.0}}

    def summary(self) -> dict:
        """The report as JSON-serialisable data (SI units; see docs/identification.md)."""
        apparent = {name: self.apparent_viscosity(name) for name in self.fits}
        laws = {}
        for name, fit in self.fits.items():
            unc = self.uncertainty[name]
            laws[name] = {
                **parameter_summary(fit.model, fit.theta, unc),
                "loss": fit.loss, "holdout_loss": fit.holdout_loss,
                "bic": self.selection["bic"][name], "residual_std": unc.residual_std,
                "effective_samples": unc.effective_samples,
                "apparent_viscosity": apparent[name],
                "evaluations": fit.evaluations, "seconds": fit.seconds, "optimizer_message": fit.message,
                "sensor": {**fit.sensor, "units": {k: UNITS[k] for k in fit.sensor}},
                "family": self.family(name),
                "slice_correction": slice_correction_summary(self.problem, fit.model.material),
            }
        laws_only = {k: v for k, v in laws.items() if k != "corotated"}
        return {
            "recording": str(self.recording.path) if self.recording.path else self.recording.name,
            "density": self.density,
            "selected": self.selection["selected"],
            "family": laws[self.selection["selected"]]["family"],
            "selection": {k: v for k, v in self.selection.items() if k != "bic"},
            "laws": laws_only,
            "baseline": laws.get("corotated"),
            "apparent_viscosity": self.selected_apparent_viscosity(apparent),
            "preliminary": self.preliminary,
            "resolvable": self.resolvable,
            "magnitude": self.magnitude,
            "windows": {"start": self.problem.windows.start, "split": self.problem.windows.split,
                        "end": self.problem.windows.end, "unit": "s"},
            "dead_start": self.problem.windows.dead_start.summary(),
            "shear_rate_range": list(self.probed_shear_rates()),
            "slice_correction": laws[self.selection["selected"]]["slice_correction"],
            "force_scale": ("3-D force" if self.problem.config.dim != 2 else
                            "F' h C" if self.problem.corrected else "F' h (fit.slice_correction=false)"),
            "simulation": {**self.problem.config.numerics(), "force_error": self.model_error,
                           "inertial_force_error": self.inertial_error},
            "seconds": self.seconds,
        }

    def report(self) -> str:
        """report.md: the selection, the apparent viscosity and every law's parameters with their intervals."""
        return markdown(self.summary())

    def plots(self, out: Path) -> dict[str, Path]:
        """forces.png, flow_curves.png and losses.png in ``out``."""
        return plot_all(self, out)

    def family(self, name: str) -> dict | None:
        """How model ``name`` behaves over the probed shear rates (``family.law_family``); None when the stir
        probed a single shear rate."""
        band = self.probed_shear_rates()
        if not band[1] > band[0] > 0.0:
            return None
        fit = self.fits[name]
        return law_family(fit.model, fit.theta, self.uncertainty[name], band, self.effective_shear_rate)

    def probed_shear_rates(self) -> tuple[float, float]:
        """The band of effective shear rates the stir covered [1/s]: γ̇_eff scaled by the rod's slowest and fastest
        speeds in the fitted window relative to its mean (speeds below ``MOVING_SHARE`` of the top speed are left
        out)."""
        speed = np.linalg.norm(self.problem.velocity[self.problem.train], axis=1)
        moving = speed[speed > MOVING_SHARE * speed.max()] if speed.max() > 0 else np.ones(1)
        ratio = self.effective_shear_rate / max(float(np.mean(speed)), 1e-12)
        return float(moving.min() * ratio), float(moving.max() * ratio)


def slice_correction_summary(problem: StirProblem, material) -> dict | None:
    """The slice correction applied to ``material``'s simulated force on ``problem`` (None in 3-D): the factor C =
    F_3D / (F'_2D h), its relative 1-σ uncertainty, whether the rig lies within the 3-D study's ranges, and the flow
    index and Reynolds number it was evaluated at (``StirProblem.slice_correction``)."""
    correction = problem.slice_correction(material)
    if correction is None:
        return None
    return {"factor": correction.factor, "sigma": correction.sigma, "inside_study": correction.inside,
            "flow_index": correction.flow_index, "reynolds": correction.reynolds, "stir_speed": problem.stir_speed,
            "orbit_radius": problem.orbit_radius, "units": {"stir_speed": "m/s", "orbit_radius": "m"}}
