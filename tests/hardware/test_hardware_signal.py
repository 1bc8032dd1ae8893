"""Signal conditioning and timing: the dry-run baseline, the adaptive Gaussian filter, clock alignment."""

from __future__ import annotations

import numpy as np
import pytest

from diffstir.hardware import Baseline, ClockAligner, adaptive_gaussian, align_clocks, gaussian_smooth, robust_noise

FS = 200.0  # Hz


def test_baseline_mean_and_profile():
    tau = np.arange(0, 2, 1 / FS)
    dry = 1.5 + 0.1 * np.sin(2 * np.pi * tau)  # N: preload plus an inertial force along the programme
    mean = Baseline.from_dry_run(tau, dry, "mean")
    assert mean.mean == pytest.approx(1.5, abs=1e-3) and mean(0.7) == pytest.approx(mean.mean)
    profile = Baseline.from_dry_run(tau, dry, "profile")
    t = np.array([0.1234, 1.5, 9.0])  # s; past the dry run the last value is held
    assert profile.subtract(t, 1.5 + 0.1 * np.sin(2 * np.pi * t) + 0.02)[:2] == pytest.approx([0.02, 0.02],
                                                                                              abs=1e-3)
    with pytest.raises(ValueError, match="'mean' or 'profile'"):
        Baseline.from_dry_run(tau, dry, "median")


def test_robust_noise_ignores_steps():
    rng = np.random.default_rng(0)
    y = 0.01 * rng.standard_normal(4000) + np.repeat([0.0, 1.0, -2.0, 0.5], 1000)
    assert robust_noise(y) == pytest.approx(0.01, rel=0.05)


def test_adaptive_gaussian_lowers_noise_and_keeps_a_step_in_place():
    rng = np.random.default_rng(1)
    t = np.arange(0, 2, 1 / FS)
    step_at, sigma = 1.0025, 0.01  # s (between samples), N
    truth = 0.1 * (t >= step_at)
    out = adaptive_gaussian(t, truth + sigma * rng.standard_normal(t.size))
    assert out.noise == pytest.approx(sigma, rel=0.15)
    flat = (np.abs(t - step_at) > 0.3) & (t > 0.1) & (t < 1.9)
    assert np.std(out.force[flat] - truth[flat]) < sigma / 4
    i = np.argmax(out.force > 0.05)  # the half-height crossing, interpolated
    crossing = np.interp(0.05, out.force[i - 1:i + 1], t[i - 1:i + 1])
    assert abs(crossing - step_at) <= out.width[i]
    assert out.width[i] <= 4 / FS and np.median(out.width[flat]) > 10 * out.width[i]  # narrow only at the step


def test_adaptive_gaussian_beats_the_raw_signal_on_a_stirring_force():
    rng = np.random.default_rng(2)
    t = np.sort(rng.uniform(0, 8, 1600))  # non-uniform sampling
    truth = 0.3 * np.sin(2 * np.pi * 0.5 * t) + 0.05 * np.sin(2 * np.pi * 2 * t)
    y = truth + 0.02 * rng.standard_normal(t.size)
    out = adaptive_gaussian(t, y)
    rms = lambda e: float(np.sqrt(np.mean(e**2)))  # noqa: E731
    assert rms(out.force - truth) < 0.5 * rms(y - truth)


def test_gaussian_smooth_noise_gain():
    t = np.arange(0, 1, 1 / FS)
    smooth, gain = gaussian_smooth(t, np.ones_like(t), 0.02)
    assert smooth == pytest.approx(1.0)
    # interior gain of a sampled Gaussian: 1 / sqrt(2 sqrt(pi) h fs)
    assert gain[100] == pytest.approx(1 / np.sqrt(2 * np.sqrt(np.pi) * 0.02 * FS), rel=0.01)


def test_adaptive_gaussian_checks_inputs():
    with pytest.raises(ValueError, match="increase strictly"):
        adaptive_gaussian([0.0, 1.0, 1.0, 2.0], [0.0, 1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="min_width"):
        adaptive_gaussian([0.0, 1.0, 2.0], [0.0, 1.0, 2.0], min_width=2.0, max_width=1.0)


@pytest.mark.parametrize("n, mean_delay", [(200, 2e-3), (4000, 5e-3)])
def test_clock_alignment_recovers_offset_and_drift(n, mean_delay):
    """Arrival = offset + (1 + drift) tau + d_min + exponential delay of mean mu. The lower envelope's error is
    set by the few smallest delays, of order mu / n; the tolerance is 20 mu / n."""
    rng = np.random.default_rng(n)
    tau = 3.0 + np.arange(n) / FS
    offset, drift, d_min = 1234.5, 80e-6, 1e-3
    arrival = offset + (1 + drift) * tau + d_min + rng.exponential(mean_delay, n)
    arrival = np.maximum.accumulate(arrival)  # a serial port delivers in order
    fit = align_clocks(tau, arrival)
    error = fit.to_host(tau) - (offset + (1 + drift) * tau + d_min)
    assert np.max(np.abs(error)) < 20 * mean_delay / n
    assert fit.rate - 1 == pytest.approx(drift, abs=20 * mean_delay / (n * (tau[-1] - tau[0])))
    assert fit.points == n


def test_clock_aligner_edge_cases():
    clock = ClockAligner(latency=0.002)
    clock.add(1.0, 11.0)
    assert clock.fit().to_host(2.0) == pytest.approx(12.0 - 0.002)
    clock.add(1.0, 10.5)  # same device time arriving earlier: the earlier arrival bounds the offset
    clock.add(2.0, 11.5)
    assert (clock.fit().offset, clock.fit().rate) == pytest.approx((9.5, 1.0))
    with pytest.raises(ValueError, match="went back"):
        clock.add(1.5, 12.0)
    with pytest.raises(ValueError, match="no samples"):
        ClockAligner().fit()
