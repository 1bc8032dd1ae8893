"""The yield stress decided by the joint fit over every speed (docs/behaviour.md, step 4): on readings of the
fitting model itself, a Herschel-Bulkley paste is told from a power law that nearly mimics it."""

import dataclasses
import json

import numpy as np
import pytest
import torch

from diffstir.behaviour import characterise, write_behaviour_report
from diffstir.behaviour.joint import PASTE_SHARES, JointProblem, screened_pastes
from diffstir.behaviour.windows import speed_windows
from diffstir.identify import StirProblem
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
    result = characterise([recording], config=FAST, density=DENSITY, iterations=1,
                          joint_models=("power_law", "herschel_bulkley"), replicates=50, workers=2)
    c = result.classification
    assert c.label == label
    if label == "yield_stress":  # strong evidence at least: 2 ln B > 6
        assert c.joint.delta_bic > 6.0 and c.joint.weight > 0.95
    else:  # the nested law wins nothing that pays for its parameter
        assert c.joint.weight < 0.5
    # the report states the test that decided
    paths = write_behaviour_report(result, tmp_path)
    stated = json.loads(paths["json"].read_text())["behaviour"]
    assert stated["class"] == label and stated["yield_test"]["joint"]["weight"] == pytest.approx(c.joint.weight)
    assert "yield stress by the joint fit" in paths["md"].read_text()


def test_paste_screen_starts_a_plastic_fluid_near_its_yield_stress():
    # a Bingham plastic whose yield stress carries 94-98 % of the stress over the programme's shear rates (U/a,
    # 3.2-13 1/s): of the paste starts on its own flow curve, the nearly plastic one (90 %) reads closer to it than
    # the half-yield one, whose flow part must then rise steeply with the rate to reach the fast speed's stress
    law = {"name": "bingham", "params": {"tau_y": 2.0, "eta_p": 0.01}}
    recording = model_readings(programme_recording(), law, noise=0.001, seed=3)
    windows = speed_windows(recording)
    rate = np.array([w.speed / recording.rod.radius for w in windows])
    curve = FlowCurve(rate, 2.0 + 0.01 * rate)
    with Workers(1, report=lambda event: None) as pool:
        start = screened_pastes(pool, JointProblem(windows, FAST, DENSITY), ["bingham"], curve)["bingham"]
    assert max(PASTE_SHARES) == pytest.approx(0.9)
    assert start.params_si()["tau_y"] == pytest.approx(0.9 * curve.stress.min(), rel=1e-4)
