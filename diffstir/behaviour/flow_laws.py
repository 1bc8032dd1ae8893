"""Laws fitted to the windows' flow curve: the behaviour experiment's second analysis (``analysis: flow_curve``).

Each recording's windows are read by Newtonian simulations of its whole programme
(``fitting.programme_viscosities``): the points η_k at γ̇_k = k_s U_k / a are the windows' Newtonian-equivalent
viscosities. The laws are then fitted to the points, as a rheometer's flow curve is (``fitting.fit_points``:
weighted least squares in ln η with each point's error from noise and simulator together, BIC = χ² + k ln S;
each parameter's interval from its profile likelihood, ``fitting.profiled``), with no further simulation. This is
the planner's model of a programme's windows (``planning.information``, whose calibration stirs each speed from
rest). It costs at most ``fitting.PROGRAMME_SIMULATIONS`` simulations per
recording, where the simulated analysis fits every window and every law through the simulator.

The class is that of the law the points select by BIC over the probed shear rates (``fitting.family``), as
``identify`` names a recording's family, with the Schwarz weight of the laws of that class as its confidence
(``Classification.with_law_families``). The points' straight line, the slope test of the simulated analysis, is
not the test here: a Carreau or Cross fluid bends across a planned sweep, its points lie off any line by more than
their errors, and the line's Birge ratio then widens the slope's interval with the curvature, not with noise. The
slope and its test stay in the report.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..fitting import PointsFit, ViscosityPoint, fit_points, law_family, parameter_summary, profiled, rank


@dataclass
class FlowCurveLaws:
    """Laws fitted to the points: ``fits`` by law, the ``selected`` law by BIC."""

    fits: dict[str, PointsFit]
    selected: str

    @property
    def bic(self) -> dict[str, float]:
        return {name: fit.bic for name, fit in self.fits.items()}

    @property
    def uncertainty(self) -> dict:
        return {name: fit.uncertainty for name, fit in self.fits.items()}

    def summary(self) -> dict:
        laws = {name: {**parameter_summary(fit.model, fit.theta, fit.uncertainty), "chi2": fit.chi2, "bic": fit.bic}
                for name, fit in self.fits.items()}
        return {"selected": self.selected, "ranking": rank(self.bic), "laws": laws, "fitted_to": "points",
                "criterion": "bic = chi2 + k ln S over the S window points, chi2 of ln η with each point's error"}

    def families(self, band: tuple[float, float], shear_rate: float) -> dict[str, str]:
        """Each law's class over the shear rates ``band`` [1/s] of a stir whose effective shear rate is
        ``shear_rate`` [1/s] (``fitting.law_family``)."""
        return {name: law_family(fit.model, fit.theta, fit.uncertainty, band, shear_rate)["class"]
                for name, fit in self.fits.items()}


def flow_curve_laws(points: list[ViscosityPoint], shear_rates: np.ndarray, names: list[str]) -> FlowCurveLaws:
    """Laws ``names`` fitted to ``points`` at ``shear_rates`` [1/s] with each point's total error of ln η."""
    return laws_of_points(shear_rates, [p.viscosity for p in points], [p.total_log_std for p in points], names)


def laws_of_points(shear_rates, viscosity, log_std, names: list[str]) -> FlowCurveLaws:
    """Laws ``names`` fitted to points (γ̇_k [1/s], η_k [Pa·s], σ_k of ln η_k [1]), each parameter's 95 % interval
    from its profile likelihood (``fitting.profiled``)."""
    fits = {name: profiled(fit_points(name, shear_rates, viscosity, log_std), shear_rates, viscosity, log_std)
            for name in names}
    return FlowCurveLaws(fits, rank({name: fit.bic for name, fit in fits.items()})[0])
