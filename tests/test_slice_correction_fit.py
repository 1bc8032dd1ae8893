"""The slice correction inside the fit and the virtual lab: a 2-D slice's force per length stands for the rod in the
recording's cup as F = F' h C (``diffstir.slice_correction``, ``fitting.problem``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from diffstir.fitting.problem import StirProblem
from diffstir.fitting.uncertainty import force_error
from diffstir.lab import Fluid, SensorModel
from diffstir.lab.synth import read_truth, simulate_truth
from diffstir.mpm import SimConfig
from diffstir.recording import CupGeometry, Recording, RodGeometry, SensorSpec
from diffstir.rheology import Carreau, Newtonian, PowerLaw
from diffstir.rig import Cup, Rig, Rod
from diffstir.slice_correction import SliceCorrection, flow_state, stir_correction, stir_scales
from diffstir.trajectory import circle

FAST = SimConfig(dim=2, dx=0.01, sound_speed=2.0)


def blank_recording(immersion: float, fill: float = 0.13) -> Recording:
    """A recording of the rod on a 15 mm circle at 0.06 m/s in a 42.5 mm cup, no readings."""
    traj = circle(radius=0.015, speed=0.06, duration=0.3, ramp_time=0.05, sample_rate=250)
    return Recording(cup=CupGeometry(radius=0.0425, fill_height=fill),
                     rod=RodGeometry(radius=0.0125, immersion_depth=immersion),
                     sensor=SensorSpec(mode="tangential", resolution=0.001, sample_rate=250), density=None,
                     t=traj.t, x=traj.xy[:, 0], y=traj.xy[:, 1], force=np.zeros(traj.t.size), name="blank")


def test_a_newtonian_flow_state_is_index_one_at_its_reynolds_number():
    index, reynolds = flow_state(Newtonian(eta=0.5), 4.8, 1000.0, 0.06, 0.025)
    assert index == pytest.approx(1.0, abs=1e-9)
    assert reynolds == pytest.approx(1000.0 * 0.06 * 0.025 / 0.5, rel=1e-6)


def test_a_power_law_and_a_carreau_law_far_past_its_corner_have_their_index():
    # the law's float32 parameters: ln of a ratio of float32 viscosities holds about 1e-7, over ln 1.21
    assert flow_state(PowerLaw(k=2.0, n=0.6), 5.0, 1000.0, 0.1, 0.025)[0] == pytest.approx(0.6, abs=1e-5)
    # Carreau: d ln η / d ln γ̇ = (1 − η∞/η) (n − 1) x² / (1 + x²), x = λ γ̇; the central difference over a factor
    # 1.1 each way errs by the curvature, about (n − 1) (ln 1.1)² / x², here 1e-6
    eta0, eta_inf, lam, n, rate = 1.0, 1e-4, 10.0, 0.5, 10.0
    x2 = (lam * rate) ** 2
    eta = eta_inf + (eta0 - eta_inf) * (1 + x2) ** ((n - 1) / 2)
    exact = 1 + (1 - eta_inf / eta) * (n - 1) * x2 / (1 + x2)
    index = flow_state(Carreau(eta0=eta0, eta_inf=eta_inf, lam=lam, n=n), rate, 1000.0, 0.1, 0.025)[0]
    assert index == pytest.approx(exact, abs=1e-5)


def test_without_a_law_the_correction_is_taken_at_index_one_and_no_inertia():
    assert flow_state(None, 5.0, 1000.0, 0.1, 0.025) == (1.0, 0.0)


def test_the_fit_reads_the_slice_times_the_immersion_and_the_correction():
    """The 2-D slice does not depend on the immersion: two rigs that differ only in it read in the ratio of h C."""
    law = Newtonian(eta=0.5)
    shallow, deep = (StirProblem(blank_recording(h), FAST, 1000.0) for h in (0.04, 0.10))
    with torch.no_grad():
        ratio = deep.simulate(law).numpy() / shallow.simulate(law).numpy()
    expected = (0.10 * deep.slice_correction(law).factor) / (0.04 * shallow.slice_correction(law).factor)
    moving = np.abs(shallow.simulate(law).detach().numpy()) > 1e-4
    np.testing.assert_allclose(ratio[moving], expected, rtol=1e-5)
    assert deep.slice_correction(law).factor != pytest.approx(shallow.slice_correction(law).factor, abs=1e-3)


def test_an_uncorrected_fit_reads_the_paper_s_extruded_slice():
    """``corrected=False`` (``fit.slice_correction=false``): F = F' h, the corrected reading over C; no correction
    is reported and none joins the intervals, and a coarser copy of the problem keeps the choice."""
    law = Newtonian(eta=0.5)
    corrected = StirProblem(blank_recording(0.08), FAST, 1000.0)
    extruded = StirProblem(blank_recording(0.08), FAST, 1000.0, corrected=False)
    with torch.no_grad():
        reading, plain = corrected.simulate(law).numpy(), extruded.simulate(law).numpy()
    moving = np.abs(plain) > 1e-4
    np.testing.assert_allclose(reading[moving] / plain[moving], corrected.slice_correction(law).factor, rtol=1e-5)
    assert extruded.slice_correction(law) is None
    assert extruded.with_config(replace(FAST, dx=0.012)).slice_correction(law) is None


def test_the_stir_scales_are_the_rods_speed_and_circle_while_it_stirs():
    # at rest for 0.1 s, then 0.3 s on a 15 mm circle at 0.06 m/s: the rest does not count
    t = np.linspace(0.0, 0.3, 301)
    phase = 0.06 / 0.015 * t
    position = np.concatenate([np.tile([[0.015, 0.0]], (100, 1)), 0.015 * np.stack([np.cos(phase), np.sin(phase)], 1)])
    velocity = np.concatenate([np.zeros((100, 2)), 0.06 * np.stack([-np.sin(phase), np.cos(phase)], 1)])
    speed, orbit = stir_scales(position, velocity)
    assert (speed, orbit) == pytest.approx((0.06, 0.015), rel=1e-12)
    # the fit's problem takes them over its fitted samples, the ramp's included
    problem = StirProblem(blank_recording(0.08), FAST, 1000.0)
    assert problem.orbit_radius == pytest.approx(0.015, rel=1e-3)
    assert 0.5 * 0.06 < problem.stir_speed < 0.06


def test_the_correction_is_none_in_3d():
    problem = StirProblem(blank_recording(0.08), replace(FAST, dim=3), 1000.0)
    assert problem.slice_correction(Newtonian(eta=0.5)) is None


def test_a_rod_path_that_leaves_no_room_at_the_wall_is_refused_before_simulating():
    from diffstir.recording import RecordingError
    traj = circle(radius=0.031, speed=0.06, duration=0.3, ramp_time=0.05, sample_rate=250)  # 31 + 12.5 > 42.5 mm
    recording = replace(blank_recording(0.08), t=traj.t, x=traj.xy[:, 0], y=traj.xy[:, 1])
    with pytest.raises(RecordingError, match="orbit_radius = 0.031.* m: the rod .* does not fit in the cup"):
        StirProblem(recording, FAST, 1000.0)


def test_a_rod_on_the_cups_axis_is_outside_the_study_and_its_correction_uncertain():
    from diffstir.slice_correction import slice_correction
    centred = slice_correction(0.0425, 0.13, 0.0125, 0.08, 0.0)
    assert not centred.inside
    assert centred.sigma >= abs(centred.factor - 1.0)


def test_the_correction_joins_the_simulators_error_in_quadrature():
    assert force_error(0.03, SliceCorrection(1.02, 0.04, True)) == pytest.approx(0.05)
    assert force_error(0.03, None) == 0.03


def test_the_virtual_labs_2d_truth_carries_the_correction_the_fit_applies():
    """A lab recording and the fit of it use the same C for the truth's fluid: the correction does not bias a fit
    of the lab's own data."""
    rig = Rig(cup=Cup(radius=0.0425, fill_height=0.13, height=0.165), rod=Rod(radius=0.0125, immersion_depth=0.08))
    traj = circle(radius=0.006, speed=0.08, duration=0.52, ramp_time=0.05, sample_rate=250)  # one period
    fluid = Fluid(name="thin syrup", density=1200.0, law={"name": "newtonian", "params": {"eta": 0.3}})
    truth = simulate_truth(fluid, traj, rig=rig, sim_config=FAST)
    lab = read_truth(truth, SensorModel(mode="tangential", sample_rate=250, resolution=0.0), seed=0)
    problem = StirProblem(lab.recording, FAST, fluid.density)
    applied = problem.slice_correction(fluid.make_law()).factor
    assert truth.slice_factor == pytest.approx(applied, rel=2e-3)
    assert lab.truth["simulator"]["slice_factor"] == truth.slice_factor
    assert truth.slice_factor == pytest.approx(stir_correction(rig, fluid.make_law(), 1200.0, 0.08, 0.006).factor,
                                               rel=5e-3)
