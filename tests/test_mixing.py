"""Mixing: the Lederer-Roegiers rule, the lab's two-fluid mode (IEM exchange, initial layouts, the truth's time
courses), the exponential approach and the mixing experiment of the fit app."""

import json
import math
import re
import sys

import numpy as np
import pytest
import torch

from diffstir.fitting.uncertainty import Z95
from diffstir.lab import Fluid, SensorModel, stirring_programme
from diffstir.lab.blend import (Blend, BlendMaterial, cell_concentration, initial_concentration, mix,
                                synthesise_blend)
from diffstir.mixing import fit_approach
from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.recording import save_recording
from diffstir.rheology import Newtonian
from diffstir.rheology.blending import blend_range, implied_alpha, lederer_roegiers
from diffstir.rig import Rig

FAST = SimConfig(dim=2, dx=0.01, sound_speed=1.0, dt_max=0.004, viscosity_cap=5.0)  # as in test_behaviour
ETA1, ETA2 = 2.0, 0.05  # Pa s


def test_lederer_roegiers_limits_inverse_and_backends():
    phi = 0.3
    assert lederer_roegiers(ETA1, ETA2, phi, 1.0) == pytest.approx(ETA1**phi * ETA2 ** (1 - phi))  # Arrhenius
    assert lederer_roegiers(ETA1, ETA2, phi, 0.0) == pytest.approx(ETA1)
    for alpha in (0.2, 0.7):
        eta = lederer_roegiers(ETA1, ETA2, phi, alpha)
        assert implied_alpha(eta, ETA1, ETA2, phi) == pytest.approx(alpha)
        assert float(lederer_roegiers(torch.tensor(ETA1, dtype=torch.float64), torch.tensor(ETA2, dtype=torch.float64),
                                      phi, alpha)) == pytest.approx(eta, rel=1e-12)
    low, high = blend_range(ETA1, ETA2, phi)
    assert low < lederer_roegiers(ETA1, ETA2, phi, 0.5) < high
    with pytest.raises(ValueError, match="more viscous fluid first"):
        blend_range(ETA2, ETA1, phi)
    with pytest.raises(ValueError, match="mixing.fraction"):
        blend_range(ETA1, ETA2, 1.0)


@pytest.fixture(scope="module")
def scene_and_state():
    material = BlendMaterial(Newtonian(eta=ETA1), Newtonian(eta=ETA2), 1.0)
    sim = StirringSimulator(material, Rig(), SimConfig(dim=2, dx=0.01, sound_speed=2.0, dtype="float64"),
                            density=1000.0)
    return sim.scene, sim.initial_state(stirring_programme([{"speed": 0.05, "duration": 1.0}], radius=0.015))


@pytest.mark.parametrize("layout", ["core", "annulus", "half"])
def test_initial_layouts_hold_the_fraction_exactly(scene_and_state, layout):
    _, state = scene_and_state
    c = initial_concentration(state.x, layout, 0.4)
    assert float(c.sum()) == round(0.4 * state.num_particles) and set(c.unique().tolist()) <= {0.0, 1.0}


def test_iem_exchange_conserves_bounds_and_mixes(scene_and_state):
    scene, state = scene_and_state
    c = initial_concentration(state.x, "half", 0.5)
    rate = torch.rand(state.num_particles, dtype=c.dtype, generator=torch.Generator().manual_seed(0)) * 10.0
    mixed = mix(scene, state.x, rate, c, dt=0.5, diffusivity=1e-9, strain_mixing=0.2)
    assert float(mixed.sum()) == pytest.approx(float(c.sum()), rel=1e-12)  # float64: conservation is exact
    assert float(mixed.min()) >= 0.0 and float(mixed.max()) <= 1.0
    assert float(mixed.var()) < float(c.var())
    uniform = torch.full_like(c, 0.3)
    assert torch.allclose(mix(scene, state.x, rate, uniform, 0.5, 1e-9, 0.2), uniform, rtol=1e-12)
    assert torch.equal(mix(scene, state.x, rate, c, 0.0, 1e-9, 0.2), c)  # no time, no exchange
    cells = cell_concentration(scene, state.x, c)
    assert float(cells.min()) >= 0.0 and float(cells.max()) <= 1.0 + 1e-12


def test_blend_of_one_fluid_is_that_fluid():
    law = Newtonian(eta=0.37)
    material = BlendMaterial(law, Newtonian(eta=0.37), 0.6)
    rate = torch.logspace(-2, 2, 9)
    for c in (0.0, 0.3, 1.0):
        torch.testing.assert_close(material.viscosity(rate, torch.full_like(rate, c)), law(rate))


@pytest.fixture(scope="module")
def blend_lab():
    blend = Blend(first=Fluid(name="syrup", density=1200.0, law={"name": "newtonian", "params": {"eta": ETA1}}),
                  second=Fluid(name="thin", density=1000.0, law={"name": "newtonian", "params": {"eta": ETA2}}),
                  fraction=0.7, alpha=0.6, layout="core", strain_mixing=0.3)
    traj = stirring_programme([{"speed": 0.1, "duration": 2.0}], radius=0.015, ramp_time=0.1)
    sensor = SensorModel(mode="tangential", sample_rate=100.0, resolution=0.001, noise_std=0.001)
    return blend, synthesise_blend(blend, traj, sim_config=FAST, sensor=sensor, seed=2)


def test_the_blend_mixes_and_its_truth_is_recorded(blend_lab):
    blend, lab = blend_lab
    history = lab.truth["mixing"]
    intensity = np.array(history["intensity_of_segregation"])
    assert intensity[0] == pytest.approx(1.0) and intensity[-1] < 0.5 * intensity[0]
    eta_d = np.array(history["dissipation_viscosity"])[1:]  # at t = 0 nothing moves
    assert np.all((eta_d > ETA2) & (eta_d < ETA1))  # a weighted mean of blend viscosities between the two
    assert lab.truth["fluid"]["density"] == pytest.approx(blend.density) == pytest.approx(0.7 * 1200 + 0.3 * 1000)
    assert np.all(np.isfinite(lab.recording.force))


def test_exponential_approach_recovers_its_parameters():
    rng = np.random.default_rng(3)
    t = np.linspace(0.2, 4.0, 12)
    sigma = np.full(t.size, 0.02)
    truth = 0.3 * np.exp(1.2 * np.exp(-(t - t[0]) / 0.8))
    a = fit_approach(t, truth * np.exp(sigma * rng.normal(size=t.size)), sigma)
    assert a.plateau_ci95[0] <= 0.3 <= a.plateau_ci95[1]
    assert a.time_constant_ci95[0] <= 0.8 <= a.time_constant_ci95[1]
    half = math.log(a.plateau_ci95[1] / a.plateau)
    assert half == pytest.approx(Z95 * a.birge * (math.log(a.plateau_ci95[1]) - math.log(a.plateau)) / (Z95 * a.birge))
    # at the homogeneity time the remaining excess equals the plateau's 95 % half-width
    assert abs(a.excess) * math.exp(-(a.homogeneity_time - a.start) / a.time_constant) == pytest.approx(half)
    assert a.homogeneity_time_ci95[0] < a.homogeneity_time < a.homogeneity_time_ci95[1]


def test_a_systematic_error_widens_the_plateau_not_the_course():
    # an error common to every window (the simulator's) moves the whole course: the plateau's interval adds it in
    # quadrature, the fitted course and the time to homogeneity (a question of its shape) are unchanged
    rng = np.random.default_rng(3)
    t = np.linspace(0.2, 4.0, 12)
    sigma = np.full(t.size, 0.02)
    eta = 0.3 * np.exp(1.2 * np.exp(-(t - t[0]) / 0.8) + sigma * rng.normal(size=t.size))
    plain, wide = fit_approach(t, eta, sigma), fit_approach(t, eta, sigma, systematic=0.1)
    stat = math.log(plain.plateau_ci95[1] / plain.plateau)
    assert math.log(wide.plateau_ci95[1] / wide.plateau) == pytest.approx(math.hypot(stat, Z95 * 0.1))
    assert wide.plateau == plain.plateau and wide.homogeneity_time == plain.homogeneity_time
    with pytest.raises(ValueError, match="systematic"):
        fit_approach(t, eta, sigma, systematic=-0.1)


def test_homogeneity_time_interval_covers_the_truth_about_95_percent_of_the_time():
    # the true t_h of the noiseless course, defined with the fit's own plateau half-width: the delta-method interval
    # is approximate, so its coverage over 200 noisy courses must be near 95 % (binomial sd 1.5 %), not exact
    t = np.linspace(0.2, 4.0, 12)
    sigma = np.full(t.size, 0.02)
    course = 1.2 * np.exp(-(t - t[0]) / 0.8)
    rng = np.random.default_rng(5)
    hits, trials = 0, 200
    for _ in range(trials):
        a = fit_approach(t, 0.3 * np.exp(course + sigma * rng.normal(size=t.size)), sigma)
        half = math.log(a.plateau_ci95[1] / a.plateau)
        truth = t[0] + 0.8 * math.log(1.2 / half)
        lo, hi = a.homogeneity_time_ci95
        hits += lo <= truth <= hi
    assert 0.95 - 4 * 0.015 <= hits / trials <= 1.0


def test_mixing_experiment_writes_the_report(blend_lab, tmp_path, monkeypatch, capsys):
    from diffstir.apps.fit import main

    blend, lab = blend_lab
    path = save_recording(lab.recording, tmp_path / "blend")
    out = tmp_path / "out"
    monkeypatch.setattr(sys, "argv", ["diffstir-fit", "experiment=mixing", f"recordings=[{path}]", f"out={out}",
                                      "sim.dx=0.01", "sim.sound_speed=1.0", "sim.dt_max=0.004", "sim.viscosity_cap=5.0",
                                      f"mixing.viscosities=[{ETA1},{ETA2}]",
                                      f"mixing.fraction={blend.fraction}", "mixing.window=0.45", "mixing.iterations=2"])
    main()
    m = json.loads((out / "report.json").read_text())["mixing"]
    course = [p["viscosity"] for p in m["time_course"]]
    # the truth's dissipation-weighted viscosity falls fastest in the first second (the viscous core around the
    # rod thins as it mixes), so the second window reads a thinner fluid than the first
    assert course[0] > course[1]
    assert ETA2 < m["blend_viscosity"] < ETA1
    assert m["lederer_roegiers"]["range"] == pytest.approx(list(blend_range(ETA1, ETA2, blend.fraction)))
    assert (out / "time_course.png").stat().st_size > 0
    text = (out / "report.md").read_text()
    assert f"blend {m['blend_viscosity']:.4g} Pa·s" in text
    assert sum(line.startswith("| ") for line in text.splitlines()) == len(course) + 1  # the header and each window
    # the progress bar's summary counts every window's simulations
    simulations = sum(p["evaluations"] for p in m["time_course"])
    assert re.search(rf"^mixing: {simulations} simulations in .+; {len(course)} windows$", capsys.readouterr().out,
                     re.MULTILINE)


def test_synth_app_writes_a_two_fluid_recording_and_its_mixing_truth(tmp_path, monkeypatch):
    from diffstir.apps.synth import main
    from diffstir.lab import truth_path
    from diffstir.recording import load_recording

    monkeypatch.setattr(sys, "argv", [
        "diffstir-synth", "lab/blend=f60_water", f"out={tmp_path}", "lab/sensor=ideal",
        "lab.programme.segments=[{speed: 0.1, duration: 1.0}]", "lab.programme.radius=0.012",
        "lab.sim.dx=0.01", "lab.sim.sound_speed=1.0", "lab.blend.fraction=0.3"])
    main()
    rec = load_recording(tmp_path / "f60_water")
    truth = json.loads(truth_path(tmp_path / "f60_water").read_text())
    blend = truth["fluid"]["blend"]
    assert blend["fraction"] == 0.3 and blend["first"]["name"] == "F60 syrup" and blend["second"]["name"] == "water"
    # one density for the blend: the volume-weighted mean of the presets' (diffstir/lab/blend.py)
    assert truth["fluid"]["density"] == pytest.approx(0.3 * 1290.0 + 0.7 * 998.23)
    intensity = truth["mixing"]["intensity_of_segregation"]
    assert intensity[0] == pytest.approx(1.0) and intensity[-1] < intensity[0]  # segregated, then mixing
    assert rec.t[-1] == pytest.approx(1.0, abs=0.02)
