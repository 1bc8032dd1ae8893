"""Sensor modes on hand-computed vectors, their gradients, and resampling between simulation and recording."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from diffstir.recording import (CupGeometry, Recording, RecordingError, RodGeometry, SensorSpec, first_order_response,
                                resample_force, sensor as sensor_module, sensor_reading, sensor_reading_np,
                                simulated_reading, trajectory_at)
from diffstir.recording.sensor import FORCE_EPS, VELOCITY_EPS, sensor_history

F = torch.tensor([[3.0, 4.0], [-2.0, 0.0], [1.0, 1.0], [0.0, -0.5]], dtype=torch.float64)
V = torch.tensor([[0.1, 0.0], [0.2, 0.0], [0.0, -0.05], [0.0, 0.3]], dtype=torch.float64)


def test_component_is_the_force_along_the_axis():
    np.testing.assert_allclose(sensor_reading(F, None, SensorSpec("component", axis=(1.0, 0.0))), [3, -2, 1, 0])
    np.testing.assert_allclose(sensor_reading(F, None, SensorSpec("component", axis=(0.6, 0.8))),
                               [5.0, -1.2, 1.4, -0.4], rtol=1e-15)
    # an axis given to 4 digits is normalised: [0.7071, 0.7071] is 45 degrees
    np.testing.assert_allclose(sensor_reading(F, None, SensorSpec("component", axis=(0.7071, 0.7071))),
                               [7 / math.sqrt(2), -math.sqrt(2), math.sqrt(2), -0.5 / math.sqrt(2)], rtol=1e-15)


def test_tangential_is_the_drag_opposing_the_motion():
    # F . (-v/|v|): [3,4].[-1,0] = -3 (pushes along the motion); [-2,0].[-1,0] = 2; [1,1].[0,1] = 1; [0,-.5].[0,-1]
    expected = [-3.0, 2.0, 1.0, 0.5]
    smoothing = (VELOCITY_EPS / 0.05) ** 2 / 2  # relative error (eps / |v|)² / 2 at the slowest |v| = 0.05 m/s
    np.testing.assert_allclose(sensor_reading(F, V, SensorSpec("tangential")), expected, rtol=1.01 * smoothing)


def test_magnitude_is_the_length_of_the_force():
    np.testing.assert_allclose(sensor_reading(F, None, SensorSpec("magnitude")), [5.0, 2.0, math.sqrt(2), 0.5],
                               rtol=0, atol=FORCE_EPS)
    assert sensor_reading(torch.zeros(1, 2, dtype=torch.float64), None, SensorSpec("magnitude")).item() == 0.0


@pytest.mark.parametrize("spec, expected", [
    (SensorSpec("component", axis=(1.0, 0.0), one_sided=True), [3.0, 0.0, 1.0, 0.0]),
    (SensorSpec("tangential", one_sided=True), [0.0, 2.0, 1.0, 0.5]),
])
def test_one_sided_clips_negative_readings_to_zero(spec, expected):
    np.testing.assert_allclose(sensor_reading(F, V, spec), expected, rtol=2.1e-6)


@pytest.mark.parametrize("mode", ["component", "tangential", "magnitude"])
def test_gradients_are_finite_at_rest_and_zero_force(mode):
    spec = SensorSpec(mode, axis=(1.0, 0.0) if mode == "component" else None)
    force = torch.tensor([[0.0, 0.0], [0.3, -0.1], [0.0, 0.0]], dtype=torch.float64, requires_grad=True)
    velocity = torch.tensor([[0.0, 0.0], [0.0, 0.0], [1e-9, 0.0]], dtype=torch.float64, requires_grad=True)
    reading = sensor_reading(force, velocity, spec)
    reading.sum().backward()
    assert torch.isfinite(force.grad).all()
    if mode == "tangential":
        assert torch.isfinite(velocity.grad).all()
        assert reading.abs().max().item() < 1e-4  # no direction, (almost) no tangential drag
        assert force.grad.abs().max().item() <= 1e-5  # |d reading / d F| = |v| / sqrt(|v|² + eps²)


def test_tangential_matches_its_finite_difference_gradient():
    force = F.clone().requires_grad_(True)
    velocity = V.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda f, v: sensor_reading(f, v, SensorSpec("tangential")), (force, velocity))


def test_numpy_wrapper_matches_torch():
    spec = SensorSpec("tangential")
    np.testing.assert_array_equal(sensor_reading_np(F.numpy(), V.numpy(), spec), sensor_reading(F, V, spec).numpy())


@pytest.mark.parametrize("spec, args, message", [
    (SensorSpec("sideways"), (F, V), "sensor.mode = 'sideways'"),
    (SensorSpec("component"), (F, None), "axis is missing"),
    (SensorSpec("tangential"), (F, None), "needs velocity_xy"),
    (SensorSpec("tangential"), (F, V[:2]), r"velocity_xy has shape \(2, 2\); expected \(4, 2\)"),
    (SensorSpec("magnitude"), (F[:, 0], None), r"force_xy has shape \(4,\)"),
])
def test_bad_sensor_inputs(spec, args, message):
    with pytest.raises(RecordingError, match=message):
        sensor_reading(*args, spec)


# -- resampling ------------------------------------------------------------------------------------------------

def uneven_times(n: int, seed: int, start: float = 0.0) -> np.ndarray:
    return start + np.cumsum(np.random.default_rng(seed).uniform(0.5e-3, 1.5e-3, n))


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_resample_force_is_exact_on_linear_functions(dtype):
    sim_t = uneven_times(3000, 0)
    rec_t = np.sort(np.random.default_rng(1).uniform(sim_t[0], sim_t[-1], 500))
    rec_t[0], rec_t[-1] = sim_t[0], sim_t[-1]
    line = lambda t: np.stack([0.2 - 0.05 * t, 0.01 + 0.3 * t], -1)  # noqa: E731
    force = torch.tensor(line(sim_t), dtype=dtype)
    atol = 1e-14 if dtype == torch.float64 else 1e-6  # float32 rounding of values ~0.5 N
    np.testing.assert_allclose(resample_force(sim_t, force, rec_t).numpy(), line(rec_t), rtol=0, atol=atol)
    np.testing.assert_allclose(resample_force(sim_t, force[:, 0], rec_t).numpy(), line(rec_t)[:, 0], rtol=0,
                               atol=atol)


def test_resample_force_is_differentiable_with_interpolation_weights():
    sim_t = np.array([0.0, 0.1, 0.3])
    force = torch.tensor([1.0, 2.0, 4.0], dtype=torch.float64, requires_grad=True)
    out = resample_force(sim_t, force, [0.05, 0.2, 0.3])
    np.testing.assert_allclose(out.detach(), [1.5, 3.0, 4.0])
    out.sum().backward()
    np.testing.assert_allclose(force.grad, [0.5, 0.5 + 0.5, 0.5 + 1.0])


def test_resample_force_does_not_extrapolate():
    with pytest.raises(RecordingError, match=r"rec_times: time 0.31 s \(index 1\) lies outside \[0.0, 0.3\] s"):
        resample_force(np.array([0.0, 0.1, 0.3]), torch.zeros(3), [0.1, 0.31])
    with pytest.raises(RecordingError, match="strictly increasing"):
        resample_force(np.array([0.0, 0.1, 0.1]), torch.zeros(3), [0.05])


def linear_recording(t: np.ndarray) -> Recording:
    return Recording(cup=CupGeometry(0.0425, fill_height=0.13), rod=RodGeometry(0.0125, 0.08),
                     sensor=SensorSpec("tangential"), density=None, t=t, x=-0.01 + 0.004 * t,
                     y=0.005 - 0.002 * t, force=np.zeros_like(t))


def test_trajectory_at_is_exact_on_a_linear_trajectory():
    rec = linear_recording(uneven_times(2000, 2, start=0.3))
    times = np.linspace(rec.t[0], rec.t[-1], 777)
    positions, velocities = trajectory_at(rec, times)
    np.testing.assert_allclose(positions, np.stack([-0.01 + 0.004 * times, 0.005 - 0.002 * times], -1), atol=1e-15)
    np.testing.assert_allclose(velocities, np.broadcast_to([0.004, -0.002], (777, 2)), atol=1e-11)
    np.testing.assert_array_equal(trajectory_at(rec, rec.t)[1], rec.velocity())
    with pytest.raises(RecordingError, match=r"stir.csv: column 't': time 0.2 s \(index 0\) lies outside"):
        trajectory_at(rec, [0.2])


def test_simulated_drag_reads_as_the_drag_force():
    """A simulated drag F = -c v on a rod circling at 1 Hz reads c |v| on a tangential sensor."""
    t = np.arange(0.0, 2.0 + 1e-9, 0.005)
    phase = 2 * math.pi * t
    rec = Recording(cup=CupGeometry(0.0425, fill_height=0.13), rod=RodGeometry(0.0125, 0.08),
                    sensor=SensorSpec("tangential"), density=None, t=t, x=0.015 * np.cos(phase),
                    y=0.015 * np.sin(phase), force=np.zeros_like(t))
    sim_t = np.arange(0.0, 2.0 + 1e-9, 1e-3)
    sim_phase = 2 * math.pi * sim_t
    c = 2.0  # N s/m
    sim_v = 2 * math.pi * 0.015 * np.stack([-np.sin(sim_phase), np.cos(sim_phase)], -1)
    reading = simulated_reading(rec, sim_t, torch.tensor(-c * sim_v))
    # exact c |v| = 0.1885 N; linear resampling of a 1 Hz signal at 1 ms errs by (2 pi 1e-3)² / 8 = 5e-6 relative,
    # and central differences at 5 ms shorten |v| by (2 pi 5e-3)² / 6 = 1.6e-4 relative
    np.testing.assert_allclose(reading.numpy(), c * 2 * math.pi * 0.015, rtol=2e-4)


@pytest.mark.parametrize("block", [7, 256])
def test_first_order_response_is_exact_for_a_ramp_on_uneven_samples(monkeypatch, block):
    # τ dy/dt = t − y, y(0) = 0: y = t − τ (1 − exp(−t/τ)); exact for input linear between samples, whatever
    # their spacing and however the samples fall into blocks
    monkeypatch.setattr(sensor_module, "RESPONSE_BLOCK", block)
    rng = np.random.default_rng(1)
    times = np.sort(np.concatenate([[0.0], rng.uniform(0.0, 1.0, 600)]))
    tau = 0.05
    exact = times - tau * (1.0 - np.exp(-times / tau))
    ramp = torch.tensor(times)
    assert np.abs(first_order_response(ramp, times, tau).numpy() - exact).max() < 1e-12
    columns = torch.stack([ramp, 2.0 * ramp], dim=1)  # (M, k) responds column by column
    assert np.abs(first_order_response(columns, times, tau).numpy()[:, 1] - 2.0 * exact).max() < 1e-12
    assert first_order_response(ramp, times, None) is ramp and first_order_response(ramp, times, 0.0) is ramp


def test_first_order_response_backpropagates_across_blocks(monkeypatch):
    monkeypatch.setattr(sensor_module, "RESPONSE_BLOCK", 5)
    times = np.cumsum(np.random.default_rng(2).uniform(0.005, 0.015, 23))
    x = torch.randn(23, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: first_order_response(v, times, 0.03), (x,))


def test_first_order_response_refuses_times_that_do_not_fit():
    with pytest.raises(RecordingError, match="strictly increasing time"):
        first_order_response(torch.zeros(3), [0.0, 0.1, 0.1], 0.02)
    with pytest.raises(RecordingError, match="one strictly increasing time"):
        first_order_response(torch.zeros(3), [0.0, 0.1], 0.02)


def test_a_stated_time_constant_delays_the_simulated_reading():
    """A drag that steps on at t = 0.2 s through a sensor stating τ = 30 ms reads c v (1 − exp(−(t − 0.2)/τ))."""
    t = np.arange(0.0, 0.6 + 1e-9, 0.005)
    spec = SensorSpec("component", axis=(1.0, 0.0), time_constant=0.03)
    rec = Recording(cup=CupGeometry(0.0425, fill_height=0.13), rod=RodGeometry(0.0125, 0.08), sensor=spec,
                    density=None, t=t, x=np.zeros_like(t), y=np.zeros_like(t), force=np.zeros_like(t))
    sim_t = np.arange(0.0, 0.6 + 1e-9, 1e-3)
    step = np.where(sim_t >= 0.2, 0.1, 0.0)  # N, switched on between 0.199 and 0.2 s
    reading = simulated_reading(rec, sim_t, torch.tensor(np.stack([step, np.zeros_like(step)], -1))).numpy()
    after = t >= 0.2 + 0.005
    # the reading's samples see a ramp from 0.195 to 0.2 s instead of the step, so the response lies between the
    # step responses starting at 0.195 and at 0.2 s
    lo = 0.1 * (1.0 - np.exp(-(t[after] - 0.2) / 0.03))
    hi = 0.1 * (1.0 - np.exp(-(t[after] - 0.195) / 0.03))
    assert np.all(reading[after] >= lo - 1e-12) and np.all(reading[after] <= hi + 1e-12)
    assert np.all(reading[t < 0.195] == 0.0)


def test_first_order_response_to_a_sinusoid_has_the_first_order_gain_and_phase():
    omega, tau = 2 * math.pi * 1.5, 0.03  # rad/s, s
    times = np.linspace(0.0, 4.0, 4001)
    y = first_order_response(torch.tensor(np.sin(omega * times)), times, tau).numpy()
    steady = times > 10 * tau  # the start's transient decays as exp(−t/τ)
    expected = np.sin(omega * times - math.atan(omega * tau)) / math.hypot(1.0, omega * tau)
    # the sinusoid is linear between samples only to O((ω h)²/8) = 1e-5
    assert np.abs(y[steady] - expected[steady]).max() < 1e-4


def test_a_one_sided_sensor_clips_what_its_element_responds_with():
    # a drag that reverses: the element lags the signed force and the one-sided reading is the clip of that,
    # so the reading stays positive for a while after the force turns negative (clipping first would not)
    times = np.arange(0.0, 1.0, 0.001)
    force = torch.tensor(np.stack([np.where(times < 0.5, 0.1, -0.1), np.zeros_like(times)], -1))
    spec = SensorSpec("component", axis=(1.0, 0.0), one_sided=True, time_constant=0.05)
    reading = sensor_history(force, None, times, spec).numpy()
    # τ dy/dt = x − y from 0.1 towards −0.1: y = −0.1 + 0.2 exp(−(t − 0.5)/τ), positive until 0.5 + τ ln 2
    crossing = 0.5 + 0.05 * math.log(2.0)
    assert np.all(reading[(times > 0.5) & (times < crossing - 0.002)] > 0)
    assert np.all(reading[times > crossing + 0.002] == 0) and np.all(reading >= 0)
