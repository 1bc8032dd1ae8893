"""The class a fitted law shows over the probed shear rates (diffstir.fitting.family)."""

import math

import numpy as np
import pytest

from diffstir.fitting.family import law_family
from diffstir.fitting.models import FitModel
from diffstir.fitting.uncertainty import Uncertainty

BAND = (1.0, 4.0)  # 1/s: the probed band of the non-Newtonian benchmark's stir
RATE = 2.0  # 1/s: its effective shear rate


def known(model: FitModel, std: float = 0.01) -> Uncertainty:
    """An uncertainty with θ known to ``std`` in every direction."""
    k = model.size
    return Uncertainty(covariance=np.eye(k) * std**2, ci95={}, identifiable={n: True for n in model.names},
                       at_bound={n: False for n in model.names}, effective_samples=100.0, residual_std=1e-3)


def family(name: str, std: float = 0.01, **params) -> dict:
    model = FitModel.named(name, **params)
    return law_family(model, model.theta(), known(model, std), BAND, RATE)


def test_the_class_is_the_laws_behaviour_over_the_band_not_its_name():
    # Carreau with λγ̇ = 1e-3: Newtonian over the band whatever n
    assert family("carreau", eta0=1.0, eta_inf=1e-3, lam=1e-3, n=0.3)["class"] == "newtonian"
    # Cross thins for every n > 0, n near 1 included (the benchmark had called n = 0.97 Newtonian)
    cross = family("cross", eta0=1.6, eta_inf=1e-4, lam=0.23, n=0.97)
    assert cross["class"] == "shear_thinning"
    eta = [1.6 / (1 + (0.23 * g) ** 0.97) for g in BAND]
    assert cross["slope"] == pytest.approx(math.log(eta[1] / eta[0]) / math.log(4.0), rel=1e-4)
    # a tiny yield stress with n > 1 thickens; a power law's slope is n − 1
    assert family("herschel_bulkley", tau_y=0.04, k=0.36, n=1.13)["class"] == "shear_thickening"
    # (to the float32 parameters and the law's regularisation at vanishing shear rate)
    assert family("power_law", k=0.3, n=1.3)["slope"] == pytest.approx(0.3, abs=1e-4)


def test_a_yield_stress_counts_when_it_carries_the_stress():
    ketchup = family("herschel_bulkley", tau_y=2.66, k=3.44, n=0.5)
    assert ketchup["class"] == "yield_stress"
    # τ_y / (τ_y + k γ̇ⁿ) at the effective shear rate, to the regularisation's exp(−γ̇/γ̇_c) and float32
    assert ketchup["yield_share"] == pytest.approx(2.66 / (2.66 + 3.44 * RATE**0.5), rel=1e-3)
    # the thickening fit of the lab's power-law fluid (n 1.3): its 0.02 Pa yield stress is 1.5 % of the stress at
    # γ̇_eff 4 1/s, though it would carry most of it at the ramps' slowest rates
    model = FitModel.named("herschel_bulkley", tau_y=0.0221, k=0.167, n=1.51)
    fitted = law_family(model, model.theta(), known(model), (0.2, 4.5), 4.05)
    assert fitted["class"] == "shear_thickening" and fitted["yield_share"] < 0.02


def test_the_slope_interval_is_reported_not_decisive():
    # an index known to ±0.3 (in θ) makes the slope's interval hold 0; the class is still the law's behaviour,
    # because the test of non-Newtonian behaviour is the selection between laws
    wide = family("power_law", std=0.3, k=0.3, n=0.8)
    assert wide["slope_ci95"][0] < 0 < wide["slope_ci95"][1] and wide["class"] == "shear_thinning"
    assert wide["slope_ci95"][1] - wide["slope_ci95"][0] == pytest.approx(2 * 1.96 * 0.3, rel=1e-3)


def test_a_band_of_one_shear_rate_is_refused():
    model = FitModel.named("newtonian", eta=1.0)
    with pytest.raises(ValueError, match="1/s"):
        law_family(model, model.theta(), known(model), (2.0, 2.0), 2.0)
