"""Behaviour classification: windows of a programme, the slope test's statistics, the classes of model flow
curves, and the whole chain (lab recording -> windows -> viscosities -> class -> joint fit -> app) on a coarse
grid."""

import json
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from diffstir.behaviour import CLASSES, BehaviourSettings, characterise, classify, joint_yield_test, log_slope
from diffstir.behaviour.classify import YIELD_CRITICAL, SlopeEstimate, combined_slope, slope_agreement
from diffstir.behaviour.joint import paste_start
from diffstir.behaviour.pipeline import reclassify
from diffstir.errors import ConfigError
from diffstir.fitting.apparent import with_baseline
from diffstir.fitting.problem import rig_from_recording
from diffstir.fitting.uncertainty import Z95, effective_samples
from diffstir.fitting.windows import speed_windows
from diffstir.lab import Fluid, SensorModel, stirring_programme, synthesise
from diffstir.mpm import SimConfig
from diffstir.recording import CupGeometry, Recording, RecordingError, RodGeometry, SensorSpec, save_recording
from diffstir.rheology import FlowCurve, Newtonian
from diffstir.slice_correction import stir_correction

ROOT = Path(__file__).resolve().parents[1]
# 1 cm cells, the rod 2.5 across, the sound speed 6 times the fastest stir, the viscosity capped at 5 Pa s, steps of
# 3.6 ms: a fast stand-in for the pipeline's statistics, the same model for the truth and the fit, with APIC
# transfers and each particle's own J. On so coarse a grid the default FLIP share and packing relaxation make the
# readings jump with η at steps of 1e-3 in ln η and differ between the truth's and the fit's replay of the rod's path
# (docs/validation.md); the numerics themselves are tested at the fitting resolution (test_mpm, test_numerics)
FAST = SimConfig(dim=2, dx=0.01, sound_speed=1.0, dt_max=0.004, viscosity_cap=5.0, flip=0.0,
                 volume_relaxation=0.0)
SPEEDS = (0.04, 0.08, 0.16)  # m/s
SEGMENT, RAMP = 0.5, 0.1     # s


def path_recording(t, x, y):
    """A recording of the paper's rig whose rod axis follows (x, y) [m] at times t [s], with no force."""
    return Recording(cup=CupGeometry(radius=0.0425, fill_height=0.13),
                     rod=RodGeometry(radius=0.0125, immersion_depth=0.08), sensor=SensorSpec(mode="tangential"),
                     density=None, t=t, x=x, y=y, force=np.zeros(t.size))


def programme_recording(segments=tuple({"speed": s, "duration": SEGMENT} for s in SPEEDS)):
    traj = stirring_programme(segments, radius=0.015, ramp_time=RAMP, sample_rate=200.0)
    return path_recording(traj.t, traj.xy[:, 0], traj.xy[:, 1])


def test_windows_are_the_programme_segments_without_their_ramps():
    windows = speed_windows(programme_recording())
    assert [w.speed for w in windows] == pytest.approx(SPEEDS, rel=1e-3)
    for k, w in enumerate(windows):
        # a window starts where the cosine ramp has slowed enough and ends at the next ramp's start
        assert k * SEGMENT < w.start < k * SEGMENT + RAMP + 0.02
        assert w.end == pytest.approx((k + 1) * SEGMENT, abs=0.011)


def test_a_programme_over_a_wide_range_of_speeds_keeps_its_slowest_and_drops_a_pause():
    # a factor 40 between the slowest and the fastest speed; the rod held still (speed 0) between them
    rec = programme_recording([{"speed": 0.004, "duration": 0.8}, {"speed": 0.0, "duration": 0.8},
                               {"speed": 0.16, "duration": 0.8}])
    windows = speed_windows(rec)
    assert [w.speed for w in windows] == pytest.approx([0.004, 0.16], rel=1e-3)
    assert windows[1].start > 1.6  # the pause between them is no window
    with pytest.raises(ValueError, match="pause_speed"):
        speed_windows(rec, pause_speed=-1.0)


def test_a_fast_small_circle_written_to_a_micrometre_holds_its_window():
    # 0.12 m/s on a 6 mm circle at 200 Hz: GCV keeps the interpolating spline, whose speed still carries the 1 µm
    # rounding, sqrt(2) (q / sqrt(12)) / h = 0.08 mm/s per sample; the rate is read over a span long enough for it
    traj = stirring_programme([{"speed": 0.12, "duration": 0.45}], radius=0.006, ramp_time=RAMP, sample_rate=200.0)
    xy = np.round(traj.xy, 6)
    (window,) = speed_windows(path_recording(traj.t, xy[:, 0], xy[:, 1]))
    assert window.speed == pytest.approx(0.12, rel=1e-3)
    # it ends within the rate's span of the record's end, 5 sqrt(2) σ_v 0.3 s / (0.05 × 0.12 m/s) = 0.029 s
    assert window.start < RAMP + 0.02 and window.end > traj.t[-1] - 0.03


def test_a_recording_without_a_steady_speed_is_refused():
    t = np.linspace(0.0, 3.0, 601)
    phase = 2.0 * t**2  # rad: the speed grows as 4 R t, by 5 % in 0.3 s only after 6 s
    rec = path_recording(t, 0.015 * np.cos(phase), 0.015 * np.sin(phase))
    with pytest.raises(RecordingError, match="one speed"):
        speed_windows(rec)


def test_slope_of_an_exact_power_law_and_its_standard_error():
    g = np.array([0.5, 1.0, 2.0, 4.0, 8.0])
    sigma = np.full(5, 0.04)
    s = log_slope(g, 2.0 * g ** (0.6 - 1.0), sigma)
    x = np.log(g)
    assert s.value == pytest.approx(-0.4, abs=1e-12) and s.intercept == pytest.approx(math.log(2.0))
    assert s.birge == 1.0  # no scatter beyond the given errors
    assert s.std == pytest.approx(0.04 / math.sqrt(np.sum((x - x.mean()) ** 2)))


def test_slope_interval_covers_the_true_slope_95_percent_of_the_time():
    rng = np.random.default_rng(0)
    g = np.array([1.0, 2.0, 4.0, 8.0])
    sigma = np.array([0.03, 0.05, 0.04, 0.06])
    trials = 2000
    covered = 0
    for _ in range(trials):
        s = log_slope(g, 0.7 * g ** 0.2 * np.exp(sigma * rng.normal(size=4)), sigma)
        covered += s.ci95[0] <= 0.2 <= s.ci95[1]
    # with correct errors the Birge scaling can only widen the interval: coverage >= 95 % less 3 sampling sigmas
    assert covered / trials >= 0.95 - 3 * math.sqrt(0.95 * 0.05 / trials)


@pytest.mark.parametrize("label,viscosity", [
    ("newtonian", lambda g: 0.5 + 0 * g),
    ("shear_thinning", lambda g: 0.5 * g ** -0.4),
    ("shear_thickening", lambda g: 0.5 * g ** 0.3),
    ("yield_stress", lambda g: 3.0 / g + 0.01),  # a stress plateau: slope -1 within the interval
    ("yield_stress", lambda g: (1.0 + g ** 0.5) / g),  # Herschel-Bulkley over 4 decades: the curvature test
])
def test_model_flow_curves_get_their_class(label, viscosity):
    g = np.logspace(-2, 2, 6)
    sigma = np.full(g.size, 0.01)
    result = classify(g, viscosity(g), sigma, replicates=50)
    assert result.label == label
    # the points lie on the curve, so a replicate is the curve plus noise of the stated size: the test keeps its
    # class in at least 95 % of replicates less 3 binomial sigmas (50 replicates), for Newtonian exactly the 95 %
    assert result.confidence >= 0.95 - 3 * math.sqrt(0.95 * 0.05 / 50)
    if label == "shear_thinning":  # a power law: nothing for the yield stress to explain
        assert result.yield_statistic < YIELD_CRITICAL


def test_joint_yield_test_is_the_schwarz_weight_of_the_yield_stress_laws():
    # BIC = -2 ln(evidence): two laws 2 apart have posterior odds e, so the better one's weight is e / (1 + e)
    test = joint_yield_test({"power_law": 10.0, "herschel_bulkley": 8.0})
    assert test.weight == pytest.approx(math.e / (1 + math.e))
    assert (test.best_yield, test.best_other, test.delta_bic) == ("herschel_bulkley", "power_law", 2.0)
    # weights add over laws: two yield laws of equal BIC against one law 2 ln 2 better hold half
    test = joint_yield_test({"herschel_bulkley": 5.0, "bingham": 5.0, "cross": 5.0 - 2 * math.log(2)})
    assert test.weight == pytest.approx(0.5)
    # no decision without laws on both sides, and a failed fit (NaN BIC) takes no part
    assert joint_yield_test({"newtonian": 1.0, "power_law": 0.0}) is None
    assert joint_yield_test({"herschel_bulkley": math.nan, "power_law": 0.0}) is None


def test_paste_start_splits_the_stress_into_yield_and_flow():
    # a Herschel-Bulkley curve τ = τ_y + k γ̇ⁿ started with its own yield share is recovered exactly (the excess is
    # then a power law), and a trace of yield stress on a power law's curve leaves its k and n where they were
    rate = np.logspace(0, 1.5, 5)
    hb = paste_start("herschel_bulkley", FlowCurve(rate, 1.0 + 0.5 * rate ** 0.6), yield_share=1.0 / (1.0 + 0.5))
    assert hb.params_si() == pytest.approx({"tau_y": 1.0, "k": 0.5, "n": 0.6}, rel=1e-5)
    share = 0.01
    traced = paste_start("herschel_bulkley", FlowCurve(rate, 3.0 * rate ** 0.4), yield_share=share)
    assert traced.params_si()["tau_y"] == pytest.approx(share * 3.0, rel=1e-5)
    # the excess 3 γ̇^0.4 − 0.03 is within 1 % of the power law, so its log fit moves n and k by about that share
    assert traced.params_si()["n"] == pytest.approx(0.4, abs=share)
    assert traced.params_si()["k"] == pytest.approx(3.0, rel=2 * share)
    with pytest.raises(ValueError, match="yield_share"):
        paste_start("bingham", FlowCurve(rate, rate), yield_share=1.0)


def test_an_immaterial_yield_stress_counts_as_a_liquid():
    # Herschel-Bulkley 10 better than the power law: odds e^5 for it, unless its yield stress carries less of the
    # slowest stress than the material share, where it is a liquid at the stirred rates
    bics = {"power_law": 10.0, "herschel_bulkley": 0.0}
    material = joint_yield_test(bics, {"herschel_bulkley": 0.3}, min_share=0.1)
    assert material.weight == pytest.approx(math.exp(5) / (1 + math.exp(5)))
    immaterial = joint_yield_test(bics, {"herschel_bulkley": 0.03}, min_share=0.1)
    assert immaterial.weight == 0.0 and immaterial.delta_bic == 10.0  # the evidence is still reported
    assert immaterial.summary()["yield_shares"] == {"herschel_bulkley": 0.03}
    # of two yield laws only the material one counts: one of three equal weights
    both = joint_yield_test({"power_law": 0.0, "herschel_bulkley": 0.0, "bingham": 0.0},
                            {"herschel_bulkley": 0.5, "bingham": 0.01}, min_share=0.1)
    assert both.weight == pytest.approx(1 / 3)


@pytest.mark.parametrize("curve,bics,label", [
    # a power law's points, but the joint fit (through the simulator, which models the plug) needs a yield stress
    (lambda g: 0.5 * g ** -0.4, {"power_law": 10.0, "herschel_bulkley": 0.0}, "yield_stress"),
    # a curved flow curve that the joint fit explains without a yield stress
    (lambda g: (1.0 + g ** 0.5) / g, {"power_law": 0.0, "herschel_bulkley": 3.0}, "shear_thinning"),
    # Newtonian points stay Newtonian without a yield stress, and a rising viscosity is never a yield stress
    (lambda g: 0.5 + 0 * g, {"power_law": 0.0, "herschel_bulkley": 2.0}, "newtonian"),
    (lambda g: 0.5 * g ** 0.3, {"power_law": 10.0, "herschel_bulkley": 0.0}, "shear_thickening"),
])
def test_joint_fit_decides_the_yield_stress(curve, bics, label):
    g = np.logspace(-2, 2, 6)
    points = classify(g, curve(g), np.full(g.size, 0.01), replicates=50)
    test = joint_yield_test(bics)
    result = points.with_joint_yield_test(test)
    assert result.label == label
    # the confidence: the replicates' share of the slope's verdict (rises or not) times the joint fit's weight
    share = points.shares
    if label == "yield_stress":
        expected = (1 - share["shear_thickening"]) * test.weight
    elif label == "shear_thinning":
        expected = (share["shear_thinning"] + share["yield_stress"]) * (1 - test.weight)
    elif label == "newtonian":
        expected = share["newtonian"] * (1 - test.weight)
    else:
        expected = points.confidence
    assert result.confidence == pytest.approx(expected)
    assert result.summary()["yield_test"]["joint"] == (None if label == "shear_thickening" else test.summary())
    assert sum(share.values()) == pytest.approx(1.0)


@pytest.mark.parametrize("index,label", [
    (SlopeEstimate(0.03, 0.02), "newtonian"),        # interval -0.009 to 0.069 holds 0
    (SlopeEstimate(0.10, 0.02), "shear_thickening"),
    (SlopeEstimate(-0.30, 0.05), "shear_thinning"),
])
def test_the_joint_power_laws_index_decides_the_slope_test(index, label):
    # points that lean thinning, as the 5 mm grid's Newtonian-equivalent points of a liquid do: the joint power
    # law's index, with its interval, decides in their place
    g = np.logspace(0, 2, 6)
    points = classify(g, 0.5 * g**-0.1, np.full(g.size, 0.01), replicates=50)
    assert points.label == "shear_thinning"
    result = points.with_slope_estimate(index)
    assert result.label == label and result.estimate is index
    # the confidence: the share of replicates b* ~ N(b, s²) that the same rule puts in the same class
    z = index.value / index.std
    expected = {"newtonian": stats.norm.cdf(Z95 - z) - stats.norm.cdf(-Z95 - z),
                "shear_thickening": stats.norm.sf(Z95 - z), "shear_thinning": stats.norm.cdf(-Z95 - z)}[label]
    assert result.confidence == pytest.approx(expected)
    assert sum(result.shares.values()) == pytest.approx(1.0)
    stated = result.summary()
    assert stated["slope"] == index.value and stated["slope_ci95"] == pytest.approx(list(index.ci95))
    assert stated["points_slope"]["value"] == points.slope.value and stated["slope_source"].startswith("joint")


def test_the_report_says_whether_the_joint_index_and_the_points_agree():
    g = np.logspace(0, 2, 6)
    points = classify(g, 0.5 * g**-0.1, np.full(g.size, 0.01), replicates=0).slope  # slope -0.1, std ~0.004
    near = slope_agreement(points, SlopeEstimate(-0.09, 0.01))
    assert near["agree"] and near["difference"] == pytest.approx(-0.09 - points.value)
    assert near["z"] == pytest.approx(near["difference"] / math.hypot(points.std, 0.01))
    assert not slope_agreement(points, SlopeEstimate(0.06, 0.008))["agree"]  # castor oil on the 5 mm grid


def test_two_reads_of_the_slope_combine_by_inverse_variance_and_widen_where_they_disagree():
    g = np.logspace(0, 2, 6)
    points = classify(g, 0.5 * g**-0.1, np.full(g.size, 0.01), replicates=0).slope
    # consistent reads (|z| ≤ 1): the plain inverse-variance mean and error
    near = SlopeEstimate(points.value + 0.5 * points.std, points.std)
    both = combined_slope(points, near)
    assert both.value == pytest.approx(points.value + 0.25 * points.std)
    assert both.std == pytest.approx(points.std / math.sqrt(2))
    # reads 6 standard errors apart, as the 5 mm grid's points and joint index of castor oil were: the mean leans to
    # the tighter read, and its error is scaled by S = |z| (PDG), so a class the reads disagree on is not certain
    far = SlopeEstimate(points.value + 6 * math.hypot(points.std, 0.3 * points.std), 0.3 * points.std)
    wide = combined_slope(points, far)
    w = np.array([1.0, 1 / 0.09])
    assert wide.value == pytest.approx((w @ [points.value, far.value]) / w.sum())
    assert wide.std == pytest.approx(6.0 * points.std / math.sqrt(w.sum()))
    assert "scale factor 6.00" in wide.source


def test_a_recording_without_a_steady_speed_is_refused_before_any_simulation(monkeypatch):
    def simulated(*args, **kwargs):
        raise AssertionError("simulated before every recording's windows were found")

    monkeypatch.setattr("diffstir.fitting.apparent.window_viscosity", simulated)
    t = np.linspace(0.0, 3.0, 601)
    phase = 2.0 * t**2  # rad: no 0.3 s at one speed (as above)
    unsteady = path_recording(t, 0.015 * np.cos(phase), 0.015 * np.sin(phase))
    with pytest.raises(RecordingError, match="one speed"):
        characterise([programme_recording(), unsteady], config=FAST, density=1000.0)


def test_the_settings_refuse_an_unknown_slope_test_before_simulating():
    with pytest.raises(ConfigError, match="behaviour.slope_test = 'index'; choose from combined, points, joint_index"):
        BehaviourSettings(slope_test="index")
    with pytest.raises(ConfigError, match="add power_law to behaviour.joint_models"):
        BehaviourSettings(slope_test="joint_index", joint_models=["herschel_bulkley"])
    with pytest.raises(ConfigError, match="behaviour.joint_models: unknown casson; choose from bingham"):
        BehaviourSettings(joint_models=["newtonian", "casson"])


def test_a_falling_index_leaves_the_yield_stress_to_the_yield_tests():
    g = np.logspace(-2, 2, 6)
    plateau = classify(g, 2.0 / g + 0.01, np.full(g.size, 0.01), replicates=50)  # a Bingham plastic's points
    assert plateau.label == "yield_stress"
    falling = plateau.with_slope_estimate(SlopeEstimate(-0.8, 0.05))
    assert falling.label == "yield_stress" and falling.shares["shear_thinning"] == 0.0
    # the joint yield test then decides, with the index's share of a falling viscosity
    liquid = falling.with_joint_yield_test(joint_yield_test({"power_law": 0.0, "herschel_bulkley": 6.0}))
    assert liquid.label == "shear_thinning"
    assert liquid.confidence == pytest.approx(falling.shares["yield_stress"] * (1 - liquid.joint.weight))
    # an index the readings do not see leaves the points' verdict
    assert plateau.with_slope_estimate(SlopeEstimate(-0.8, math.inf)) is plateau


def test_a_windows_baseline_does_not_count_as_noise():
    # readings with a baseline b = 4 q on white noise σ: the step estimates b, and the noise's error of ln η is the
    # least-squares one of σ with b a parameter under its prior, not of the larger spread b leaves before the step
    rng = np.random.default_rng(1)
    readings = 0.02 * (1.0 + 0.3 * np.sin(np.linspace(0.0, 6.0, 400)))  # N
    sigma, q = 1e-4, 5e-4  # N
    noise = sigma * rng.normal(size=readings.size)
    _, noise_std, _, baseline = with_baseline(readings, noise + 4 * q, 0.0, q, readings, 0.0)
    design = np.column_stack([readings, np.ones_like(readings)])
    precision = design.T @ design / sigma**2 + np.diag([0.0, 1.0 / q**2])
    expected = math.sqrt(np.linalg.inv(precision)[0, 0])
    # s² from N = 400 white samples: its relative error is √(2/N) = 7 %, N_eff's ~ 10 %; 3σ of both
    assert noise_std == pytest.approx(expected, rel=0.4)
    assert baseline == pytest.approx(4 * q, abs=4 * math.sqrt(np.linalg.inv(precision)[1, 1]))
    # with b read as noise its variance would be (4q)²/σ² = 400 times too large: ln η's error 20 times too wide
    assert noise_std < 2 * expected


def test_window_interval_carries_the_simulators_force_error():
    # a drag p = c η^e read with noise: a relative force error σ_m of the simulator moves ln η by σ_m / e whatever
    # the noise (the readings' Jacobian d p / d ln η is e p); the noise's own error is the least-squares one
    rng = np.random.default_rng(0)
    readings = 0.02 * (1.0 + 0.3 * np.sin(np.linspace(0.0, 6.0, 400)))  # N
    residuals = 1e-4 * rng.normal(size=readings.size)
    for elasticity in (0.1, 0.5, 1.0):
        _, noise_std, model_std, _ = with_baseline(elasticity * readings, residuals, 0.0, 0.0, readings, 0.063)
        assert model_std == pytest.approx(0.063 / elasticity, rel=1e-9)
        jacobian = elasticity * readings
        left = residuals - jacobian * (jacobian @ residuals) / (jacobian @ jacobian)  # after the step
        s2 = left @ left / (residuals.size - 1)
        n_eff = min(effective_samples(left), residuals.size)
        assert noise_std == pytest.approx(math.sqrt(s2 * residuals.size / n_eff / (jacobian @ jacobian)), rel=1e-9)
    assert with_baseline(readings, residuals, 0.0, 0.0, readings, 0.0)[2] == 0.0
    # the inertial part p − J = (1 − e) p errs by σ_i: ln η moves by σ_i (1 − e) / e more, in quadrature
    for elasticity in (0.1, 0.5, 1.0):
        model_std = with_baseline(elasticity * readings, residuals, 0.0, 0.0, readings, 0.03, 0.3)[2]
        assert model_std == pytest.approx(math.hypot(0.03 / elasticity, 0.3 * (1 - elasticity) / elasticity),
                                          rel=1e-9)


def test_classify_refuses_bad_points():
    with pytest.raises(ValueError, match="two speeds"):
        classify([1.0], [0.5], [0.1])
    with pytest.raises(ValueError, match="viscosity must be finite and > 0 \\(Pa s\\)"):
        classify([1.0, 2.0], [0.5, -0.1], [0.1, 0.1])


@pytest.fixture(scope="module")
def lab_recordings():
    return lab_fluid_recordings()


def lab_fluid_recordings() -> dict:
    """A Newtonian (0.5 Pa·s) and a thinning (power law, k = 3 Pa·sⁿ, n = 0.4) fluid of water's density stirred at
    ``SPEEDS`` on FAST, by name."""
    traj = stirring_programme([{"speed": s, "duration": SEGMENT} for s in SPEEDS], radius=0.015, ramp_time=RAMP)
    # 400 Hz: the fit replays the recorded rod path between samples along chords, which at 100 Hz and 0.16 m/s
    # changes the simulated drag by a few per cent (docs/behaviour.md); that is not what these tests are about
    sensor = SensorModel(mode="tangential", sample_rate=400.0, resolution=0.001, noise_std=0.001)
    make = {name: Fluid(name=name, density=1000.0, law=law) for name, law in (
        ("newtonian", {"name": "newtonian", "params": {"eta": 0.5}}),
        ("thinning", {"name": "power_law", "params": {"k": 3.0, "n": 0.4}}))}
    return {name: synthesise(fluid, traj, sim_config=FAST, sensor=sensor, seed=1).recording
            for name, fluid in make.items()}


def test_newtonian_lab_fluid_is_newtonian_and_its_viscosity_is_recovered(lab_recordings):
    result = characterise([lab_recordings["newtonian"]], config=FAST,
                          settings=BehaviourSettings(iterations=2, joint_models=[], replicates=50))
    assert result.classification.label == "newtonian"
    for p in result.points:  # the truth and the fit share the simulator: each interval holds the truth
        lo, hi = p.ci95
        assert lo <= 0.5 <= hi
    assert result.density["source"].startswith("archimedes")
    # each window reads the slice as the cup's rod with the correction of a Newtonian fluid at its speed: C moves
    # with Re by c₅ ≈ 0.004 per unit, so the windows' small differences of η and speed change it by well under 1e-3
    recording = lab_recordings["newtonian"]
    rig = rig_from_recording(recording)
    for p in result.points:
        expected = stir_correction(rig, Newtonian(eta=p.viscosity), 1000.0, p.speed, 0.015).factor
        assert p.slice_factor == pytest.approx(expected, abs=1e-3)
        assert p.summary()["slice_factor"] == p.slice_factor


def test_a_fluid_thicker_than_the_viscosity_cap_is_refused_naming_the_cap(lab_recordings):
    """The 0.5 Pa·s fluid fitted by a simulator capped at 0.2 Pa·s: every window's Newtonian fit ends at the cap,
    above which the reading no longer responds to η, so no window is resolved, and the refusal says why."""
    refusal = (r"\(recording@[^:]+: at the viscosity cap, .*\); raise sim.viscosity_cap \(0.2 Pa s\) with "
               r"sim.viscous_solver=implicit, whose step does not shorten with the viscosity: the windows at it")
    with pytest.raises(RecordingError, match=refusal):
        characterise([lab_recordings["newtonian"]], config=FAST.replace(viscosity_cap=0.2),
                     settings=BehaviourSettings(iterations=2, joint_models=[], replicates=50))


def test_thinning_lab_fluid_and_the_joint_fit(lab_recordings, capsys):
    # the truth is FAST's own simulator, so its inertial force is exact here: σ_i, the 2.5 mm slice's error against
    # a finite-element reference, would be a per-window error this recording does not have (at 0.16 m/s on 1 cm
    # cells the thinned fluid's reading is largely inertial, and σ_i widens n's interval past 1)
    result = characterise([lab_recordings["thinning"]], config=FAST, workers=2, progress=True,
                          settings=BehaviourSettings(iterations=2, joint_models=["newtonian", "power_law"],
                                                     joint_iterations=4, replicates=50, slope_test="joint_index",
                                                     inertial_error=0.0))
    c = result.classification
    # Metzner-Otto: a power law's Newtonian-equivalent viscosity goes as U^(n-1) in creeping flow; inertia and the
    # capped far field flatten it, so the per-speed slope only has to be negative; the joint fit, through the same
    # simulator, must find n itself (four Gauss-Newton steps from the per-speed flow curve's power law converge)
    assert -(1 - 0.4) - Z95 * c.slope.std < c.slope.value < 0
    joint = result.joint
    assert joint.selected == "power_law"  # one more parameter, and BIC still prefers it to Newtonian
    lo, hi = joint.uncertainty["power_law"].ci95["n"]
    assert lo <= 0.4 <= hi
    # slope_test="joint_index": n − 1 with the same interval decides the slope test
    assert c.label == "shear_thinning" and c.estimate.ci95 == pytest.approx((lo - 1, hi - 1))
    # the report holds what decides the class again under any slope test without simulating: its own test gives
    # its own class and confidence back
    summary = json.loads(json.dumps(result.summary()))
    again = reclassify(summary, slope_test="joint_index", replicates=50)
    assert again.label == c.label and again.confidence == pytest.approx(c.confidence, rel=1e-6)
    points = reclassify(summary, slope_test="points", replicates=50)
    assert points.slope.value == pytest.approx(c.slope.value) and points.estimate is None
    combined = reclassify(summary, slope_test="combined", replicates=50)
    assert combined.estimate.source.startswith("points and joint power law index combined")
    # the progress summary counts the windows' simulations and the joint fits' (from the worker processes), the
    # kept fits' at least: the screens and the starts not kept add to them
    line = re.search(r"^behaviour: (\d+) simulations in .+; shear_thinning \(confidence \d\.\d\d\)$",
                     capsys.readouterr().out, re.MULTILINE)
    assert line is not None
    windows = sum(p.evaluations for p in result.points)
    assert int(line[1]) >= windows + sum(f.evaluations for f in joint.fits.values())
    # the laws were fitted in two worker processes, as FitJobs on diffstir.parallel.Workers, whose results equal
    # those fitted in one process (test_identify's test_models_fitted_in_parallel_processes_equal_those_fitted_in_one)


def test_a_report_with_only_the_index_interval_is_decided_again():
    """The saved reports of docs/data/behaviour-paste-programme carry n's 95 % interval but no standard error: the
    index's standard error is the interval's half width over z₉₅, and each report is decided again under every
    slope test (``scripts/behaviour_benchmark.py --from-reports``)."""
    from diffstir.behaviour.pipeline import reported_joint_index

    reports = sorted((ROOT / "docs" / "data" / "behaviour-paste-programme").glob("*.json"))
    assert reports
    for path in reports:
        summary = json.loads(path.read_text(encoding="utf-8"))
        law = summary["joint_fit"]["laws"]["power_law"]
        assert "standard_error" not in law
        lo, hi = law["ci95"]["n"]
        index = reported_joint_index(summary)
        assert index.value == pytest.approx(law["params"]["n"] - 1.0)
        assert index.std == pytest.approx((hi - lo) / (2 * Z95))
        for test in ("points", "joint_index", "combined"):
            assert reclassify(summary, slope_test=test, replicates=50).label in CLASSES
    unidentified = json.loads(reports[0].read_text(encoding="utf-8"))
    unidentified["joint_fit"]["laws"]["power_law"]["ci95"]["n"] = None
    assert reported_joint_index(unidentified).std == math.inf


def test_behaviour_experiment_writes_the_report(lab_recordings, tmp_path, monkeypatch):
    from diffstir.apps.fit import main

    paths = [save_recording(lab_recordings["newtonian"], tmp_path / "a")]
    out = tmp_path / "out"
    monkeypatch.setattr(sys, "argv", ["diffstir-fit", "experiment=behaviour", f"recordings=[{paths[0]}]",
                                      f"out={out}", "sim.dx=0.01", "sim.sound_speed=1.0", "sim.dt_max=0.004",
                                      "sim.viscosity_cap=5.0", "behaviour.iterations=2", "behaviour.joint_models=[]",
                                      "behaviour.replicates=20"])
    main()
    report = json.loads((out / "report.json").read_text())
    b = report["behaviour"]
    assert b["class"] in CLASSES and 0 <= b["confidence"] <= 1
    assert b["slope_ci95"][0] <= b["slope"] <= b["slope_ci95"][1]
    assert b["slope_ci95"][1] - b["slope"] == pytest.approx(Z95 * b["slope_std"])
    assert (out / "viscosity_vs_speed.png").stat().st_size > 0 and (out / "flow_curve.png").stat().st_size > 0


def test_recordings_windows_side_by_side_equal_those_in_one_process(lab_recordings):
    # each recording's windows are one job (its windows in order, each ladder started from the one before); two
    # recordings in two worker processes give the points of one process, in the recordings' order
    recordings = [lab_recordings["newtonian"], lab_recordings["thinning"]]
    one, two = (characterise(recordings, config=FAST, workers=w,
                             settings=BehaviourSettings(iterations=1, joint_models=[], replicates=20))
                for w in (1, 2))
    assert [p.window.label for p in two.points] == [p.window.label for p in one.points]
    assert [p.window.recording.source("csv") for p in two.points][0] == recordings[0].source("csv")
    # one torch thread in a worker, as many as the process has here: the sums' order may differ in the last bits
    assert [p.viscosity for p in two.points] == pytest.approx([p.viscosity for p in one.points], rel=1e-4)
