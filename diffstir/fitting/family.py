"""The behaviour a fitted law shows over the shear rates a stir probed: its law family as a fluid class.

A law's name does not say how it behaves where it was measured: a Carreau law with λγ̇ ≪ 1 is Newtonian there,
a Cross law thins for every n > 0, and a Herschel-Bulkley law with a tiny yield stress and n > 1 thickens. So the
class is read off the fitted law over the probed band [γ̇_lo, γ̇_hi] [1/s]:

* **yield_stress** when the law has a yield stress τ_y that carries at least ``YIELD_SHARE`` of its stress
  τ = η γ̇ at the stir's effective shear rate γ̇_eff (a smaller one changes the apparent viscosity there by less
  than the 10 % an identification resolves; at the band's low end, set by the ramps, any τ_y of a thickening law
  would dominate);
* **newtonian** when η changes across the band by less than ``NEWTONIAN_CHANGE``;
* otherwise **shear_thinning** or **shear_thickening** by the sign of the chord slope
  s = [ln η(γ̇_hi) − ln η(γ̇_lo)] / ln(γ̇_hi/γ̇_lo).

The statistical test of non-Newtonian behaviour is the choice between laws (``selection``: BIC with N_eff, so a
law with more parameters must earn them): the class of the *selected* law is the identification's answer. The
slope's 95 % interval (delta method, ds/dθ from d ln η/dθ at both ends) is reported beside it; it is not the
test, because where a law's parameters trade off against each other (λ, η_inf and n of a Carreau fit to a narrow
band) its linearisation spans far more than the curves the data allow.
"""

from __future__ import annotations

import math

import numpy as np

from ..rheology import has_yield_stress
from .models import FitModel
from .uncertainty import Z95, Uncertainty, delta_variance

#: Least share of the stress at the effective shear rate that a yield stress must carry to count [1].
YIELD_SHARE = 0.1

#: Largest change of η across the band, |ln η(γ̇_hi)/η(γ̇_lo)|, that is still Newtonian: 10 %, what an
#: identification resolves [1].
NEWTONIAN_CHANGE = math.log(1.1)


def law_family(model: FitModel, theta: np.ndarray, uncertainty: Uncertainty, band: tuple[float, float],
               effective_shear_rate: float) -> dict:
    """The class of ``model`` at ``theta`` over the shear rates ``band`` [1/s] of a stir whose effective shear
    rate is ``effective_shear_rate`` [1/s] (module docstring): {"class", "slope", "slope_ci95", "yield_share",
    "band"}."""
    lo, hi = float(band[0]), float(band[1])
    if not (0.0 < lo < hi and math.isfinite(hi)):
        raise ValueError(f"band = {band}; expected shear rates 0 < lo < hi in 1/s")
    if not (effective_shear_rate > 0 and math.isfinite(effective_shear_rate)):
        raise ValueError(f"effective_shear_rate = {effective_shear_rate}; expected a positive rate in 1/s")
    eta, grad = model.viscosity(np.array([lo, hi, effective_shear_rate]), theta)
    eta, grad, eta_eff = eta[:2], grad[:2], float(eta[2])
    width = math.log(hi / lo)
    slope = float(np.log(eta[1] / eta[0])) / width
    half = Z95 * math.sqrt(float(delta_variance(((grad[1] - grad[0]) / width)[None], uncertainty.covariance)[0]))
    share = 0.0
    if has_yield_stress(model.name):
        share = model.params_si()["tau_y"] / max(eta_eff * effective_shear_rate, 1e-300)
    if share >= YIELD_SHARE:
        cls = "yield_stress"
    elif abs(slope) * width < NEWTONIAN_CHANGE:
        cls = "newtonian"
    else:
        cls = "shear_thinning" if slope < 0 else "shear_thickening"
    return {"class": cls, "slope": slope, "slope_ci95": [slope - half, slope + half], "yield_share": share,
            "band": [lo, hi], "units": {"slope": "1", "band": "1/s"}}
