"""The stirring plan (``diffstir.planning``) against closed forms of the window model."""

import math

import numpy as np
import pytest

from diffstir.errors import ConfigError
from hydra import compose, initialize_config_dir

from diffstir.apps import CONF_DIR
from diffstir.apps.plan import plan_inputs
from diffstir.behaviour import JOINT_MODELS
from diffstir.fitting import SHEAR_RATE_PROBES, Z95, FitModel, ViscosityLadder
from diffstir.fitting.initial import mean_readings
from diffstir.mpm import FINE_STAGE, SimConfig
from diffstir.planning import (CALIBRATION_SAMPLE_RATE, CALIBRATION_STEADY_TIME, ArmLimits, Calibration, PlanSettings,
                               Planner, Prior, Programme, Window, WindowErrors, calibrate, candidates,
                               fisher_information, information_gain, rig_calibration, window_points)
from diffstir.planning.calibration import _one_speed_problem
from diffstir.planning.information import expected_delta_bic, predicted_intervals
from diffstir.rig import Rig

SPEEDS = (0.01, 0.02, 0.04, 0.08, 0.16)  # m/s
PROBES = (0.01, 0.1, 1.0, 10.0, 100.0)   # Pa s


def viscous_calibration(speeds=SPEEDS, inertial=0.0, factor=1.5, rod_radius=0.0125):
    """A calibration whose reading is M = c_i ρ U² + c_v η U [N] (a Stokes drag on an inertial part), exactly linear
    in η as the ladder interpolates it."""
    ladders = tuple(ViscosityLadder(PROBES, tuple(inertial * 1000 * u * u + 0.8 * eta * u for eta in PROBES))
                    for u in speeds)
    return Calibration(0.015, rod_radius, tuple(speeds), ladders, factor)


NO_NOISE = WindowErrors(noise=0.0, resolution=0.0, model_error=0.03, inertial_error=0.3)


def test_a_purely_viscous_window_measures_ln_eta_to_the_model_error():
    # M ∝ η: s = 1, so the inertial error has no share and one window gives I = 1/σ_m² for ln η
    calibration = viscous_calibration()
    model = FitModel.named("newtonian", eta=0.5)
    (point,) = window_points([Window(0.04, 200)], model, calibration, NO_NOISE)
    assert point.log_slope == pytest.approx(1.0)
    assert point.shear_rate == pytest.approx(1.5 * 0.04 / 0.0125)
    assert fisher_information([point])[0, 0] == pytest.approx(1 / 0.03**2)
    (lo, hi) = predicted_intervals(model, fisher_information([point]))["eta"]["ci95"]
    assert math.log(hi / lo) / 2 == pytest.approx(Z95 * 0.03, rel=1e-9)


def test_the_inertial_share_and_the_noise_widen_a_window_as_stated():
    # M = a + b η with a = b η at η = 0.5: s = 1/2; σ² = σ_e²/(n M²) + σ_m² + (σ_i/2)², and ln η's error σ / s
    u, eta, n = 0.04, 0.5, 150
    calibration = viscous_calibration(inertial=0.8 * eta / (1000 * u))
    errors = WindowErrors(noise=0.001, resolution=0.005, model_error=0.03, inertial_error=0.3)
    (point,) = window_points([Window(u, n)], FitModel.named("newtonian", eta=eta), calibration, errors)
    mean_abs = 2 * 0.8 * eta * u
    assert point.mean_abs == pytest.approx(mean_abs) and point.log_slope == pytest.approx(0.5)
    sigma_e = 0.005 / math.sqrt(12)  # the resolution's quantisation noise, 1.4 mN, exceeds the stated 1 mN
    expected = math.sqrt(sigma_e**2 / (n * mean_abs**2) + 0.03**2 + 0.15**2)
    assert point.log_error == pytest.approx(expected)
    assert point.viscosity_error == pytest.approx(expected / 0.5)


def test_below_the_inertial_floor_a_window_adds_nothing():
    ladder = ViscosityLadder(PROBES, (0.02, 0.02, 0.03, 0.1, 0.8))  # flat up to 0.1 Pa s
    calibration = Calibration(0.015, 0.0125, (0.04,), (ladder,), 1.5)
    (point,) = window_points([Window(0.04, 200)], FitModel.named("newtonian", eta=0.05), calibration, NO_NOISE)
    assert point.log_slope == 0.0 and point.viscosity_error == math.inf
    assert fisher_information([point])[0, 0] == 0.0


def test_two_speeds_fix_a_power_laws_index_as_a_two_point_slope():
    # ln η = ln k + (n − 1) ln γ̇ through two points of errors σ_1, σ_2: var n = (σ_1² + σ_2²) / ln(γ̇_2/γ̇_1)²
    calibration = viscous_calibration()
    model = FitModel.named("power_law", k=2.0, n=0.6)
    windows = [Window(0.01, 200), Window(0.16, 200)]
    points = window_points(windows, model, calibration, NO_NOISE)
    covariance = np.linalg.inv(fisher_information(points))
    n_index = model.names.index("n")
    spread = math.log(points[1].shear_rate / points[0].shear_rate)
    assert covariance[n_index, n_index] == pytest.approx(
        (points[0].viscosity_error ** 2 + points[1].viscosity_error ** 2) / spread**2, rel=1e-4)  # float32 law
    # one speed cannot separate k from n: the index is not identified
    one = predicted_intervals(model, fisher_information(window_points(windows[:1], model, calibration, NO_NOISE)))
    assert one["n"] == {"ci95": [None, None], "identifiable": False}


def test_the_information_gain_is_lindleys_for_one_parameter():
    # G = ½ ln(1 + I / P) for k = 1, and it never falls when a window is added
    assert information_gain(np.array([[3.0]]), np.array([1.0])) == pytest.approx(0.5 * math.log(4.0))
    calibration = viscous_calibration()
    model = FitModel.named("carreau", eta0=1.0, eta_inf=1e-3, lam=0.5, n=0.5)
    precision = np.ones(model.size)
    gains = [information_gain(fisher_information(window_points([Window(u, 200) for u in SPEEDS[:k]], model,
                                                               calibration, NO_NOISE)), precision)
             for k in range(1, len(SPEEDS) + 1)]
    assert all(b >= a - 1e-12 for a, b in zip(gains, gains[1:])) and gains[-1] > gains[0]


def test_expected_delta_bic_is_the_penalty_when_the_rival_nests_the_truth_and_the_misfit_when_it_cannot():
    calibration = viscous_calibration()
    windows = [Window(u, 200) for u in SPEEDS]
    newtonian = FitModel.named("newtonian", eta=0.5)
    power_law = FitModel.named("power_law", k=0.5, n=1.0)
    # a power law of index 1 is the Newtonian fluid: ΔBIC = (2 − 1) ln S
    assert expected_delta_bic(newtonian, power_law.copy(), [power_law], windows, calibration, NO_NOISE) == \
        pytest.approx(math.log(len(windows)), abs=1e-6)
    # a thinning power law against the best Newtonian constant: the weighted spread of (n − 1) ln γ̇ about its mean
    thinning = FitModel.named("power_law", k=0.5, n=0.7)
    points = window_points(windows, thinning, calibration, NO_NOISE)
    w = np.array([(p.log_slope / p.log_error) ** 2 for p in points])
    x = -0.3 * np.log([p.shear_rate for p in points])
    chi2 = float(np.sum(w * (x - np.sum(w * x) / np.sum(w)) ** 2))
    delta = expected_delta_bic(thinning, newtonian.copy(), [newtonian], windows, calibration, NO_NOISE)
    assert delta == pytest.approx(chi2 - math.log(len(windows)), rel=1e-4)


def test_prior_draws_have_the_reference_viscosity_in_the_prior_range():
    prior = Prior(viscosity=(0.2, 5.0), draws=8)
    for name in ("newtonian", "power_law", "carreau", "cross", "herschel_bulkley", "bingham"):
        draws = prior.draw(name, reference_rate=4.0)
        assert len(draws) == 8 and all(m.name == name for m in draws)
        etas = [float(m.viscosity(np.array([4.0]))[0][0]) for m in draws]
        assert all(0.2 * (1 - 1e-9) <= e <= 5.0 * (1 + 1e-9) for e in etas)
        assert len({round(e, 9) for e in etas}) == 8  # the draws differ
        assert [m.theta().tolist() for m in prior.draw(name, 4.0)] == [m.theta().tolist() for m in draws]
    index = [m.params_si()["n"] for m in prior.draw("carreau", 4.0)]
    assert min(index) >= 0.3 and max(index) <= 0.9


@pytest.mark.parametrize("field, value, words", [
    ("viscosity", (5.0, 0.2), "prior.viscosity = [5.0, 0.2]; expected [low, high] in Pa s"),
    ("laws", ("newtonian", "maxwell"), "prior.laws: unknown maxwell"),
    ("draws", 0, "prior.draws = 0; expected a whole number of at least 1"),
])
def test_a_bad_prior_is_refused_in_one_line(field, value, words):
    with pytest.raises(ConfigError, match=words.replace("[", r"\[").replace("]", r"\]")):
        Prior(**{field: value})


def test_the_arm_bounds_the_speeds_and_the_ramps():
    arm = ArmLimits(max_speed=0.25, max_acceleration=2.0)
    assert arm.fastest(0.01) == pytest.approx(math.sqrt(2.0 * 0.01))  # the centripetal limit U²/r = a_max
    assert arm.ramp_time(0.16, 0.05) == pytest.approx(math.pi * 0.16 / 4.0)  # π ΔU / (2 t) = a_max
    assert arm.ramp_time(0.16, 0.2) == 0.2  # never shorter than asked
    settings = PlanSettings(speeds=SPEEDS, radius=0.01, arm=arm)
    assert settings.levels() == SPEEDS[:-1]  # 0.16 m/s would pull 2.6 m/s² on a 10 mm circle
    for programme in candidates(settings):
        assert programme.duration * len(programme.speeds) == pytest.approx(settings.budget)
        assert programme.duration >= programme.ramp_time + settings.settle_time + settings.min_window
        assert list(programme.speeds) == sorted(programme.speeds)


def test_a_circle_that_would_touch_the_wall_or_a_budget_without_room_is_refused():
    rig = Rig()
    with pytest.raises(ConfigError, match="plan.radius = 0.03 m; the rod stays 0.005 m clear"):
        PlanSettings(radius=0.03).check_rig(rig)
    with pytest.raises(ConfigError, match="plan.budget = 0.6 s leaves no segment room"):
        PlanSettings(budget=0.6).check_rig(rig)  # a 0.2 s ramp, 0.2 s of settling and a 0.3 s window need 0.7 s


def test_the_plan_stirs_several_speeds_and_beats_one_speed_for_a_thinning_prior():
    calibration = viscous_calibration(inertial=0.01)
    prior = Prior(laws=("newtonian", "power_law", "carreau"), draws=4)
    settings = PlanSettings(speeds=SPEEDS, radius=0.015)
    planner = Planner(calibration, prior, settings)
    best = planner.best()
    single = Programme.through((0.04,), settings)
    assert len(best.speeds) >= 2
    assert planner.gain(best)[0] > planner.gain(single)[0]
    assert best.speeds[-1] / best.speeds[0] >= 4  # the information on an index grows with ln(γ̇_max / γ̇_min)
    plan, one = planner.assess(best), planner.assess(single)
    # one speed has one point: a power law fits it exactly as a Newtonian fluid does, and the reverse
    assert one.evidence["power_law"]["newtonian"] == pytest.approx(0.0, abs=1e-6)
    assert plan.evidence["power_law"]["newtonian"] > one.evidence["power_law"]["newtonian"]


def test_the_evidence_counts_each_pair_up_to_its_decision_in_nats():
    # a Newtonian truth against a power-law rival: the rival fits its points exactly, ΔBIC = (2 - 1) ln S;
    # power laws of index 0.4-0.5 against a Newtonian rival over a factor 16 of shear rate: ΔBIC far above 10,
    # counted as 10. The evidence is the mean of min(ΔBIC, 10) / 2 over the two pairs; one speed decides neither.
    calibration = viscous_calibration()
    prior = Prior(laws=("newtonian", "power_law"), power_law_index=(0.4, 0.5), draws=4)
    settings = PlanSettings(speeds=SPEEDS, radius=0.015)
    planner = Planner(calibration, prior, settings)
    sweep = Programme.through((0.01, 0.04, 0.16), settings)
    evidence = planner.evidence(sweep)
    assert evidence["newtonian"]["power_law"] == pytest.approx(np.full(4, math.log(3)), abs=1e-6)
    assert np.all(evidence["power_law"]["newtonian"] > 100)
    assert planner.discrimination(sweep) == pytest.approx((math.log(3) / 2 + 5.0) / 2, abs=1e-6)
    assert planner.discrimination(Programme.through((0.04,), settings)) == pytest.approx(0.0, abs=1e-6)
    assessment = planner.assess(sweep)
    assert assessment.score == pytest.approx(assessment.gain + assessment.discrimination)
    assert assessment.open_pairs() == [("newtonian", "power_law")]


FAST = SimConfig(dim=2, dx=0.01, sound_speed=2.0)  # as tests/test_identify.py: coarse, but the same model


def test_a_calibration_is_simulated_once_and_then_read_from_the_cache(tmp_path):
    events = []
    kwargs = dict(ramp_time=0.1, steady_time=0.4, settle_time=0.1, sample_rate=100.0, cache_dir=tmp_path)
    first = calibrate(Rig(), FAST, 1000.0, 0.015, (0.03, 0.06), (0.1, 0.3, 1.0), report=events.append, **kwargs)
    simulated = len(events)
    assert events[0][:2] == ("calibration", 2 * 3 + SHEAR_RATE_PROBES)  # announced, then one event per simulation
    assert [e[0] for e in events[1:]] == ["evaluation"] * (2 * 3 + SHEAR_RATE_PROBES)
    # a Stokes drag grows with η and with U; the Metzner-Otto constant lies where stirrers' do
    for ladder in first.ladders:
        assert list(ladder.mean_abs) == sorted(ladder.mean_abs)
    assert first.ladder(0.06).mean_abs[-1] > first.ladder(0.03).mean_abs[-1]
    assert 0.1 <= first.shear_rate_factor <= 10.0
    again = calibrate(Rig(), FAST, 1000.0, 0.015, (0.03, 0.06), (0.1, 0.3, 1.0), report=events.append, **kwargs)
    assert len(events) == simulated and again == first
    assert len(list((tmp_path / "plan").glob("calibration-*.json"))) == 1


def test_the_command_defaults_are_the_python_defaults_and_their_calibration_is_shipped(tmp_path):
    # diffstir-plan's conf/plan.yaml and PlanSettings(), Prior() agree, and the calibration they need is the one in
    # diffstir/data/plan/, so the default plan simulates nothing; nor does diffstir-record's sequential mode, whose
    # plan is for the session's 200 Hz sensor: the calibration does not depend on the sensor's rate
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg, recording = compose("plan"), compose("record")
    rig, config, prior, settings = plan_inputs(cfg)
    assert (prior, settings, config) == (Prior(), PlanSettings(), FINE_STAGE)
    assert prior.laws == tuple(JOINT_MODELS)  # the laws the planned stir's flow-curve analysis selects among
    record_settings = plan_inputs(recording)[3]
    assert (record_settings.sample_rate, record_settings.resolution) == (recording.sensor.sample_rate,
                                                                         recording.sensor.resolution)
    assert record_settings.sample_rate != settings.sample_rate
    events = []
    calibration = rig_calibration(rig, prior, settings, config, cache_dir=tmp_path, report=events.append)
    assert rig_calibration(rig, prior, record_settings, config, cache_dir=tmp_path, report=events.append) == calibration
    assert events == [] and not (tmp_path / "plan").exists()
    # and the simulator still reads what was shipped: the middle speed's 1 Pa s probe, simulated again (float32
    # round-off on another machine moves it by far less than the 3 % force error the plan assumes), and read at
    # the record sensor's rate it is the same to a tenth of that error
    speed = calibration.speeds[len(calibration.speeds) // 2]
    ladder = calibration.ladder(speed)
    shipped = ladder.mean_abs[ladder.viscosities.index(1.0)]
    for rate, tolerance in ((CALIBRATION_SAMPLE_RATE, 1e-3), (record_settings.sample_rate, 3e-3)):
        problem = _one_speed_problem(rig, config, settings.density, settings.radius, speed,
                                     ramp_time=settings.arm.ramp_time(max(calibration.speeds), settings.min_ramp),
                                     steady_time=CALIBRATION_STEADY_TIME, settle_time=settings.settle_time,
                                     sample_rate=rate)
        (mean_abs,) = mean_readings(problem, [FitModel.named("newtonian", eta=1.0)])
        assert mean_abs == pytest.approx(shipped, rel=tolerance)
