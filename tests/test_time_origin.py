"""Times on a rig's clock: a recording whose time stamps start at a rig's uptime (1e5 s) or a Unix time (1.7e9 s)
replays to the forces of the same recording at origin 0."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from diffstir.fitting.problem import StirProblem
from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.recording import (CupGeometry, Recording, RecordingWarning, RodGeometry, SensorSpec, load_recording,
                                save_recording)
from diffstir.rheology import Newtonian
from diffstir.trajectory import circle

COARSE = SimConfig(dim=2, dx=0.01, sound_speed=2.0)  # the rod 2.5 cells across: the identification tests' scene


def recording(origin: float) -> Recording:
    """0.3 s of a 15 mm circle at 0.06 m/s sampled at 250 Hz, its sensor stating a 20 ms response, times from
    ``origin`` [s]."""
    traj = circle(radius=0.015, speed=0.06, duration=0.3, ramp_time=0.05, sample_rate=250)
    return Recording(cup=CupGeometry(radius=0.0425, fill_height=0.13), rod=RodGeometry(radius=0.0125,
                     immersion_depth=0.08), sensor=SensorSpec("tangential", time_constant=0.02), density=None,
                     t=traj.t + origin, x=traj.xy[:, 0], y=traj.xy[:, 1], force=np.zeros(traj.t.size))


def replay(rec: Recording) -> np.ndarray:
    with torch.no_grad():
        return StirProblem(rec, COARSE, 1000.0).simulate(Newtonian(eta=0.8)).double().numpy()


@pytest.fixture(scope="module")
def at_zero() -> np.ndarray:
    return replay(recording(0.0))


def test_simulated_step_times_are_float64_on_a_rigs_clock():
    """A float32 time resolves 1 ms at 1e4 s: the mid-step times of a 0.4 ms step would repeat."""
    traj = circle(radius=0.015, speed=0.06, duration=0.05, sample_rate=250)
    sim = StirringSimulator(Newtonian(eta=0.8), config=COARSE, density=1000.0)
    shifted = type(traj)(traj.t + 1e4, traj.xy, traj.z, traj.angle)
    with torch.no_grad():
        times = sim(shifted).times
    assert times.dtype == torch.float64
    assert np.all(np.diff(times.numpy()) > 0)
    np.testing.assert_allclose(times.numpy() - 1e4, sim(traj).times.numpy(), rtol=0, atol=1e-11)


def test_an_uptime_origin_in_memory_replays_to_the_same_forces(at_zero):
    """Times held as 1e5 s + t in float64 (1.5e-11 s spacing): the same readings to float32 round-off of the
    force (the simulation runs in float32; 1e-5 of the largest reading)."""
    shifted = replay(recording(1e5))
    np.testing.assert_allclose(shifted, at_zero, rtol=0, atol=1e-5 * np.abs(at_zero).max())


@pytest.mark.parametrize("origin", [1e5, 1.7e9])
def test_a_recording_on_a_clock_loads_from_its_first_sample(tmp_path, at_zero, origin):
    """Saved with its clock's origin and loaded, a recording counts from its first sample (exactly the times at
    origin 0) and replays to exactly the same readings."""
    rec = recording(0.0)
    rec.time_origin = origin
    path = save_recording(rec, tmp_path / "rec")
    assert (path / "stir.csv").read_text().split("\n")[2].startswith(f"{origin:.1f}"[:-2])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RecordingWarning)  # the zero force of a recording made for replaying
        loaded = load_recording(path, validate=False)
    assert loaded.time_origin == origin
    np.testing.assert_array_equal(loaded.t, rec.t)
    np.testing.assert_array_equal(replay(loaded), at_zero)
