"""The behaviour experiment's flow-curve analysis (``behaviour.analysis = flow_curve``): each recording's windows read
by simulations of its whole programme (``fitting.programme``), the laws fitted to the points (``behaviour.flow_laws``).
The truth here is the fitting model itself (FAST, test_behaviour), so the points must hold it within their
intervals: what is tested is the iteration and the statistics, not the simulator's accuracy."""

import math

import numpy as np
import pytest
from test_behaviour import FAST, lab_fluid_recordings

from diffstir.behaviour import BehaviourSettings, characterise, reclassify
from diffstir.behaviour.report import markdown
from diffstir.errors import ConfigError
from diffstir.recording import RecordingError
from diffstir.fitting import PROGRAMME_SIMULATIONS, programme
from diffstir.fitting.programme import (BRACKET, MAX_RUNGS, MIN_SLOPE, THICKEST_RUNG, Rungs, _probe_window,
                                       _waveform_estimate)

#: FAST's inertia is its own, so σ_i (the 2.5 mm slice's error against finite elements) is left out (test_behaviour)
SETTINGS = {"analysis": "flow_curve", "replicates": 50, "inertial_error": 0.0}


@pytest.fixture(scope="module")
def lab_recordings():
    return lab_fluid_recordings()


def test_rungs_read_each_window_between_the_two_that_bracket_it():
    # ln M = ln(a + b η) per window: between rungs the reading is interpolated linearly in ln η, beyond them
    # extrapolated from the nearest two, and a window whose reading falls with η has no bracket
    eta = np.array([0.1, 0.3, 1.0])
    sizes = np.log(np.array([[0.01 + 0.02 * e, 0.02 + 0.01 * e, 0.05 - 0.01 * e] for e in eta]))
    rungs = Rungs(eta, sizes)
    log_eta, slope, width = rungs.read(np.log([0.01 + 0.02 * 0.5, 0.02 + 0.01 * 2.0, 0.045]))
    x = np.log(eta)
    expected = x[1] + (np.log(0.02) - sizes[1, 0]) / ((sizes[2, 0] - sizes[1, 0]) / (x[2] - x[1]))
    assert log_eta[0] == pytest.approx(expected) and width[0] == pytest.approx(x[2] - x[1])
    # over a bracket of a factor 1.5 the chord's error in ln M is at most h²/32 (h = ln 1.5; ln M's curvature
    # s (1 − s) ≤ 1/4), 0.5 %, a sixth of the 3 % force error: here s = 1/2 at 0.5 Pa·s
    near = Rungs(np.array([0.4, 0.6]), np.log(0.02 + 0.02 * np.array([[0.4], [0.6]]) / 0.5))
    (log_near,), (s_near,), _ = near.read(np.log([0.04]))
    assert abs(log_near - math.log(0.5)) <= math.log(BRACKET) ** 2 / 32 / s_near
    assert width[1] == math.inf and log_eta[1] > x[2]
    assert width[2] == math.inf and slope[2] < 0


def test_a_window_is_fitted_on_readings_linear_in_viscosity_between_its_rungs():
    """A Stokes drag η w(t) [N] read off rungs a factor 3 apart, from a start in the wrong half of the bracket: the
    fit lands on the truth within its noise interval, and its slope J = d p / d ln η is the local η w, so σ_i finds
    no inertial part p − J to count (a chord in ln η has J = 2 w / ln 3, 1.5 times the local slope at 1.2 Pa·s)."""
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 2.0, 400)
    w = 0.01 * (1.0 + 0.5 * np.sin(3.0 * t))  # N/(Pa·s)
    readings = {eta: eta * w for eta in (1.0, 3.0)}
    truth, offset, noise = 1.2, 0.0005, 1e-4  # Pa·s, N, N
    measured = truth * w + offset + noise * rng.standard_normal(t.size)
    log_eta, log_std, model_log_std, baseline, p = _waveform_estimate(
        readings, measured, np.ones(t.size, bool), math.log(2.5), resolution=0.001, model_error=0.0,
        inertial_error=0.3)
    assert abs(log_eta - math.log(truth)) <= 4 * log_std
    assert model_log_std <= 1e-9
    assert baseline == pytest.approx(offset, abs=4 * noise)
    np.testing.assert_allclose(p, math.exp(log_eta) * w, rtol=1e-12)


def test_a_window_below_a_flat_foot_of_the_ladder_asks_for_no_thinner_rung():
    # a drag under the sensor's resolution reads the noise floor: the sizes of the thinnest rungs no longer fall
    # with η, so a thinner rung cannot bracket the window; it is settled (width 0) and not resolvable, where a
    # window below a foot that still falls with η asks for one (width inf)
    eta = np.array([0.01, 0.1, 1.0])
    sizes = np.log(np.array([[0.003 + 1e-5 * e, 0.003 + 0.01 * e] for e in eta]))  # M [N]: floor + drag
    _, slope, width = Rungs(eta, sizes).read(np.log([0.002, 0.0025]))
    assert width[0] == 0.0 and slope[0] <= MIN_SLOPE
    assert width[1] == math.inf and slope[1] > MIN_SLOPE


def test_k_s_is_measured_on_the_first_window_whose_drag_is_viscous():
    # a thin fluid's slowest window can read the sensor's noise (its size barely grows with η): the probes of k_s
    # go to the first window whose size grows at least half as fast as η, else to the fastest-growing one
    assert _probe_window(np.array([0.1, 0.3, 0.7, 0.9])) == 2
    assert _probe_window(np.array([0.1, 0.3, 0.2])) == 1


def test_a_newtonian_programme_reads_its_viscosity_at_every_window_and_is_newtonian(lab_recordings):
    result = characterise([lab_recordings["newtonian"]], config=FAST, workers=2, settings=BehaviourSettings(**SETTINGS))
    (fit,) = result.programmes
    assert fit.simulations <= PROGRAMME_SIMULATIONS and len(fit.rungs) <= MAX_RUNGS
    brackets = [(max(v for v in fit.rungs if v <= p.viscosity), min(v for v in fit.rungs if v >= p.viscosity))
                for p in fit.points]
    assert all(hi / lo <= BRACKET for lo, hi in brackets) or len(fit.rungs) == MAX_RUNGS
    for p in fit.points:  # the truth is the fitting model: each window's interval holds 0.5 Pa·s
        lo, hi = p.ci95
        assert p.resolvable and lo <= 0.5 <= hi
        assert p.model_log_std >= 0.03 * (1 - 1e-9)  # σ_m / s with s = d ln M / d ln η at most 1
        assert abs(p.baseline) <= 3 * 0.001  # the truth has no offset: b within 3 σ of its prior N(0, q²)
    # every law passes through points that agree within their errors: the Newtonian one needs no more parameters
    assert result.classification.label == "newtonian"
    assert result.joint.selected == "newtonian"
    summary = result.summary()
    assert summary["programmes"][0]["rungs"] == list(fit.rungs)
    assert summary["programmes"][0]["ceiling"] == fit.ceiling == THICKEST_RUNG and fit.diverged == ()
    assert reclassify(summary).label == "newtonian"
    # report.md says of each window whether it is classified, and why not
    rows = [line for line in markdown(summary).splitlines() if line.startswith("| ") and "@" in line]
    assert len(rows) == len(fit.points) and all(row.endswith("| yes |") for row in rows)
    summary["points"][0].update(classified=False, capped=True)
    summary["points"][1].update(classified=False, capped=False)
    rows = [line for line in markdown(summary).splitlines() if line.startswith("| ") and "@" in line]
    assert rows[0].endswith("| no: at the viscosity cap |") and rows[1].endswith("| no: not resolved |")


def test_a_fluid_thicker_than_the_thickest_rung_gets_no_rung_above_it_and_is_refused_naming_it(lab_recordings):
    """The 0.5 Pa·s fluid read by rungs of at most 0.2 Pa·s: above it every rung would read alike, so none is
    simulated there (the ladder climbed to 1000 Pa·s and failed), each window is at the thickest rung, and the
    analysis refuses in one line that names it."""
    capped = FAST.replace(viscosity_cap=0.2)
    refusal = r"at the viscosity cap, .*\); raise behaviour.thickest_rung \(0.2 Pa s\)"
    with pytest.raises(RecordingError, match=refusal):
        characterise([lab_recordings["newtonian"]], config=capped, workers=2,
                     settings=BehaviourSettings(**SETTINGS, thickest_rung=0.2))


def test_rungs_above_the_viscosity_cap_are_simulated_implicitly_and_read_the_fluid(lab_recordings):
    """The 0.5 Pa·s fluid read by a simulator capped at 0.2 Pa·s: the rungs above the cap are simulated with the
    implicit shear stress and the cap at the thickest rung, and every window's interval holds the truth, as with
    the explicit rungs of a higher cap."""
    capped = FAST.replace(viscosity_cap=0.2)
    result = characterise([lab_recordings["newtonian"]], config=capped, workers=2,
                          settings=BehaviourSettings(**SETTINGS))
    (fit,) = result.programmes
    assert any(v > 0.2 for v in fit.rungs) and any(v <= 0.2 for v in fit.rungs)
    for p in fit.points:
        lo, hi = p.ci95
        assert p.resolvable and not p.capped and lo <= 0.5 <= hi


def test_a_rung_diverging_at_its_step_is_simulated_again_at_half_of_it(lab_recordings, monkeypatch):
    """The 0.5 Pa·s fluid whose 1 Pa·s rung diverges at FAST's step (its readings made non-finite here) but not at
    half of it: the ladder keeps the rung from the shorter step and every window's interval holds the truth."""
    class Diverging(programme.ReadingJob):
        def run(self, report):
            readings = super().run(report)
            full_step = self.problem.config.dt_max == FAST.dt_max
            return readings * math.nan if self.key == "rung 1" and full_step else readings

    monkeypatch.setattr(programme, "ReadingJob", Diverging)
    result = characterise([lab_recordings["newtonian"]], config=FAST, workers=1, settings=BehaviourSettings(**SETTINGS))
    (fit,) = result.programmes
    assert 1.0 in fit.rungs
    for p in fit.points:
        lo, hi = p.ci95
        assert p.resolvable and lo <= 0.5 <= hi


def test_a_diverging_rung_is_dropped_and_the_rung_below_it_becomes_the_thickest(lab_recordings, monkeypatch):
    """The 0.5 Pa·s fluid whose 1 Pa·s rung diverges at either step (its readings made non-finite here): the rung
    is dropped with a warning that names it, no rung is simulated above the 0.1 Pa·s one, every window reads at
    it, and the analysis refuses in one line that names the step, not the thickest rung, instead of carrying NaN
    into a law."""
    class Diverging(programme.ReadingJob):
        def run(self, report):
            readings = super().run(report)
            return readings * math.nan if self.key == "rung 1" else readings

    monkeypatch.setattr(programme, "ReadingJob", Diverging)
    refusal = (r"at the viscosity cap.*; use a smaller sim.dt_max \(0.004 s\): the simulations of the 1 Pa s rungs "
               r"diverged, so the windows at 0.1 Pa s read a fluid at least that thick$")
    with pytest.warns(RuntimeWarning, match=r"the 1 Pa s rung's simulation diverged; windows thicker than 0.1 Pa s"):
        with pytest.raises(RecordingError, match=refusal):
            characterise([lab_recordings["newtonian"]], config=FAST, workers=1,
                         settings=BehaviourSettings(**SETTINGS))


def test_the_flow_curve_analysis_classifies_and_fits_the_laws_to_the_points(lab_recordings):
    result = characterise([lab_recordings["thinning"]], config=FAST, workers=2,
                          settings=BehaviourSettings(joint_models=["newtonian", "power_law"], **SETTINGS))
    assert result.classification.label == "shear_thinning"
    summary = result.summary()
    laws = summary["joint_fit"]["laws"]
    assert summary["joint_fit"]["fitted_to"] == "points" and summary["joint_fit"]["selected"] == "power_law"
    lo, hi = laws["power_law"]["ci95"]["n"]
    assert lo <= 0.4 <= hi  # the truth's index (k = 3 Pa·sⁿ, n = 0.4)
    assert laws["newtonian"]["bic"] - laws["power_law"]["bic"] > 10
    assert "slope_check" not in summary["behaviour"]  # the points' power law is their own slope
    assert summary["behaviour"]["laws"]["families"]["power_law"] == "shear_thinning"
    assert result.classification.confidence == pytest.approx(
        sum(w for name, w in summary["behaviour"]["laws"]["weights"].items() if name != "newtonian"))
    assert reclassify(summary).label == "shear_thinning"
    assert "χ²" in result.report()


def test_the_flow_curve_analysis_refuses_the_joint_index_slope_test():
    with pytest.raises(ConfigError, match="behaviour.slope_test"):
        BehaviourSettings(analysis="flow_curve", slope_test="joint_index")
    with pytest.raises(ConfigError, match="behaviour.analysis"):
        BehaviourSettings(analysis="rheometer")


def test_the_rungs_and_points_do_not_depend_on_how_many_processes_simulate_them(lab_recordings):
    # the rounds add RUNGS_PER_ROUND rungs whatever the workers: one process runs them in turn, two side by side
    settings = BehaviourSettings(joint_models=["newtonian", "power_law"], **SETTINGS)
    (alone,), (pair,) = (characterise([lab_recordings["thinning"]], config=FAST, workers=w,
                                      settings=settings).programmes for w in (1, 2))
    assert alone.rungs == pair.rungs and alone.simulations == pair.simulations
    assert [p.viscosity for p in alone.points] == pytest.approx([p.viscosity for p in pair.points], rel=1e-6)
