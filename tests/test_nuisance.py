"""The sensor's offset and lag as nuisances of a fit (diffstir.fitting.nuisance)."""

import math

import numpy as np
import pytest
import torch

from diffstir.fitting.models import FitModel
from diffstir.fitting.nuisance import NO_NUISANCE, NUISANCES, SensorNuisance, lag_response
from diffstir.fitting.optimise import fit_model
from diffstir.mpm import SimConfig
from diffstir.recording import SensorSpec


def test_profiling_recovers_the_offset_and_the_lag_of_a_reading():
    times = np.linspace(0.0, 2.0, 201)
    simulated = 0.05 * np.sin(2 * math.pi * times) + 0.02 * np.sin(2 * math.pi * 3.1 * times)
    truth = {"lag": 0.023, "offset": 0.004}  # s, N
    sensor = SensorNuisance(NUISANCES)
    measured = sensor.apply(simulated, times, truth)
    values = sensor.profile(simulated, measured, times, np.ones(times.size, bool))
    assert values["lag"] == pytest.approx(truth["lag"], abs=1e-5)
    assert values["offset"] == pytest.approx(truth["offset"], abs=1e-7)
    assert NO_NUISANCE.profile(simulated, measured, times, np.ones(times.size, bool)) == {}


def test_the_projected_jacobian_gives_the_marginal_covariance():
    # variable projection: (P⊥J)ᵀ(P⊥J) is the Schur complement, so its inverse is θ's block of the covariance
    # of θ and the nuisances fitted together
    rng = np.random.default_rng(1)
    times = np.linspace(0.0, 1.0, 101)
    simulated = np.sin(2 * math.pi * times) + 0.3 * rng.normal(size=times.size)
    jacobian = rng.normal(size=(times.size, 2))
    sensor, values = SensorNuisance(NUISANCES), {"lag": 0.02, "offset": 0.0}
    train = np.ones(times.size, bool)
    projected = sensor.projected(jacobian, simulated, times, values, train)
    full = np.column_stack([jacobian, sensor.columns(simulated, times, values)])
    marginal = np.linalg.inv(full.T @ full)[:2, :2]
    assert np.allclose(np.linalg.inv(projected.T @ projected), marginal, rtol=1e-9, atol=0)


def test_unknown_nuisances_are_refused_with_the_config_key():
    with pytest.raises(ValueError, match="fit.sensor_nuisance"):
        SensorNuisance(("offset", "gain"))


class _LaggedProblem:
    """A stand-in for StirProblem: the reading is η times a two-tone signal [N], read through a 30 ms lag and a
    3 mN offset, with 1 mN noise."""

    def __init__(self, eta_true: float):
        self.times = np.linspace(0.0, 2.0, 201)
        self.signal = np.sin(2 * math.pi * self.times) + 0.4 * np.sin(2 * math.pi * 2.3 * self.times)
        noise = np.random.default_rng(2).normal(0.0, 1e-3, self.times.size)
        self.measured = lag_response(eta_true * self.signal, self.times, 0.03) + 0.003 + noise
        self.train = np.ones(self.times.size, dtype=bool)
        self.weights = np.ones(self.train.size)
        self.config = SimConfig(dim=2, viscosity_cap=1e3)
        self.recording = type("Recording", (), {"sensor": SensorSpec(mode="component", axis=(0.0, 1.0),
                                                                         resolution=1e-3, sample_rate=100.0)})()

    def simulate(self, law):
        return torch.as_tensor(float(law(torch.ones(1, dtype=torch.float64))) * self.signal)

    def loss(self, predicted, train=True):
        return float(np.mean(np.abs(self.measured - predicted)))


def test_a_fit_with_the_nuisances_finds_the_viscosity_that_the_lag_would_bias():
    problem, eta = _LaggedProblem(0.5), 0.5  # Pa s
    plain = fit_model(problem, FitModel.named("newtonian", eta=1.0), max_iterations=6)
    fitted = fit_model(problem, FitModel.named("newtonian", eta=1.0), max_iterations=6,
                       sensor=SensorNuisance(NUISANCES))
    # 1 mN noise on 201 samples of a ~0.3 N rms signal: ln η is known to ~1e-3; the lag alone biases it by %
    assert fitted.model.params_si()["eta"] == pytest.approx(eta, rel=5e-3)
    assert abs(plain.model.params_si()["eta"] / eta - 1.0) > 3 * abs(fitted.model.params_si()["eta"] / eta - 1.0)
    assert fitted.sensor["lag"] == pytest.approx(0.03, abs=2e-3)
    assert fitted.sensor["offset"] == pytest.approx(0.003, abs=5e-4)
    assert fitted.loss < 0.5 * plain.loss
    assert np.allclose(fitted.simulated_readings, eta * problem.signal, rtol=5e-3)


def test_the_papers_adam_refuses_nuisances_it_cannot_profile():
    with pytest.raises(ValueError, match="fit.sensor_nuisance.*optimizer"):
        fit_model(_LaggedProblem(0.5), FitModel.named("newtonian", eta=1.0), optimizer="adam",
                  sensor=SensorNuisance(("lag",)))
