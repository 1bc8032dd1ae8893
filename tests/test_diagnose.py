"""Diagnosis: the locating statistics against closed forms, the sensor candidates on readings with a known
concealed effect (no simulation), the verdict's false-alarm guard, and the whole pipeline on a small simulated
recording."""

import json
import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from diffstir.diagnosis import DiagnosisSettings, diagnose, needs_diagnosis
from diffstir.diagnosis.base import base_from_identification, law_from_report, simulate_base
from diffstir.diagnosis.candidates import (PHYSICS_CANDIDATES, SENSOR_CANDIDATES, SLIP_STARTS, CachedReplay, Context,
                                           PhysicsModel, check_names, scaled_law)
from diffstir.diagnosis.compare import (ANCHOR_RANGE, DISTINCT, EVIDENCE, EXPLAINED, NONE, REANCHORS,
                                        SOUND_SPEED_TOLERANCE, ScaleReadings, fit_physics, fit_sensor, rank,
                                        reachable_rss, refrozen, screened_start, second_budget)
from diffstir.diagnosis.locate import harmonic_shares, kinematics, phases, reading_lag
from diffstir.fitting import Z95
from diffstir.fitting.problem import StirProblem, Windows
from diffstir.lab import first_order_lag, stirring_programme
from diffstir.mpm import SimConfig
from diffstir.recording import CupGeometry, Recording, RodGeometry, SensorSpec, sensor_reading_np
from diffstir.rheology import Newtonian, make_law
from problems import fitted_force

FAST = SimConfig(dim=2, dx=0.01, sound_speed=2.0)  # as tests/test_identify.py: coarse, but the same model
NOISE = 0.002  # N
RATE = 100.0   # Hz
SEEDS = 5      # noise draws per sensor effect


def programme(speeds=(0.06, 0.0, -0.06), durations=(0.5, 0.3, 0.5)):
    return stirring_programme([{"speed": s, "duration": d} for s, d in zip(speeds, durations)], radius=0.015,
                              ramp_time=0.1, sample_rate=RATE)


def synthetic_context(effect=None, seed=0, **truth):
    """A context whose base reading is a stirring-like force (a circle's component plus a speed-change spike) and
    whose measurement is that reading, with the Newtonian viscosity 10 % higher, through the ``effect``'s sensor
    model with ``truth`` parameters, plus white noise."""
    traj = programme()
    t, xy = traj.t, traj.xy
    velocity = np.gradient(xy, t, axis=0)
    accel = np.gradient(velocity, t, axis=0)
    accel_y = accel[:, 1]
    p0 = -0.05 / 0.06 * velocity[:, 1]  # drag opposite to the motion, N: 0.05 N at 0.06 m/s
    column = p0.copy()  # a Newtonian reading is proportional to η: d p / d ln η = p
    ctx = Context(times=t, measured=np.zeros_like(t), base_reading=p0, scale_column=column,
                  accel_reading=accel_y, noise=NOISE, shear_rate=4.8, duration=float(t[-1]), rebuild_time=1.0,
                  law=Newtonian(eta=1.0), rod_radius=0.0125)
    true_reading = p0 * 1.1
    if effect is not None:
        true_reading = SENSOR_CANDIDATES[effect].reading(true_reading, ctx, truth)
    ctx.measured = true_reading + np.random.default_rng(seed).normal(0.0, NOISE, t.size)
    return ctx


def test_the_lag_candidate_is_the_labs_first_order_lag_and_its_step_response():
    t = np.arange(200) / RATE
    x = np.where(t > 0.5, 1.0, 0.0)
    lagged = SENSOR_CANDIDATES["sensor_lag"].reading(x, SimpleNamespace(times=t), {"lag_time": 0.1})
    # the lab holds each sample (zero-order hold), the candidate joins samples by lines (first-order hold): the
    # same response to a step delayed by half a sample, so they differ by at most (1 − e^(−Δt/2τ)) of the step
    assert np.abs(lagged - first_order_lag(x, 1 / RATE, 0.1)).max() < 1 - math.exp(-1 / (2 * RATE * 0.1))
    # 63 % of a step after one time constant, to within one sample's worth of the exponential
    k = np.searchsorted(t, 0.6)
    assert lagged[k] == pytest.approx(1 - math.exp(-1), abs=1 / (RATE * 0.1))


def test_locate_labels_the_programme_and_measures_lag_and_harmonics():
    traj = programme()
    velocity = np.gradient(traj.xy, traj.t, axis=0)
    kin = kinematics(traj.t, traj.xy, velocity, rod_radius=0.0125)
    label, transient = phases(traj.t, kin, 0.0125)
    assert transient == pytest.approx(2 * 0.0125 / 0.06, rel=0.02)
    at = lambda s: label[np.searchsorted(traj.t, s)]  # noqa: E731
    assert at(0.2) == "start-up" and at(0.45) == "steady" and at(0.7) == "stop" and at(0.9) == "reversal"
    assert at(0.55) == "speed change"  # the ramp down before the stop
    phase = kin["phase"]
    second = np.cos(2 * phase)
    assert harmonic_shares(second, phase)["harmonic_2"] == pytest.approx(1.0, abs=1e-6)
    t = np.arange(400) / RATE
    simulated = np.sin(2 * np.pi * 1.3 * t)
    measured = np.sin(2 * np.pi * 1.3 * (t - 0.043))
    assert reading_lag(t, measured, simulated, 0.15) == pytest.approx(0.043, abs=0.2 / RATE)


@pytest.mark.parametrize("effect, truth", [("sensor_lag", {"lag_time": 0.08}),
                                           ("sensor_deadband", {"dead_band": 0.01}),
                                           ("sensor_drift", {"offset": 0.004, "drift_rate": 0.01}),
                                           ("inertia", {"moving_mass": 0.05})])
def test_sensor_candidates_recover_their_effect_and_win(effect, truth):
    # the base reading enters linearised in ln s, p0 (1 + ln s), so the measured 1.1 p0 is s = e^0.1
    expected = {"viscosity_scale": math.exp(0.1), **truth}
    covered = {key: 0 for key in expected}
    for seed in range(SEEDS):
        ctx = synthetic_context(effect, seed=seed, **truth)
        fits = {name: fit_sensor(c, ctx) for name, c in SENSOR_CANDIDATES.items()}
        fits["none"] = fit_sensor(NONE, ctx)
        assert rank(fits, ctx.measured, NOISE)[1] == effect
        fit = fits[effect]
        for key, value in expected.items():
            covered[key] += fit.ci95[key][0] <= value <= fit.ci95[key][1]
        # with the effect modelled the residual is the noise: mean |r| = σ sqrt(2/π), within 4 standard errors
        assert fit.loss == pytest.approx(NOISE * math.sqrt(2 / math.pi), rel=4 / math.sqrt(ctx.times.size))
        assert fit.loss < 0.5 * fits["none"].loss
    # a 95 % interval misses the truth in more than one of five seeds with probability 2 %
    assert all(count >= SEEDS - 1 for count in covered.values()), covered


def test_a_sensor_fit_beyond_the_linear_range_is_reanchored_on_a_simulation():
    # a dead band read on a fluid 65 % more viscous than the base law (ln s = 0.5): a Newtonian drag is p0 s, so the
    # linearised reading p0 (1 + ln s) can match it only at ln s = e^0.5 − 1 = 0.65
    ctx = synthetic_context(None)
    truth, band = 0.5, 0.01
    clean = SENSOR_CANDIDATES["sensor_deadband"].reading(ctx.base_reading * math.exp(truth), ctx, {"dead_band": band})
    ctx.measured = clean + np.random.default_rng(0).normal(0.0, NOISE, clean.size)
    linear = fit_sensor(SENSOR_CANDIDATES["sensor_deadband"], ctx)
    assert math.log(linear.params["viscosity_scale"]) == pytest.approx(math.exp(truth) - 1, abs=0.02)
    assert linear.warning is not None and linear.simulations == 0
    scales = []
    readings = ScaleReadings(ctx, lambda s: scales.append(s) or ctx.base_reading * s)
    anchored = fit_sensor(SENSOR_CANDIDATES["sensor_deadband"], ctx, readings)
    assert anchored.warning is None and anchored.simulations == len(scales) and 1 <= len(scales) <= REANCHORS
    # the quadratic through p0 (slope p0 at 0) and the last anchor a misses p0 e^u by e^ξ u² |u − a| / 6, which
    # moves ln s by as much; the rest is the fit's own statistical error
    u, a = math.log(anchored.params["viscosity_scale"]), math.log(scales[-1])
    assert abs(u - a) <= ANCHOR_RANGE
    model_error = math.exp(max(u, a)) * u**2 * abs(u - a) / 6 / math.exp(u)
    lo, hi = (math.log(v) for v in anchored.ci95["viscosity_scale"])
    assert u == pytest.approx(truth, abs=model_error + 1.5 * (hi - lo) / 2)
    assert anchored.ci95["dead_band"][0] < band < anchored.ci95["dead_band"][1]


def test_no_effect_is_named_in_clean_readings():
    alarms = 0
    for seed in range(10):
        ctx = synthetic_context(None, seed=seed)
        fits = {name: fit_sensor(c, ctx) for name, c in SENSOR_CANDIDATES.items()}
        fits["none"] = fit_sensor(NONE, ctx)
        alarms += rank(fits, ctx.measured, NOISE)[1] != "none"
    # ΔBIC > 10 is a likelihood ratio above e^5 against a one-parameter extension: false alarms are rare
    assert alarms <= 1


def test_reachable_rss_is_the_bounded_linear_least_squares_optimum():
    rng = np.random.default_rng(0)
    jacobian = rng.normal(size=(200, 2))
    noise = rng.normal(0.0, 0.1, 200)
    residual = jacobian @ np.array([0.8, -0.3]) + noise
    box = SimpleNamespace(lower=np.array([-1.0, -1.0]), upper=np.array([1.0, 1.0]))
    free = residual - jacobian @ np.linalg.lstsq(jacobian, residual, rcond=None)[0]
    assert reachable_rss(residual, jacobian, np.zeros(2), box) == pytest.approx(free @ free, rel=1e-9)
    # θ already at 0.5 of a bound at 1: the first step stops at 0.5, and what is left is more than the free optimum
    at_edge = reachable_rss(residual, jacobian, np.array([0.5, 0.0]), box)
    assert free @ free < at_edge < residual @ residual


def test_a_fit_cut_short_that_could_still_catch_up_makes_the_verdict_ambiguous():
    """A candidate is not ruled out because its budget stopped its fit: when one more Gauss-Newton step on its last
    Jacobian promises to come within DISTINCT of the best, the verdict is ambiguous; converged, it is ruled out."""
    ctx = synthetic_context("sensor_lag", lag_time=0.1)
    fits = {"sensor_lag": fit_sensor(SENSOR_CANDIDATES["sensor_lag"], ctx), "none": fit_sensor(NONE, ctx)}
    none, lagged = fits["none"], fits["sensor_lag"]
    # a two-parameter "physics" fit stuck at the base reading, whose Jacobian points at the lagged reading
    direction = (lagged.predicted - none.predicted)[:, None]
    box = SimpleNamespace(lower=np.array([-2.0]), upper=np.array([2.0]))
    stuck = replace(none, name="thixotropy", kind="physics", size=lagged.size, converged=False,
                    reachable_rss=reachable_rss(ctx.measured - none.predicted, direction, np.zeros(1), box))
    assert stuck.reachable_rss == pytest.approx(lagged.rss, rel=0.05)
    _, verdict, evidence = rank({**fits, "thixotropy": stuck}, ctx.measured, NOISE)
    assert verdict == "ambiguous" and set(evidence["tied"]) == {"sensor_lag", "thixotropy"}
    assert evidence["unconverged_contenders"]["thixotropy"] < DISTINCT
    settled = replace(stuck, converged=True, reachable_rss=none.rss)
    assert rank({**fits, "thixotropy": settled}, ctx.measured, NOISE)[1] == "sensor_lag"


def test_a_best_fit_cut_short_that_explains_too_little_gets_a_second_budget():
    """The best physics fit, unconverged, with the evidence (ΔBIC > EVIDENCE) but under EXPLAINED of the mismatch
    explained: only the materiality rule stops it, and its budget may be why, so it is fitted further; converged,
    short of the evidence, a sensor candidate (fitted to convergence), or where the residual is noise, it is not."""
    ctx = synthetic_context("sensor_lag", lag_time=0.1)
    none = fit_sensor(NONE, ctx)
    slip = replace(none, name="wall_slip", kind="physics", size=2, converged=False)
    evidence = {"best": "wall_slip", "gain_over_none": 2 * EVIDENCE, "explained": 0.8 * EXPLAINED,
                "residual_test": {"needed": True}, "unconverged_contenders": {}}
    fits = {"none": none, "wall_slip": slip}
    assert second_budget(fits, "none", evidence) == ["wall_slip"]
    assert second_budget({**fits, "wall_slip": replace(slip, converged=True)}, "none", evidence) == []
    assert second_budget(fits, "none", {**evidence, "gain_over_none": 0.5 * EVIDENCE}) == []
    assert second_budget(fits, "none", {**evidence, "residual_test": {"needed": False}}) == []
    lag = replace(none, name="sensor_lag", converged=False)
    assert second_budget({"none": none, "sensor_lag": lag}, "none", {**evidence, "best": "sensor_lag"}) == []
    # named, uncontended: nothing to decide; contended: the contender and the best
    assert second_budget(fits, "wall_slip", {**evidence, "explained": 1.0}) == []
    contended = {**evidence, "explained": 1.0, "unconverged_contenders": {"thixotropy": 0.5 * DISTINCT}}
    assert second_budget(fits, "ambiguous", contended) == ["thixotropy", "wall_slip"]


def test_the_screen_starts_a_physics_fit_on_the_valley_floor_nearest_the_truth():
    """Slip and viscosity trade off: a drag s f(b) p with f falling in b. Each start is rescaled by the
    least-squares factor, so one whose shape fits wins even if its scale is far off; where every start has the
    same shape, the rescale alone recovers s, and a scale beyond its bound is clipped to it."""
    t = np.linspace(0.0, 2.0, 200)
    shape = np.sin(3 * t) + 0.3 * np.sign(np.sin(3 * t))

    def reading(theta):  # a stiffer shape and less force as b grows: the valley s ∝ 1 / f(b)
        s, b = math.exp(theta[0]), math.exp(theta[1])
        return s / (1 + b / 0.002) * (shape + 50 * b * t)

    measured = reading(np.log([1.3, 0.002])) + np.random.default_rng(0).normal(0.0, 1e-3, t.size)
    starts = [np.log([1.0, b]) for b in (0.0004, 0.0012, 0.004)]
    best = screened_start(reading, starts, measured, math.log(0.05), math.log(20.0))
    assert best[1] == pytest.approx(math.log(0.0012))  # the start whose shape is nearest the truth's
    # rescaled onto the valley floor: the force of the truth at that b
    assert math.exp(best[0]) == pytest.approx(1.3 * (1 + 0.0012 / 0.002) / 2, rel=0.05)
    same = screened_start(reading, [np.log([1.0, 0.002])], measured, math.log(0.05), math.log(20.0))
    assert math.exp(same[0]) == pytest.approx(1.3, rel=1e-3)  # noise 1e-3 on a reading of order 1
    assert screened_start(reading, starts[:1], 100 * measured, math.log(0.05), math.log(20.0))[0] == math.log(20.0)


def test_a_physics_fit_goes_on_at_the_sound_speed_of_where_it_moved():
    """The simulator raises its sound speed as √η in a viscous stir (``SimConfig.compressibility``): a fit that
    moves the viscosity scale s by more than twice ``SOUND_SPEED_TOLERANCE`` gets a replay frozen at its new c, one
    that moves less keeps its replay (and its cache)."""
    traj = programme()
    blank = rig_recording(traj, name="blank")
    # a floor of 0.5 m/s under the viscous c of 0.8 Pa s at 0.06 m/s, 1.45 m/s
    problem = StirProblem(blank, replace(FAST, sound_speed=0.5, compressibility=0.03), 1000.0)
    zeros = np.zeros(traj.t.size)
    ctx = Context(times=traj.t, measured=zeros, base_reading=zeros, scale_column=zeros, accel_reading=None,
                  noise=NOISE, shear_rate=4.8, duration=float(traj.t[-1]), rebuild_time=1.0,
                  law=Newtonian(eta=0.8), rod_radius=0.0125)
    model = PhysicsModel(PHYSICS_CANDIDATES["wall_slip"], ctx.law, ctx)
    replay = CachedReplay(problem.frozen(model.material), model)
    replay.simulations = 4
    c0 = replay.problem.config.fixed_sound_speed
    assert c0 > 1.0 and replay.problem.config.rollout_sound_speed == c0
    near = model.theta()
    near[0] = math.log(1 + SOUND_SPEED_TOLERANCE)  # c up by half the tolerance
    model.set_theta(near)
    assert refrozen(replay, problem, model) is replay
    far = near.copy()
    far[0] = math.log(1.1)
    model.set_theta(far)
    fresh = refrozen(replay, problem, model)
    assert fresh is not replay and fresh.simulations == 4 and fresh.cache == {}
    assert fresh.problem.config.fixed_sound_speed == pytest.approx(c0 * math.sqrt(1.1), rel=1e-5)


def test_needs_diagnosis_tells_structure_from_noise():
    rng = np.random.default_rng(1)
    t = np.arange(300) / RATE
    predicted = 0.05 * np.sin(2 * np.pi * t)
    problem = SimpleNamespace(train=np.ones(t.size, bool), recording=SimpleNamespace(sensor=SensorSpec(
        mode="tangential", resolution=None)))
    problem.measured = predicted + rng.normal(0, NOISE, t.size)
    ident = SimpleNamespace(problem=problem, selected=SimpleNamespace(predicted=predicted))
    assert not needs_diagnosis(ident)["needed"]
    problem.measured = first_order_lag(predicted, 1 / RATE, 0.1) + rng.normal(0, NOISE, t.size)
    verdict = needs_diagnosis(ident)
    assert verdict["needed"] and verdict["excess"] > verdict["excess_limit"]


def test_bad_inputs_name_the_field_or_file(tmp_path):
    with pytest.raises(ValueError, match="diagnose.candidates.*sensor_lag"):
        check_names(["sensor_lag", "gremlins"])
    with pytest.raises(FileNotFoundError, match="report.json"):
        law_from_report(tmp_path)
    (tmp_path / "report.json").write_text(json.dumps({"selected": "newtonian", "laws": {}}))
    with pytest.raises(ValueError, match="newtonian"):
        law_from_report(tmp_path / "report.json")


def test_scaled_law_scales_the_viscosity_at_every_rate():
    law = make_law("carreau", eta0=1.0, eta_inf=0.01, lam=0.5, n=0.6)
    rates = torch.tensor([0.1, 1.0, 10.0], dtype=torch.float64)
    np.testing.assert_allclose(scaled_law(law, 1.5)(rates).detach().numpy(), 1.5 * law(rates).detach().numpy(),
                               rtol=1e-5)


def test_base_reuses_the_identification_readings_on_the_same_samples():
    law = Newtonian(eta=0.8)
    times = np.arange(50) / RATE
    jacobian = np.linspace(0.0, 1.0, 50)[:, None]
    problem = SimpleNamespace(config=FAST, times=times)
    fit = SimpleNamespace(model=SimpleNamespace(name="newtonian", material=law), predicted=np.ones(50),
                          jacobian=jacobian, sensor={})
    ident = SimpleNamespace(selected=fit, density={"value": 1000.0}, problem=problem)
    base = base_from_identification(ident, problem)
    assert base.simulations == 0 and base.density == 1000.0
    np.testing.assert_array_equal(base.scale_column, jacobian[:, 0])  # η is the Newtonian law's stress scale


def rig_recording(traj, force=None, name="lagged"):
    """A recording of the rig's rod following ``traj``, read along y; ``force`` [N] (None: zeros)."""
    return Recording(cup=CupGeometry(radius=0.0425, fill_height=0.13),
                     rod=RodGeometry(radius=0.0125, immersion_depth=0.08),
                     sensor=SensorSpec(mode="component", axis=(0.0, 1.0), resolution=0.001, sample_rate=RATE),
                     density=None, t=traj.t, x=traj.xy[:, 0], y=traj.xy[:, 1],
                     force=np.zeros(traj.t.size) if force is None else force, name=name)


def lagged_recording(tau, eta=0.8, seed=0, durations=(0.4, 0.2, 0.4)):
    """A recording of a Newtonian fluid made with the fitting simulator, read through a first-order lag."""
    traj = programme(durations=durations)
    blank = rig_recording(traj)
    t, f = fitted_force(Newtonian(eta=eta), blank, FAST)  # the path the fitter replays, F = F' h C
    force = np.stack([np.interp(traj.t, t, f[:, k]) for k in range(2)], axis=-1)
    reading = first_order_lag(sensor_reading_np(force, blank.velocity(), blank.sensor), 1 / RATE, tau)
    reading += np.random.default_rng(seed).normal(0.0, NOISE, reading.shape)
    return rig_recording(traj, reading)


def test_diagnose_names_a_concealed_sensor_lag_and_reports_it(tmp_path):
    recording = lagged_recording(tau=0.08)
    # the identification's report, as diffstir-fit writes it: a Newtonian law 20 % off, which the scale corrects
    report = {"selected": "newtonian", "laws": {"newtonian": {"params": {"eta": 0.96}}},
              "density": {"value": 1000.0}}
    (tmp_path / "report.json").write_text(json.dumps(report))
    diag = diagnose(recording, tmp_path / "report.json", config=FAST,
                    settings=DiagnosisSettings(candidates=["sensor_lag", "viscoelasticity"], max_iterations=2))
    assert diag.verdict == "sensor_lag"
    assert diag.base.simulations == 2 and diag.fits["viscoelasticity"].simulations > 0
    fit = diag.fits["sensor_lag"]
    lo, hi = fit.ci95["lag_time"]
    # the recording's lag holds each sample over the interval before it (zero-order hold at the sample rate),
    # which leads the continuous response by half a sample; the candidate's exact response takes that up in τ
    assert lo <= 0.08 - 0.5 / RATE <= hi
    assert fit.law["params"]["eta"] == pytest.approx(0.8, rel=0.05)
    paths = diag.write(tmp_path / "out")
    report = json.loads(paths["json"].read_text())
    top = report["ranking"][0]
    assert report["verdict"] == "sensor_lag" and top["effect"] == "sensor_lag"
    assert {"effect", "score", "params", "standard_error", "ci95", "correlations", "loss_before",
            "loss_after"} <= set(top)
    # the lag's standard error is the one its interval was built from: ln(hi/lo) = 2 Z95 SE/τ for a log-scaled τ
    assert top["standard_error"]["lag_time"] == pytest.approx(
        top["params"]["lag_time"] * math.log(hi / lo) / (2 * Z95), rel=1e-6)
    assert all((top["standard_error"][k] is None) == (top["ci95"][k] is None) for k in top["params"])
    assert top["loss_after"] < 0.5 * top["loss_before"]
    assert "sensor response" in report["sentence"]
    assert all(paths[k].stat().st_size > 0 for k in ("md", "residual", "before_after", "candidates"))


def test_a_resumed_physics_fit_goes_on_from_where_it_stopped():
    """The second budget of a fit cut short keeps its θ and Jacobian: no new finite differences, only the start's
    simulation again and the further evaluations."""
    recording = lagged_recording(tau=0.08)
    problem = StirProblem(recording, FAST, 1000.0, Windows.of(recording, None, 0.0))
    base = simulate_base(problem, Newtonian(eta=0.96), 1000.0, "test")
    ctx = Context(times=problem.times, measured=problem.measured, base_reading=base.predicted,
                  scale_column=base.scale_column, accel_reading=None, noise=NOISE, shear_rate=4.8,
                  duration=problem.trajectory.duration, rebuild_time=1.0, law=base.law,
                  rod_radius=problem.rig.rod.radius)
    first = fit_physics("wall_slip", ctx, problem, max_iterations=1)
    assert not first.converged and first.reachable_rss <= first.rss
    # the screen of the slip starts, then the forward-difference Jacobian of (s, b): the start and one step each
    assert first.simulations == len(SLIP_STARTS) + 3
    more = fit_physics("wall_slip", ctx, problem, max_iterations=2, resume=first)
    assert first.simulations < more.simulations <= first.simulations + 2
    assert more.params != first.params and more.seconds > first.seconds


def test_diagnose_app_writes_the_diagnosis(tmp_path, monkeypatch):
    import sys

    from diffstir.apps.diagnose import main
    from diffstir.recording import save_recording

    # loading checks that a recording spans at least one stirring period (1.6 s at 0.06 m/s on this circle)
    recording = lagged_recording(tau=0.08, durations=(0.8, 0.3, 0.8))
    path = save_recording(recording, tmp_path / "rec")
    report = {"selected": "newtonian", "laws": {"newtonian": {"params": {"eta": 0.8}}}, "density": {"value": 1000.0}}
    (tmp_path / "fit").mkdir()
    (tmp_path / "fit" / "report.json").write_text(json.dumps(report))
    out = tmp_path / "out"
    monkeypatch.setattr(sys, "argv", ["diffstir-diagnose", f"recording={path}", f"identification={tmp_path / 'fit'}",
                                      f"out={out}", "diagnosis.candidates=[sensor_lag,sensor_drift]", "sim.dx=0.01",
                                      "sim.sound_speed=2.0", "progress=false"])
    main()
    diagnosis = json.loads((out / "diagnosis.json").read_text())
    assert diagnosis["verdict"] == "sensor_lag"
    assert [r["effect"] for r in diagnosis["ranking"]][0] == "sensor_lag"
    assert (out / "diagnosis.md").read_text().startswith("# Diagnosis")


def test_candidates_fitted_in_parallel_processes_equal_those_fitted_in_one(tmp_path):
    # every simulation is deterministic at a given thread count: the workers must reproduce the fits exactly
    recording = lagged_recording(tau=0.08)
    report = {"selected": "newtonian", "laws": {"newtonian": {"params": {"eta": 0.96}}},
              "density": {"value": 1000.0}}
    (tmp_path / "report.json").write_text(json.dumps(report))
    kwargs = dict(config=FAST, settings=DiagnosisSettings(candidates=["sensor_lag", "wall_slip", "viscoelasticity"],
                                                          max_iterations=1, window=0.5))
    one, two = (diagnose(recording, tmp_path / "report.json", workers=n, **kwargs) for n in (1, 2))
    assert list(two.fits) == list(one.fits) == ["sensor_lag", "wall_slip", "viscoelasticity", "none"]
    for name, fit in one.fits.items():
        assert two.fits[name].params == fit.params
        np.testing.assert_array_equal(two.fits[name].predicted, fit.predicted)
    timeless = [[{k: v for k, v in entry.items() if k != "seconds"} for entry in d.ranking] for d in (one, two)]
    assert two.verdict == one.verdict and timeless[1] == timeless[0]
