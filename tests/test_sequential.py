"""The sequential mode (``planning.sequential``): the next segment from the stir so far, against closed forms."""

import dataclasses
import math

import numpy as np
import pytest
from test_planning import viscous_calibration

from diffstir.fitting import FitModel, law_family, schwarz_weights
from diffstir.planning import PlanSettings, Prior, Window, window_points
from diffstir.planning.sequential import DECIDED, StirSoFar, next_segment, shortest_stir

SETTINGS = PlanSettings(speeds=(0.01, 0.02, 0.04, 0.08, 0.16), radius=0.015)
CALIBRATION = viscous_calibration(inertial=0.01)


def stir_of(law: FitModel, speeds, log_std=0.03, elapsed=None) -> StirSoFar:
    """Points that lie on ``law`` exactly, each with the error ``log_std`` of ln η."""
    rates = [CALIBRATION.shear_rate(u) for u in speeds]
    eta = law.viscosity_values(np.array(rates))
    return StirSoFar(tuple(speeds), tuple(rates), tuple(float(v) for v in eta), (log_std,) * len(speeds),
                     2.0 * len(speeds) if elapsed is None else elapsed)


def test_a_thinning_and_a_newtonian_stir_over_a_decade_are_decided():
    thinning = next_segment(stir_of(FitModel.named("power_law", k=1.0, n=0.5), (0.01, 0.04, 0.16)), CALIBRATION)
    assert thinning.decided and thinning.family == "shear_thinning" and thinning.confidence >= DECIDED
    assert thinning.speed is None
    newtonian = next_segment(stir_of(FitModel.named("newtonian", eta=0.65), (0.01, 0.04, 0.16)), CALIBRATION)
    assert newtonian.decided and newtonian.family == "newtonian"


def test_one_point_decides_nothing_and_its_gain_is_lindleys():
    # one law (no rival, no evidence): the next window's score is ½ ln((Λ + s²/σ_U²) / Λ) with Λ the prior's
    # precision plus the point's 1/σ²; every law passes through one point, so no family is named yet
    prior = Prior(laws=("newtonian",))
    law = FitModel.named("newtonian", eta=0.65)
    so_far = stir_of(law, (0.04,), log_std=0.05)
    step = next_segment(so_far, CALIBRATION, prior, SETTINGS)
    assert not step.decided and step.family is None and step.confidence == 0.0
    assert step.speed in SETTINGS.levels() and step.speed == max(step.rates, key=step.rates.get)
    rate = CALIBRATION.shear_rate(0.04)
    precision = prior.precision("newtonian", rate)[0] + 1 / 0.05**2
    for speed, score in step.scores.items():
        ramp = SETTINGS.arm.ramp_time(speed, SETTINGS.min_ramp)  # from rest
        duration = shortest_stir(speed, SETTINGS.budget / SETTINGS.max_segments, ramp, SETTINGS)
        samples = int((duration - ramp - SETTINGS.settle_time) * SETTINGS.sample_rate)
        (point,) = window_points([Window(speed, samples)], law, CALIBRATION, SETTINGS.errors)
        information = point.gradient[0] ** 2 / point.log_error**2
        assert score == pytest.approx(0.5 * math.log((precision + information) / precision), rel=1e-9)
        assert step.durations[speed] == duration and step.rates[speed] == score / duration


def test_an_undecided_stir_asks_for_a_segment_while_the_budget_holds_one():
    # two points 1.5 apart in ln γ̇ with 30 % errors cannot tell a weak thinning from a Newtonian fluid
    law = FitModel.named("power_law", k=1.0, n=0.9)
    step = next_segment(stir_of(law, (0.02, 0.04), log_std=0.3), CALIBRATION, settings=SETTINGS)
    assert not step.decided and step.speed in SETTINGS.levels()
    assert step.ramp_time >= SETTINGS.min_ramp
    spent = next_segment(stir_of(law, (0.02, 0.04), log_std=0.3, elapsed=7.0), CALIBRATION, settings=SETTINGS)
    assert not spent.decided and spent.speed is None and not spent.scores


def test_a_report_gives_its_classified_points_with_their_errors_its_laws_and_its_recordings_length():
    z = 1.959963984540054
    summary = {"joint_fit": {"fitted_to": "points", "laws": {"newtonian": {}, "power_law": {}}}, "points": [
        {"window": "a@0.19-1s", "end": 1.0, "speed": 0.01, "shear_rate": 0.9, "viscosity": 1.0,
         "viscosity_ci95": [0.0, math.inf], "classified": False},
        {"window": "a@1.19-2s", "end": 2.0, "speed": 0.04, "shear_rate": 3.6, "viscosity": 0.5,
         "viscosity_ci95": [0.5 * math.exp(-0.1 * z), 0.5 * math.exp(0.1 * z)], "classified": True},
        {"window": "b@0.39-2s", "end": 2.0, "speed": 0.16, "shear_rate": 14.4, "viscosity": 0.3,
         "viscosity_ci95": [0.3 * math.exp(-0.2 * z), 0.3 * math.exp(0.2 * z)], "classified": True}]}
    so_far = StirSoFar.from_report(summary)
    assert so_far.speeds == (0.04, 0.16) and so_far.log_std == (pytest.approx(0.1), pytest.approx(0.2))
    assert so_far.rate_per_speed == pytest.approx(90.0)  # k_s / a [1/m]
    assert so_far.elapsed == 4.0  # two recordings of 2 s, the unresolved window's counted
    assert so_far.laws == ("newtonian", "power_law")


def test_the_stir_is_judged_by_the_laws_its_analysis_fitted():
    # two points a factor 4 apart, n = 0.9 with 10 % errors: the flow-curve analysis's laws (the power law among
    # them) give the family and confidence its report states, the Schwarz weight of the best law's family
    laws = ("newtonian", "power_law", "carreau", "cross", "herschel_bulkley")
    points = dataclasses.replace(stir_of(FitModel.named("power_law", k=0.3, n=0.9), (0.02, 0.08), log_std=0.1),
                                 laws=laws)
    step = next_segment(points, CALIBRATION, settings=SETTINGS)
    fits = points.fits(laws)
    band = (min(points.shear_rates), max(points.shear_rates))
    families = {name: law_family(fit.model, fit.theta, fit.uncertainty, band, math.sqrt(band[0] * band[1]))["class"]
                for name, fit in fits.items()}
    weights = schwarz_weights({name: fit.bic for name, fit in fits.items()})
    best = min(fits, key=lambda name: fits[name].bic)
    assert step.family == families[best]
    assert step.confidence == pytest.approx(sum(w for name, w in weights.items() if families[name] == step.family))


def test_the_next_stir_starts_from_rest():
    law = FitModel.named("power_law", k=1.0, n=0.9)
    step = next_segment(stir_of(law, (0.02, 0.04), log_std=0.3), CALIBRATION, settings=SETTINGS)
    assert step.ramp_time == SETTINGS.arm.ramp_time(step.speed, SETTINGS.min_ramp)
    programme = step.programme(0.015)
    assert programme["segments"] == [{"speed": step.speed, "duration": step.duration}]
    assert programme["radius"] == 0.015 and programme["ramp_time"] == step.ramp_time


def test_a_slow_stir_lasts_a_turn_of_the_circle_as_a_recording_must():
    # a recording spans one stirring period (recording.validate): from rest on a 15 mm circle, about one turn,
    # 2 pi r / U, plus the ramp's lost travel and the 0.1 s steps; a fast stir keeps the plan's 2 s segment, and
    # 0.01 m/s, whose turn takes 9.4 s, does not fit the 8 s budget
    for speed in (0.02, 0.04):
        turn = 2 * math.pi * SETTINGS.radius / speed
        assert turn <= shortest_stir(speed, 2.0, 0.2, SETTINGS) <= turn + 0.2 + 0.1
    assert shortest_stir(0.16, 2.0, 0.2, SETTINGS) == 2.0
    assert shortest_stir(0.01, 2.0, 0.2, SETTINGS) == math.inf
