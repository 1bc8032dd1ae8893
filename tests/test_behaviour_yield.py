"""The yield stress decided by the joint fit over every speed (docs/behaviour.md, step 4): on readings of the
fitting model itself, a Herschel-Bulkley paste is told from a power law that nearly mimics it."""

import dataclasses
import json
import warnings

import numpy as np
import pytest
import torch

from diffstir.behaviour import BehaviourSettings, characterise
from diffstir.behaviour.joint import (INDEX_SHIFTS, PASTE_SHARES, JointProblem, index_starts, paste_start,
                                     screened_starts)
from diffstir.fitting.models import FitModel
from diffstir.fitting.problem import StirProblem
from diffstir.fitting.windows import speed_windows
from diffstir.parallel import Workers
from diffstir.recording import Recording
from diffstir.rheology import FlowCurve, make_law
from test_behaviour import FAST, programme_recording

DENSITY = 1000.0  # kg/m³


def model_readings(recording: Recording, law: dict, noise: float, seed: int) -> Recording:
    """``recording`` with its force replaced by what the fitting model itself (FAST, water's density) reads for
    ``law`` [SI], plus white noise of ``noise`` [N]: the joint fit's model is then exact."""
    problem = StirProblem(recording, FAST, DENSITY)
    with torch.no_grad():
        readings = problem.simulate(make_law(law["name"], **law["params"]).double()).numpy()
    force = recording.force.copy()
    force[problem.index] = readings + noise * np.random.default_rng(seed).normal(size=readings.size)
    return dataclasses.replace(recording, force=force)


@pytest.mark.parametrize("law,label", [
    ({"name": "herschel_bulkley", "params": {"tau_y": 2.0, "k": 0.5, "n": 0.6}}, "yield_stress"),
    ({"name": "power_law", "params": {"k": 3.0, "n": 0.4}}, "shear_thinning"),
])
def test_joint_fit_tells_a_yield_stress_from_a_power_law(law, label, tmp_path):
    # over these speeds (a factor 4) the paste's stress, 2.8-3.9 Pa, is nearly a power law of index 0.23: what tells
    # them apart is the flow the yield stress makes around the rod, which only the joint fit through the simulator
    # sees. On FAST the lab's truth and the fit's replay of it differ by more than that, so the readings here are
    # the fitting model's own, with 1 mN of white noise
    recording = model_readings(programme_recording(), law, noise=0.001, seed=2)
    result = characterise([recording], config=FAST, density=DENSITY, workers=2,
                          settings=BehaviourSettings(iterations=1, joint_models=["power_law", "herschel_bulkley"],
                                                     replicates=50))
    c = result.classification
    assert c.label == label
    if label == "yield_stress":  # strong evidence at least: 2 ln B > 6
        assert c.joint.delta_bic > 6.0 and c.joint.weight > 0.95
    else:  # the nested law wins nothing that pays for its parameter, and the slope is the power law's own index
        assert c.joint.weight < 0.5
        check = result.summary()["behaviour"]["slope_check"]
        lo, hi = check["joint_index_ci95"]
        assert lo <= law["params"]["n"] - 1 <= hi
    # the report states the test that decided
    paths = result.write(tmp_path)
    stated = json.loads(paths["json"].read_text())["behaviour"]
    assert stated["class"] == label and stated["yield_test"]["joint"]["weight"] == pytest.approx(c.joint.weight)
    assert "yield stress by the joint fit" in paths["md"].read_text()
    assert "the joint power law's slope n − 1" in paths["md"].read_text()


def test_paste_screen_starts_a_plastic_fluid_near_its_yield_stress():
    # a Bingham plastic whose yield stress carries 94-98 % of the stress over the programme's shear rates (U/a,
    # 3.2-13 1/s): of the paste starts on its own flow curve, the nearly plastic one (90 %) reads closer to it than
    # the half-yield one, whose flow part must then rise steeply with the rate to reach the fast speed's stress
    law = {"name": "bingham", "params": {"tau_y": 2.0, "eta_p": 0.01}}
    recording = model_readings(programme_recording(), law, noise=0.001, seed=3)
    windows = speed_windows(recording)
    rate = np.array([w.speed / recording.rod.radius for w in windows])
    curve = FlowCurve(rate, 2.0 + 0.01 * rate)
    candidates = {"bingham": {f"paste{share:g}": paste_start("bingham", curve, share) for share in PASTE_SHARES}}
    with Workers(1, report=lambda event: None) as pool:
        kept = screened_starts(pool, JointProblem(windows, FAST, DENSITY), candidates)["bingham"]
    assert max(PASTE_SHARES) == pytest.approx(0.9) and kept.label == "paste0.9"
    # kept with its stress scaled by its readings' amplitude on the measured ones
    assert kept.model.params_si()["tau_y"] == pytest.approx(0.9 * curve.stress.min() * kept.amplitude, rel=1e-4)


class StressReadings:
    """A stand-in for ``JointProblem`` whose readings scale with the stress exactly, as a Stokes drag's do: in each
    of three windows the law's stress at that window's shear rate [Pa] times a unit sinusoid [N/Pa]."""

    RATES = np.array([2.0, 8.0, 30.0])  # 1/s

    def __init__(self, truth, window_scales=(1.0, 1.0, 1.0)):
        self.times = np.linspace(0.0, 1.0, 50)
        self.measured = self.simulate(truth).numpy()
        self.weights = np.repeat(min(window_scales) / np.asarray(window_scales), self.times.size)

    def cost(self, predicted) -> float:
        return float(np.sqrt(np.mean((self.weights * (self.measured - predicted)) ** 2)))

    def simulate(self, law) -> torch.Tensor:
        with torch.no_grad():
            stress = (law(torch.as_tensor(self.RATES, dtype=torch.float64)) * torch.as_tensor(self.RATES)).numpy()
        return torch.as_tensor(np.concatenate([tau * np.sin(2 * np.pi * self.times) for tau in stress]))

    def loss(self, predicted, train=True) -> float:
        return float(np.mean(np.abs(self.measured - predicted)))


def test_a_start_of_the_right_shape_at_the_wrong_scale_beats_a_wrong_shape_at_the_right_one():
    """Where the fitting grid reads every law too high, a start with the truth's flow curve reads worse than one with
    the wrong curve at the measured size; scaled by its readings' amplitude it reads the truth (docs/accuracy.md)."""
    truth = FitModel.named("herschel_bulkley", tau_y=3.0, k=0.1, n=1.0)
    problem = StressReadings(truth.material)
    candidates = {"herschel_bulkley": {"right shape, 1.3 times the stress": truth.stress_scaled(1.3),
                                       "power law of index 0.3": FitModel.named("herschel_bulkley", tau_y=1e-3,
                                                                                k=2.4, n=0.3)}}
    right, wrong = candidates["herschel_bulkley"].values()
    unscaled = {label: problem.loss(problem.simulate(m.material).numpy())
                for label, m in candidates["herschel_bulkley"].items()}
    assert unscaled["right shape, 1.3 times the stress"] > unscaled["power law of index 0.3"]
    with Workers(1, report=lambda event: None) as pool:
        kept = screened_starts(pool, problem, candidates)["herschel_bulkley"]
    assert kept.label == "right shape, 1.3 times the stress"
    assert kept.amplitude == pytest.approx(1 / 1.3, rel=1e-5)  # float32 parameters
    for name, value in truth.params_si().items():
        assert kept.model.params_si()[name] == pytest.approx(value, rel=1e-5)


def test_a_stress_scale_multiplies_every_laws_stress():
    rate = np.logspace(-2, 2, 9)
    for name, params in [("newtonian", {"eta": 0.5}), ("power_law", {"k": 2.0, "n": 0.4}),
                         ("carreau", {"eta0": 1.0, "eta_inf": 0.01, "lam": 0.5, "n": 0.6}),
                         ("cross", {"eta0": 1.0, "eta_inf": 0.01, "lam": 0.5, "n": 0.6}),
                         ("herschel_bulkley", {"tau_y": 3.0, "k": 0.5, "n": 0.7}),
                         ("bingham", {"tau_y": 3.0, "eta_p": 0.1})]:
        model = FitModel.named(name, **params)
        eta, _ = model.viscosity(rate)
        np.testing.assert_allclose(model.stress_scaled(0.7).viscosity(rate)[0], 0.7 * eta, rtol=1e-6)
    with pytest.raises(ValueError, match="> 0"):
        model.stress_scaled(0.0)


def test_a_window_the_simulator_reads_by_chance_does_not_pick_the_start():
    """The fast window's readings carry the simulation's jitter, tens of percent of its misfit for a 0.5 % change
    of the sound speed (docs/accuracy.md). Where they happen to read 20 % high, a law that is 20 % too stiff at the
    fast rate only, and wrong at the slow ones, reads closer with one variance for all windows, because the fast
    window's stress is the largest; weighed by each window's own scale, the law that reads the slow windows wins."""
    truth = FitModel.named("power_law", k=1.0, n=0.8)
    problem = StressReadings(truth.material)
    fast = slice(2 * problem.times.size, None)
    problem.measured[fast] *= 1.2  # the jitter's draw in the fast window
    stiff = FitModel.named("power_law", k=0.75, n=0.92)  # 1.2x the truth's stress at 30 1/s, 0.8x at 2 1/s
    candidates = {"power_law": {"truth": truth, "stiff at the fast rate": stiff}}
    with Workers(1, report=lambda event: None) as pool:
        assert screened_starts(pool, problem, candidates)["power_law"].label == "stiff at the fast rate"
        # the scale of each window: what a free viscosity per window leaves (here the fast window's 20 %)
        problem.weights = StressReadings(truth.material, window_scales=(0.01, 0.01, 0.2)).weights
        assert screened_starts(pool, problem, candidates)["power_law"].label == "truth"


def test_joint_problem_weighs_each_window_by_its_scale():
    windows = speed_windows(programme_recording())
    problem = JointProblem(windows, FAST, DENSITY, window_scales=[0.004, 0.002, 0.02])  # N
    times = np.concatenate([p.times[m] for p, m in zip(problem.problems, problem.masks)])
    residual = np.zeros(times.size)  # N: each window's scale, which weighs as the best window's 2 mN
    for w, scale in zip(windows, (0.004, 0.002, 0.02)):
        inside = (times > w.start) & (times <= w.end)
        np.testing.assert_allclose(problem.weights[inside], 0.002 / scale)
        residual[inside] = scale
    assert problem.cost(problem.measured - residual) == pytest.approx(0.002)
    assert JointProblem(windows, FAST, DENSITY).weights == pytest.approx(1.0)
    for scales in ([0.004, 0.002], [0.004, 0.0, 0.02], [0.004, float("nan"), 0.02]):
        with pytest.raises(ValueError, match="one misfit > 0 in N per window"):
            JointProblem(windows, FAST, DENSITY, window_scales=scales)


def test_index_starts_shift_the_index_and_keep_the_stress_at_the_pivot():
    rate = np.array([0.5, 10.0, 60.0])  # 1/s: the pivot in the middle
    for name, params in [("power_law", {"k": 0.51, "n": 0.97}),
                         ("herschel_bulkley", {"tau_y": 1.0, "k": 0.3, "n": 0.9}),
                         ("carreau", {"eta0": 2.0, "eta_inf": 0.05, "lam": 1.0, "n": 0.4})]:
        model = FitModel.named(name, **params)
        starts = index_starts(model, 10.0)
        assert list(starts) == ["points", *(f"n{shift:+g}" for shift in INDEX_SHIFTS)] and starts["points"] is model
        for shift in INDEX_SHIFTS:
            shifted = starts[f"n{shift:+g}"]
            assert shifted.params_si()["n"] == pytest.approx(params["n"] + shift, abs=1e-6)
            eta, _ = shifted.viscosity(rate)
            assert eta[1] == pytest.approx(model.viscosity(rate)[0][1], rel=1e-5)
            # the stress now grows with the rate by the shifted index: steeper above the pivot for a larger n
            assert (eta[2] > model.viscosity(rate)[0][2]) == (shift > 0)
    assert list(index_starts(FitModel.named("newtonian", eta=1.0), 10.0)) == ["points"]
    # glycerol's points' Carreau curve on the 5 mm grid: η∞ above η0, nearly Newtonian at n = 1; raising n drives
    # its viscosity to the floor at the pivot, and that start is left out instead of scaled by an infinite factor
    glycerol = FitModel.named("carreau", eta0=0.3842, eta_inf=275.06, lam=185.6, n=1.0001)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert list(index_starts(glycerol, 10.0)) == ["points", "n-0.15"]
