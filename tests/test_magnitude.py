"""The Newtonian viscosity from the reading's size (``fitting.magnitude``) against closed forms."""

import math

import numpy as np
import pytest
import torch

from diffstir.fitting.magnitude import RESOLVED_FACTOR, expected_magnitude, magnitude_estimate
from diffstir.mpm import SimConfig
from diffstir.recording import SensorSpec


@pytest.mark.parametrize("p_over_sigma", [0.0, 0.5, 2.0, 10.0])
def test_expected_magnitude_is_the_folded_normal_mean(p_over_sigma):
    sigma = 0.003
    samples = np.abs(p_over_sigma * sigma + np.random.default_rng(1).normal(0.0, sigma, 400_000))
    expected = expected_magnitude(np.array([-p_over_sigma * sigma]), sigma)[0]  # the sign of p does not matter
    assert expected == pytest.approx(samples.mean(), abs=4 * samples.std() / math.sqrt(samples.size))
    if p_over_sigma == 0.0:
        assert expected == pytest.approx(sigma * math.sqrt(2 / math.pi), rel=1e-12)


class _InertialProblem:
    """A stand-in for StirProblem whose reading is (a0 + a1 η) sin 2πt [N]: an inertial part a0 [N] that no
    viscosity changes, and a viscous part a1 η; measured at ``eta_true`` with white noise of std ``noise`` [N]."""

    a0, a1 = 0.02, 0.05  # N, N/(Pa s)

    def __init__(self, eta_true: float, noise: float, seed: int):
        self.times = np.linspace(0.0, 2.0, 400)
        rng = np.random.default_rng(seed)
        self.measured = self.reading(eta_true) + rng.normal(0.0, noise, self.times.size)
        self.train = np.ones(self.times.size, dtype=bool)
        self.weights = np.ones(self.train.size)
        self.config = SimConfig(dim=2, viscosity_cap=1e3)
        self.recording = type("Recording", (), {"sensor": SensorSpec(mode="tangential", resolution=1e-6,
                                                                         sample_rate=200.0)})()
        self.noise = noise

    def reading(self, eta: float) -> np.ndarray:
        return (self.a0 + self.a1 * eta) * np.sin(2 * np.pi * self.times)

    def log_slope(self, eta: float, h: float = 1e-4) -> float:
        """d ln M / d ln η [1] at ``eta`` of the noise-folded statistic, by central differences."""
        m = [np.mean(expected_magnitude(self.reading(eta * math.exp(s)), self.noise)) for s in (-h, h)]
        return math.log(m[1] / m[0]) / (2 * h)

    def simulate(self, law):
        return torch.as_tensor(self.reading(float(law(torch.ones(1, dtype=torch.float64)))))

    def loss(self, predicted, train=True):
        return float(np.mean(np.abs(self.measured - predicted)))


def test_a_viscous_reading_is_resolved_and_its_interval_covers_the_truth():
    # the noise (a sixth of the amplitude) is folded into the simulated side, so the estimate is unbiased; with
    # no model error the interval is the noise's and must hold the truth in about 95 % of recordings: at least
    # 34 of 40 (the binomial's 0.1 % point at p = 0.95 is 33)
    eta_true, covered = 0.4, 0
    for seed in range(40):
        problem = _InertialProblem(eta_true, noise=0.007, seed=seed)
        estimate = magnitude_estimate(problem, start=0.1, model_error=0.0)
        assert estimate.resolved
        covered += estimate.ci95[0] < eta_true < estimate.ci95[1]
        # d ln M / d ln η by secants near the root, against the derivative of the folded-normal M there
        assert estimate.slope == pytest.approx(problem.log_slope(estimate.viscosity), rel=0.1)
    assert covered >= 34


def test_noise_as_large_as_half_the_reading_is_not_read_as_viscosity():
    eta_true = 0.4
    problem = _InertialProblem(eta_true, noise=0.02, seed=3)
    estimate = magnitude_estimate(problem, start=0.1, model_error=0.0)
    assert estimate.ci95[0] < eta_true < estimate.ci95[1]
    # mean |m| against the noise-free mean |p| would read the noise's share of the size as viscosity
    naive = np.mean(np.abs(problem.measured)) / np.mean(np.abs(np.sin(2 * np.pi * problem.times)))
    assert (naive - problem.a0) / problem.a1 > estimate.ci95[1]


def test_a_start_at_the_root_still_measures_the_slope_there():
    problem = _InertialProblem(0.4, noise=1e-5, seed=0)
    estimate = magnitude_estimate(problem, start=0.4, model_error=0.03)
    assert estimate.resolved and estimate.ci95[0] < 0.4 < estimate.ci95[1]
    assert estimate.slope == pytest.approx(problem.log_slope(0.4), rel=0.1)


def test_a_model_error_widens_the_interval_by_its_share_over_the_slope():
    problem = _InertialProblem(0.4, noise=1e-5, seed=0)
    estimate = magnitude_estimate(problem, start=0.1, model_error=0.03)
    # σ = 3 % in ln M over a slope of 0.5: ±1.96 · 6 % in ln η
    lo, hi = estimate.ci95
    assert math.log(hi / lo) / 2 == pytest.approx(1.96 * 0.03 / 0.5, rel=0.1)
    assert estimate.resolved


def test_a_thin_fluid_below_the_inertial_floor_is_not_resolved():
    # at 1 mPa s the viscous part is 0.25 % of the reading, below the 3 % model error: the reading's size does
    # not fix η, the interval's lower end is not found (the reading stops falling with η), and it says so
    problem = _InertialProblem(0.001, noise=0.003, seed=0)
    estimate = magnitude_estimate(problem, start=0.01, model_error=0.03)
    assert not estimate.resolved
    assert estimate.ci95[0] < 0.001 / RESOLVED_FACTOR
    summary = estimate.summary()
    assert summary["resolved"] is False and summary["units"]["viscosity"] == "Pa s"


class _BlowsUpAbove(_InertialProblem):
    """A stand-in whose simulation blows up for η above ``limit`` [Pa·s], as an explicit step past its bound."""

    def __init__(self, eta_true: float, limit: float):
        super().__init__(eta_true, noise=1e-4, seed=0)
        self.limit = limit

    def simulate(self, law):
        if float(law(torch.ones(1, dtype=torch.float64))) > self.limit:
            raise FloatingPointError("the simulation became non-finite at step 3")
        return super().simulate(law)


def test_a_simulation_that_blows_up_ends_the_search_without_failing_the_identification():
    problem = _BlowsUpAbove(0.4, limit=0.3)  # the root lies where the simulator cannot go
    estimate = magnitude_estimate(problem, start=0.1, model_error=0.03)
    assert not estimate.resolved and estimate.viscosity <= 0.3 and math.isfinite(estimate.slope)


def test_the_inertial_parts_error_widens_the_interval_by_its_share_of_the_reading():
    # M = a0 + a1 η: at 0.4 Pa s the inertial part a0 is half of M, so s = 1/2 and σ_i = 30 % adds 15 % in ln M,
    # ±1.96 √(0.03² + 0.15²) / 0.5 in ln η; a purely viscous reading (a0 = 0) would not be widened at all
    problem = _InertialProblem(0.4, noise=1e-5, seed=0)
    estimate = magnitude_estimate(problem, start=0.1, model_error=0.03, inertial_error=0.3)
    lo, hi = estimate.ci95
    s = problem.log_slope(0.4)
    assert s == pytest.approx(0.5, rel=1e-3)
    assert math.log(hi / lo) / 2 == pytest.approx(1.96 * math.hypot(0.03, 0.3 * (1 - s)) / s, rel=0.1)
    assert estimate.relative_error == pytest.approx(math.hypot(0.03, 0.3 * (1 - s)), rel=0.05)
    assert lo < 0.4 < hi
