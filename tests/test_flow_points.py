"""Laws fitted to apparent-viscosity points (``fitting.flow_points``): weighted least squares in ln η, its covariance
with the Birge ratio, BIC with known errors, open intervals where the points leave a parameter undetermined, and
the profile-likelihood intervals."""

import math

import numpy as np
import pytest

from diffstir.fitting import Z95, FitModel, fit_points, profiled

RATES = np.array([0.9, 1.8, 3.6, 14.4])  # 1/s: the default plan's effective shear rates (docs/planning.md)


def test_a_newtonian_fit_is_the_weighted_mean_of_ln_eta_with_its_variance():
    # closed form: ln η̂ = Σ w ln η / Σ w, var = B² / Σ w with w = 1/σ², B² = max(1, χ²/(S − 1))
    eta = np.array([1.0, 1.1, 0.95, 1.02])
    sigma = np.array([0.05, 0.1, 0.05, 0.2])
    w = 1.0 / sigma**2
    mean = float(np.sum(w * np.log(eta)) / np.sum(w))
    chi2 = float(np.sum(w * (np.log(eta) - mean) ** 2))
    fit = fit_points("newtonian", RATES, eta, sigma)
    assert fit.model.params_si()["eta"] == pytest.approx(math.exp(mean), rel=1e-6)
    assert fit.chi2 == pytest.approx(chi2, rel=1e-6)
    assert fit.uncertainty.covariance[0, 0] == pytest.approx(max(1.0, chi2 / 3) / np.sum(w), rel=1e-5)
    assert fit.bic == pytest.approx(chi2 + math.log(4), rel=1e-6)


def test_points_that_agree_better_than_their_errors_do_not_narrow_the_interval():
    sigma = np.full(4, 0.05)
    fit = fit_points("newtonian", RATES, np.full(4, 0.7), sigma)
    assert fit.chi2 == pytest.approx(0.0, abs=1e-12)
    assert math.sqrt(fit.uncertainty.covariance[0, 0]) == pytest.approx(0.05 / 2.0, rel=1e-6)  # σ / √S, B = 1


def test_an_exact_power_law_is_recovered_with_an_interval_of_the_two_point_slope():
    k, n, sigma = 3.0, 0.4, 0.03
    eta = k * RATES ** (n - 1.0)
    fit = fit_points("power_law", RATES, eta, np.full(4, sigma))
    # the law's regularisation at a small shear rate g_c (rheology.RegularisedLaw) bends it by ~1e-5 at 0.9 1/s
    assert fit.model.params_si()["n"] == pytest.approx(n, abs=1e-4)
    assert fit.model.params_si()["k"] == pytest.approx(k, rel=1e-4)
    x = np.log(RATES)
    expected = sigma / math.sqrt(np.sum((x - x.mean()) ** 2))  # straight-line slope's standard error
    j = fit.model.names.index("n")
    assert math.sqrt(fit.uncertainty.covariance[j, j]) == pytest.approx(expected, rel=1e-4)
    lo, hi = fit.uncertainty.ci95["n"]
    assert (hi - lo) / 2 == pytest.approx(Z95 * expected, rel=1e-4)


def test_four_points_leave_a_four_parameter_law_partly_open_and_rank_it_by_bic():
    truth = FitModel.named("carreau", eta0=1.0, eta_inf=0.01, lam=0.5, n=0.6)
    eta = truth.viscosity(RATES)[0]
    fits = {name: fit_points(name, RATES, eta, np.full(4, 0.04)) for name in ("newtonian", "power_law", "carreau")}
    assert fits["carreau"].chi2 < 1e-3  # it passes through its own points
    assert not all(fits["carreau"].uncertainty.identifiable.values())
    # BIC = χ² + k ln S: the Newtonian law cannot follow a factor 2 of thinning, 0.04 in ln η per point
    assert fits["newtonian"].bic - fits["carreau"].bic > 10
    assert fits["carreau"].bic == pytest.approx(fits["carreau"].chi2 + 4 * math.log(4))


@pytest.mark.parametrize("name,eta", [
    ("newtonian", np.array([1.0, 1.1, 0.95, 1.02])),             # scattered beyond its errors: B > 1
    ("power_law", np.array([2.1, 1.4, 1.15, 0.62]))])
def test_the_profile_interval_of_a_law_linear_in_ln_eta_is_its_covariance_interval(name, eta):
    # ln η = θ (Newtonian) and ln η = ln k + (n − 1) ln γ̇ (power law) are linear in θ: χ² is quadratic, and its
    # profile rises by Z95² B² exactly at θ_j ± Z95 σ_j
    sigma = np.full(4, 0.03)
    fit = fit_points(name, RATES, eta, sigma)
    profile = profiled(fit, RATES, eta, sigma)
    for parameter in fit.model.names:
        assert profile.uncertainty.ci95[parameter] == pytest.approx(fit.uncertainty.ci95[parameter], rel=1e-5)
        assert profile.uncertainty.identifiable[parameter] == fit.uncertainty.identifiable[parameter]
    assert profile.chi2 == fit.chi2 and np.array_equal(profile.uncertainty.covariance, fit.uncertainty.covariance)


def test_the_profile_holds_a_cross_fluid_where_the_curvature_of_a_law_through_its_points_misleads():
    # four windows of a Cross fluid (η0 = 2 Pa·s, η∞ = 0.02 Pa·s, λ = 1 s, n = 0.7) off the plan's stir on a 2-D
    # truth, standard errors 0.05-0.07: the Cross law passes through the four points, and the curvature there
    # gives η∞ [0.13, 0.49] Pa·s and λ [0.22, 0.43] s, which miss the truth; the profile, along which the other
    # parameters follow, holds all four and names none identified
    rates = np.array([0.901, 1.802, 3.603, 14.412])
    eta = np.array([0.9721, 0.8698, 0.6056, 0.2917])
    sigma = np.array([0.0614, 0.0698, 0.0542, 0.0709])
    truth = {"eta0": 2.0, "eta_inf": 0.02, "lam": 1.0, "n": 0.7}
    fit = fit_points("cross", rates, eta, sigma)
    profile = profiled(fit, rates, eta, sigma)
    for name, value in truth.items():
        lo, hi = profile.uncertainty.ci95[name]
        assert lo <= value <= hi and lo <= fit.model.params_si()[name] <= hi
        assert not profile.uncertainty.identifiable[name]


@pytest.mark.parametrize("rates,eta,sigma", [
    (RATES, np.ones(3), np.ones(4)), (RATES, -np.ones(4), np.ones(4)), (RATES, np.ones(4), np.zeros(4))])
def test_bad_points_are_refused(rates, eta, sigma):
    with pytest.raises(ValueError, match="fit_points"):
        fit_points("newtonian", rates, eta, sigma)
