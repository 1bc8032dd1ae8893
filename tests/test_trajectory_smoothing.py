"""The rod's path as the arm moved it: the GCV smoothing spline against scipy's, and the replayed speed, acceleration
and speed windows of circles and speed steps recorded with 1 µm rounding and 20-50 µm jitter at 200 Hz-1 kHz.

Tolerances come from the spline as a filter: on uniform samples h apart it passes Y(ω) / (1 + α h ω⁴), so a stir
of angular frequency ω is slowed by α h ω⁴, and white position noise σ per axis leaves velocity noise
σ_v² = σ² h / (2π) ∫ ω² / (1 + α h ω⁴)² dω and acceleration noise σ_a² = σ² h / (2π) ∫ ω⁴ / (1 + α h ω⁴)² dω.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.interpolate import make_smoothing_spline

from diffstir.fitting.windows import speed_windows
from diffstir.lab.programme import programme_speed, stirring_programme
from diffstir.recording import CupGeometry, Recording, RecordingWarning, RodGeometry, SensorSpec
from diffstir.recording.smoothing import smooth_path, smoothing_spline
from diffstir.trajectory import through_samples

RADIUS, SPEED = 0.015, 0.05  # m, m/s: the circle of the issue
OMEGA = SPEED / RADIUS  # rad/s


def noise_rms(sigma: float, h: float, alpha: float, power: int) -> float:
    """rms of the ``power``/2-th derivative of white noise σ [m] at spacing h [s] through the spline of weight α."""
    c = alpha * h
    integral = quad(lambda w: w**power / (1 + c * w**4) ** 2, -np.inf, np.inf)[0]
    return sigma * math.sqrt(h / (2 * math.pi) * integral)


def recorded(segments, ramp, rate, jitter, step, seed=0):
    """Times [s], recorded positions [m] and true speed [m/s] of a programme on the 15 mm circle."""
    true = stirring_programme(segments, radius=RADIUS, ramp_time=ramp, sample_rate=rate)
    xy = true.xy + np.random.default_rng(seed).normal(0.0, jitter, true.xy.shape) if jitter else true.xy
    if step:
        xy = np.round(step * np.round(xy / step), 12)
    return true.t, xy, np.abs(programme_speed(true.t, segments, ramp))


def path_recording(t, xy):
    return Recording(cup=CupGeometry(radius=0.0425, fill_height=0.13),
                     rod=RodGeometry(radius=0.0125, immersion_depth=0.08), sensor=SensorSpec(mode="tangential"),
                     density=None, t=t, x=xy[:, 0], y=xy[:, 1], force=np.zeros(t.size))


def test_the_gcv_spline_is_scipys_smoothing_spline_at_the_gcv_minimum():
    rng = np.random.default_rng(3)
    t = np.sort(rng.uniform(0.0, 2.0, 300))
    y = 0.01 * np.sin(3.0 * t) + rng.normal(0.0, 1e-4, t.size)
    fit = smoothing_spline(t, y)
    # the same minimiser of Σ (y − g)² + α ∫ g''² at the chosen α
    np.testing.assert_allclose(fit(t), make_smoothing_spline(t, y, lam=fit.alpha)(t), rtol=0, atol=1e-9)
    # and the same fit as scipy's own GCV search (lam=None), within what the steps of the two searches move it
    scipy_gcv = make_smoothing_spline(t, y)(t)
    assert np.sqrt(np.mean((fit(t) - scipy_gcv) ** 2)) < 0.05 * 1e-4
    # GCV leaves residuals of the noise's size: RSS / (n − dof) estimates σ² (σ = 0.1 mm), within 4 / sqrt(2 n)
    assert math.sqrt(fit.residual**2 * t.size / (t.size - fit.dof)) == pytest.approx(1e-4, rel=4 / math.sqrt(600))


CIRCLE = [{"speed": SPEED, "duration": 4.0}]
CASES = {  # rate [Hz], jitter σ [m], written step q [m]: the noise per axis is σ, or q / sqrt(12) for rounding alone
    "200 Hz, 1 µm steps": (200.0, 0.0, 1e-6),
    "1 kHz, 20 µm jitter": (1000.0, 20e-6, 0.0),
    "1 kHz, 50 µm jitter": (1000.0, 50e-6, 0.0),
}


@pytest.mark.parametrize("rate, jitter, step", CASES.values(), ids=CASES.keys())
def test_a_jittered_circle_is_replayed_at_its_true_speed(rate, jitter, step):
    t, xy, true_speed = recorded(CIRCLE, 0.5, rate, jitter, step)
    sigma, h = (jitter or step / math.sqrt(12)), 1.0 / rate
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        replay = through_samples(t, xy, where="run-1/stir.csv")
    axes = smooth_path(t, xy).axes
    # the speed error the filter predicts: its slowing of the stir and the velocity noise it leaves, each the mean
    # over the two axes (the speed error is the velocity error along the path, which turns through both)
    slowing = np.mean([f.alpha * h * OMEGA**4 for f in axes])
    expected = math.hypot(slowing, math.sqrt(np.mean([noise_rms(sigma, h, f.alpha, 2) ** 2 for f in axes])) / SPEED)
    steady = (replay.t > 0.7) & (replay.t < t[-1] - 0.2)  # past the 0.5 s ramp and the spline's end effects
    speed = np.linalg.norm(replay.velocity(), axis=-1)[steady]
    error = np.sqrt(np.mean((speed / np.interp(replay.t[steady], t, true_speed) - 1) ** 2))
    # the rms over ~3 s of a noise correlated over (α h)^(1/4) ≲ 0.1 s is within 1.5 times its expectation
    assert error < 1.5 * expected < 0.03
    # accelerations: the circle's U²/R and the ramp's π U / (2 t_ramp), plus six standard deviations of noise
    acceleration = np.linalg.norm(np.gradient(replay.velocity(), replay.t, axis=0), axis=-1)
    bound = SPEED**2 / RADIUS + math.pi * SPEED / (2 * 0.5) + 6 * max(noise_rms(sigma, h, f.alpha, 4) for f in axes)
    assert acceleration.max() < bound < 2.0  # m/s²: the spline through the samples reached hundreds
    # one warning for jitter, stating it in µm; none for rounding alone
    jitter_warnings = [w for w in caught if issubclass(w.category, RecordingWarning)]
    if jitter:
        assert len(jitter_warnings) == 1
        message = str(jitter_warnings[0].message)
        stated = float(message.split("carry ")[1].split(" µm")[0])
        assert message.startswith("run-1/stir.csv: columns 'x', 'y'")
        assert stated == pytest.approx(jitter * 1e6, rel=0.05)  # √(RSS/n) of n = 8000 draws: within 2 %
    else:
        assert not jitter_warnings


@pytest.mark.parametrize("rate, jitter, step", CASES.values(), ids=CASES.keys())
def test_speed_windows_of_a_jittered_circle_hold_its_speed(rate, jitter, step):
    t, xy, _ = recorded(CIRCLE, 0.5, rate, jitter, step)
    sigma, h = (jitter or step / math.sqrt(12)), 1.0 / rate
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecordingWarning)
        windows = speed_windows(path_recording(t, xy))
    alpha = max(f.alpha for f in smooth_path(t, xy).axes)
    assert len(windows) == 1
    assert windows[0].start < 0.7 and windows[0].end > t[-1] - 0.05  # the ramp ends at 0.5 s
    # a window's mean speed: slowed by α h ω⁴, its noise averaged over the window (bounded here by σ_v itself)
    assert windows[0].speed == pytest.approx(SPEED * (1 - alpha * h * OMEGA**4),
                                             abs=3 * noise_rms(sigma, h, alpha, 2))


STEPS = [{"speed": 0.04, "duration": 1.0}, {"speed": 0.08, "duration": 1.0}, {"speed": 0.16, "duration": 1.0},
         {"speed": 0.0, "duration": 1.0}]


@pytest.mark.parametrize("rate, jitter, step", CASES.values(), ids=CASES.keys())
def test_a_speed_step_programme_keeps_its_steps_ramps_and_stop(rate, jitter, step):
    ramp = 0.1
    t, xy, true_speed = recorded(STEPS, ramp, rate, jitter, step, seed=1)
    sigma, h = (jitter or step / math.sqrt(12)), 1.0 / rate
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecordingWarning)
        replay = through_samples(t, xy)
    axes = smooth_path(t, xy).axes
    noise = max(noise_rms(sigma, h, f.alpha, 2) for f in axes)  # m/s
    speed = np.linalg.norm(replay.velocity(), axis=-1)
    truth = np.interp(replay.t, t, true_speed)
    # everywhere, ramps and stop included, the replayed speed follows the programme: its noise (five σ_v) and a
    # lag of the 0.1 s cosine ramps of at most 5 % of the smallest step, the windows' own speed tolerance
    assert np.max(np.abs(speed - truth)) < 5 * noise + 0.05 * 0.04
    stopped = replay.t > 3.0 + ramp + 0.05
    assert np.max(speed[stopped]) < 5 * noise


@pytest.mark.parametrize("rate, jitter, step", list(CASES.values())[:2], ids=list(CASES.keys())[:2])
def test_speed_windows_of_a_speed_step_programme_are_its_steps(rate, jitter, step):
    """At 50 µm the global GCV smoothing, set by the 0.1 s ramps, leaves the 0.04 m/s step a speed noise whose rate
    over 0.3 s is within 3 σ of the 5 % tolerance: too noisy to call steady (docs/behaviour.md)."""
    ramp = 0.1
    t, xy, _ = recorded(STEPS, ramp, rate, jitter, step, seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecordingWarning)
        windows = speed_windows(path_recording(t, xy))
    assert [w.speed for w in windows] == pytest.approx([0.04, 0.08, 0.16], rel=0.01)
    # each window lies in its step, shortened at each end by at most half the span the rate is read over
    span = 5 * math.sqrt(2) * smooth_path(t, xy).speed_noise * 0.3 / (0.05 * 0.04) + 1.0 / rate
    for k, w in enumerate(windows):
        assert k < w.start < k + ramp + span / 2 + 0.02 and k + 1 - span / 2 - 0.02 < w.end <= k + 1 + 1.0 / rate


def test_a_path_known_to_every_digit_is_replayed_through_its_samples_without_a_warning():
    t, xy, _ = recorded(STEPS, 0.1, 1000.0, 0.0, 0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RecordingWarning)
        replay = through_samples(t, xy)
    np.testing.assert_allclose(replay.poses(t)[0], xy, rtol=0, atol=1e-12)


@pytest.mark.parametrize("jitter", [0.0, 0.1e-6])
def test_a_path_whose_jitter_leaves_the_replayed_speed_alone_raises_no_warning(jitter):
    # 0.1 µm at 1 kHz moves a replay through the raw samples by sqrt(2) σ / h = 0.14 mm/s, 0.3 % of 0.05 m/s:
    # nothing a user need hear of, though it is more than the samples' 1 nm steps explain
    t, xy, _ = recorded([{"speed": SPEED, "duration": 1.0}, {"speed": 2 * SPEED, "duration": 1.0}], 0.1, 1000.0,
                        jitter, 0.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        through_samples(t, xy, where="run-1/stir.csv")
    assert not [w for w in caught if issubclass(w.category, RecordingWarning)]


def test_a_recordings_velocity_is_the_arms_not_the_jitters():
    # what the tangential sensor's direction, the plausibility checks and the dead-start test read of the rod
    t, xy, true_speed = recorded(CIRCLE, 0.5, 1000.0, 30e-6, 1e-6)
    rec = path_recording(t, xy)
    steady = (t > 0.7) & (t < t[-1] - 0.2)
    velocity = rec.velocity()
    direction = velocity[steady] / np.linalg.norm(velocity[steady], axis=-1, keepdims=True)
    true_direction = np.gradient(recorded(CIRCLE, 0.5, 1000.0, 0.0, 0.0)[1], t, axis=0)[steady]
    true_direction /= np.linalg.norm(true_direction, axis=-1, keepdims=True)
    # a difference of raw samples carries sqrt(2) σ / h = 0.042 m/s of noise, 85 % of the speed; the arm's path
    # carries the smoothing spline's velocity noise, bounded in the replay test above by 3 %
    cosine = np.sum(direction * true_direction, axis=-1)
    assert np.degrees(np.arccos(np.clip(cosine, -1, 1))).max() < 3.0
    speed_error = np.linalg.norm(velocity[steady], axis=-1) / true_speed[steady] - 1
    assert np.sqrt(np.mean(speed_error**2)) < 0.03
    np.testing.assert_array_equal(rec.velocity(), velocity)  # computed once, the same each call
