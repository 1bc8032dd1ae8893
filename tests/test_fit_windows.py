"""Fit windows where the signal is: a sensor that wakes late (a dead start) is detected from the readings alone,
reported, and the fit window starts where it wakes; live readings are not taken for a dead start; a sensor silent
throughout is refused before any simulation."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from diffstir.fitting import FitSettings
from diffstir.fitting.problem import DEAD_START_CHANCE, StirProblem, Windows, dead_start
from diffstir.identification import identify
from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.recording import (CupGeometry, Recording, RecordingError, RodGeometry, SensorSpec, load_recording,
                                sensor_reading_np)
from diffstir.rheology import Newtonian
from diffstir.trajectory import circle
from problems import fitted_force

FAST = SimConfig(dim=2, dx=0.01, sound_speed=2.0)  # as tests/test_identify.py: coarse, but the same model
CUP, ROD = CupGeometry(radius=0.0425, fill_height=0.13), RodGeometry(radius=0.0125, immersion_depth=0.08)
SEEDS = 20
EXAMPLES = Path(__file__).resolve().parents[1] / "diffstir" / "data" / "examples"


def thin_film(force, rate, duration, resolution=None, one_sided=True, speed=0.1):
    """A recording of a rod circling at ``speed`` [m/s] read by a one-sided sensor: ``force(t, rng)`` [N]."""
    traj = circle(radius=0.015, speed=speed, duration=duration, ramp_time=0.05, sample_rate=rate)
    sensor = SensorSpec(mode="tangential", one_sided=one_sided, resolution=resolution, sample_rate=rate)
    return Recording(cup=CUP, rod=ROD, sensor=sensor, density=None, t=traj.t, x=traj.xy[:, 0], y=traj.xy[:, 1],
                     force=force(traj.t), name="thin_film")


def test_a_sensor_that_wakes_late_is_a_dead_start_and_the_window_starts_where_it_wakes():
    """The DiffStir authors' sensor: 1 kHz, zero for its first 1.5 s, then a steady 8-11 mN."""
    rng = np.random.default_rng(0)
    rec = thin_film(lambda t: np.where(t < 1.5, 0.0, 0.0095 + rng.uniform(-0.0015, 0.0015, t.size)), 1000.0, 7.5)
    dead = dead_start(rec)
    assert dead.detected and dead.until == pytest.approx(1.499, abs=1e-9)  # the last zero, 1 ms before 1.5 s
    assert dead.summary() == {"detected": True, "until_s": dead.until}
    windows = Windows.of(rec, 2.0, 0.25)
    assert (windows.start, windows.end) == (dead.until, pytest.approx(dead.until + 2.0))
    assert windows.split == pytest.approx(dead.until + 1.5) and windows.dead_start == dead
    problem = StirProblem(rec, FAST, 1000.0, windows)
    assert problem.measured.min() > 0.0075  # every compared sample is live
    assert Windows.of(rec, 10.0, 0.0).end == rec.t[-1]  # clipped to the recording


@pytest.mark.parametrize("name, woke", [("rig_dead_start", 0.4), ("rig_jitter_1khz", None),
                                        ("rig_behaviour_slow", None), ("carreau_example", None)])
def test_the_bundled_recordings_dead_starts_are_read_right(name, woke):
    """The bundled thin film wakes 0.4 s in (its truth file); the other rigs' sensors are live from the start."""
    rec = load_recording(EXAMPLES / name)
    dead = dead_start(rec)
    assert dead.detected == (woke is not None)
    if woke is not None:  # the last dead sample, one 1 ms sample before it wakes
        assert json.loads((EXAMPLES / f"{name}.truth.json").read_text())["sensor"]["dead_start"] == woke
        assert dead.until == pytest.approx(woke - 1e-3, abs=1e-9)
        assert Windows.of(rec, 2.0, 0.25).start == dead.until
    else:
        assert dead.until == rec.t[0] == Windows.of(rec, 2.0, 0.25).start


def test_a_quantised_sensor_that_wakes_late_is_a_dead_start():
    # 100 Hz, 1 mN steps, 0.5 mN noise: a live reading holds its value for 1 sample with chance erf(0.5/(√2·0.5))
    rng = np.random.default_rng(1)
    live = lambda t: np.round((0.02 + rng.normal(0.0, 5e-4, t.size)) / 1e-3) * 1e-3  # noqa: E731
    rec = thin_film(lambda t: np.where(t < 0.6, 0.0, live(t)), 100.0, 2.0, resolution=1e-3)
    dead = dead_start(rec)
    assert dead.detected and dead.until == pytest.approx(0.59, abs=1e-9)
    # the chance that a live reading held its value over those ~55 moving samples
    assert math.erf(0.5e-3 / (math.sqrt(2) * 5e-4)) ** 55 < DEAD_START_CHANCE


@pytest.mark.parametrize("rate", [100.0, 1000.0])
def test_live_readings_are_not_a_dead_start(rate):
    """A reading that rises from zero as the rod starts, a one-sided sensor that reads zero while the force points
    away (every period, the first half-period included), and a noise-free reading quantised at 1 mN."""
    false_alarms = 0
    for seed in range(SEEDS):
        rng = np.random.default_rng(seed)
        rising = thin_film(lambda t: 0.01 * np.minimum(t / 0.05, 1.0) + rng.normal(0.0, 5e-4, t.size), rate, 1.0,
                           resolution=1e-3, one_sided=False)
        false_alarms += dead_start(rising).detected
    assert false_alarms == 0  # each has a chance below DEAD_START_CHANCE: none in 20 but by a 2 % chance
    # the force points away from the sensor for the first half of every 0.94 s period: zero there, live elsewhere
    clipped = thin_film(lambda t: np.maximum(-0.01 * np.sin(2 * np.pi * t / 0.94), 0.0), rate, 3.0)
    assert clipped.force[: int(0.3 * rate)].max() == 0.0 and not dead_start(clipped).detected
    quantised = thin_film(lambda t: np.round(0.01 * np.minimum(t / 0.05, 1.0) / 1e-3) * 1e-3, rate, 1.0,
                          resolution=1e-3, one_sided=False)
    assert not dead_start(quantised).detected


def test_a_sensor_silent_throughout_is_refused_before_any_simulation(monkeypatch):
    def no_simulation(*args, **kwargs):
        raise AssertionError("simulated")

    monkeypatch.setattr(StirringSimulator, "__call__", no_simulation)
    silent = thin_film(lambda t: np.zeros(t.size), 1000.0, 1.0, resolution=1e-4)
    with pytest.raises(RecordingError, match=r"^<unsaved recording 'thin_film'> stir.csv: column 'force' reads 0 N "
                                             r"throughout \(within its resolution of 0.0001 N\); the sensor recorded "
                                             r"no force$"):
        identify(silent, ["newtonian"], config=FAST, density=1000.0, progress=False)


def test_a_fit_after_a_dead_start_reads_the_live_signal_and_reports_the_dead_start():
    """A Newtonian fluid read by a sensor that wakes at 0.2 s: the default window's length (here 0.2 s) from where
    it wakes recovers the viscosity, where the first 0.2 s hold nothing to fit."""
    eta, noise = 0.8, 0.002  # Pa s, N
    traj = circle(radius=0.015, speed=0.06, duration=0.5, ramp_time=0.05, sample_rate=250)
    sensor = SensorSpec(mode="tangential", resolution=0.001, sample_rate=250)
    blank = Recording(cup=CUP, rod=ROD, sensor=sensor, density=None, t=traj.t, x=traj.xy[:, 0], y=traj.xy[:, 1],
                      force=np.zeros(traj.t.size), name="waking")
    t, f = fitted_force(Newtonian(eta=eta), blank, FAST)  # the path the fitter replays, F = F' h C
    force = np.stack([np.interp(traj.t, t, f[:, k]) for k in range(2)], axis=-1)
    reading = sensor_reading_np(force, blank.velocity(), sensor)
    reading += np.random.default_rng(0).normal(0.0, noise, reading.shape)
    rec = Recording(cup=CUP, rod=ROD, sensor=sensor, density=None, t=traj.t, x=traj.xy[:, 0], y=traj.xy[:, 1],
                    force=np.where(traj.t < 0.2, 0.0, reading), name="waking")
    fit = identify(rec, ["newtonian"], config=FAST, density=1000.0, baseline=False, progress=False, size_estimate=False,
                   fit=FitSettings(window=0.2, holdout_fraction=0.0, max_iterations=3))
    lo, hi = fit.uncertainty["newtonian"].ci95["eta"]
    assert lo < eta < hi and fit.uncertainty["newtonian"].identifiable["eta"]
    summary = fit.summary()
    assert summary["dead_start"] == {"detected": True, "until_s": pytest.approx(0.196, abs=1e-9)}
    assert summary["windows"]["start"] == pytest.approx(0.196) and summary["windows"]["end"] == pytest.approx(0.396)
