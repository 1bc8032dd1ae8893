"""Conditioning of the measured force: the paper's dry-run baseline and its adaptive Gaussian filter.

Dry-run baseline (paper, "Calibration and Data Processing"): a run without fluid gives the non-fluidic force,
which is subtracted from the stir's force. Two readings of "dry run":

- ``mean``: the rod held still in air; the baseline is the mean force, the grip preload on the sensor plus
  its offset: F_fluid(t) = F(t) - mean(F_dry).
- ``profile``: the stirring programme run in air; the baseline is the dry force against programme time tau
  (time since the arm started the programme), which also holds the rod's inertial and cable forces:
  F_fluid(tau) = F(tau) - F_dry(tau), F_dry linearly interpolated, held constant outside the dry run.

Adaptive Gaussian filter (the paper names it without defining it; this is the definition used here): a
Gaussian kernel smoother whose width is chosen per sample by the intersection-of-confidence-intervals rule
(Katkovnik, 1999; Goldenshluger and Nemirovski, 1997). For widths h_1 < h_2 < ... (a factor sqrt 2 apart),

    y_k(t_i) = sum_j w_ij y_j / sum_j w_ij,    w_ij = exp(-(t_j - t_i)^2 / (2 h_k^2)),
    s_k(t_i) = sigma sqrt(sum_j w_ij^2) / sum_j w_ij,

with sigma the noise, estimated robustly as 1.4826 MAD(diff y) / sqrt 2 (white noise assumed). The width at
t_i is the largest h_k for which the intervals [y_l - Gamma s_l, y_l + Gamma s_l], l <= k, still intersect:
wide where the force is flat (noise averages out), narrow where it bends or jumps (no smearing). Sampling may
be non-uniform.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Baseline:
    """The non-fluidic force of a dry run (module docstring).

    Attributes:
        mode: ``"mean"`` or ``"profile"``.
        mean: mean dry-run force [N].
        std: standard deviation of the dry-run force [N], the sensor's noise at rest.
        t: programme times of the dry run [s] (profile mode), else None.
        force: dry-run force at ``t`` [N] (profile mode), else None.
    """

    mode: str
    mean: float
    std: float
    t: np.ndarray | None = None
    force: np.ndarray | None = None

    @classmethod
    def from_dry_run(cls, t, force, mode: str = "mean") -> "Baseline":
        """Baseline from a dry run's programme times ``t`` [s] and forces ``force`` [N]."""
        t, force = np.asarray(t, dtype=np.float64), np.asarray(force, dtype=np.float64)
        keep = np.isfinite(force)
        t, force = t[keep], force[keep]
        if force.size < 2:
            raise ValueError(f"dry run has {force.size} valid samples; need at least 2 for a baseline")
        if mode == "mean":
            return cls("mean", float(force.mean()), float(force.std(ddof=1)))
        if mode == "profile":
            return cls("profile", float(force.mean()), float(force.std(ddof=1)), t, force)
        raise ValueError(f"baseline mode {mode!r}; expected 'mean' or 'profile'")

    def __call__(self, t) -> np.ndarray:
        """Baseline force [N] at programme time(s) ``t`` [s]."""
        t = np.asarray(t, dtype=np.float64)
        if self.mode == "mean":
            return np.full_like(t, self.mean)
        return np.interp(t, self.t, self.force)

    def subtract(self, t, force) -> np.ndarray:
        """The fluid's force [N]: ``force`` [N] minus the baseline at programme times ``t`` [s]."""
        return np.asarray(force, dtype=np.float64) - self(t)


@dataclass(frozen=True)
class Smoothed:
    """Output of ``adaptive_gaussian``: the filtered ``force`` [N], the kernel ``width`` chosen per sample [s]
    and the estimated white ``noise`` of the input [N]."""

    force: np.ndarray
    width: np.ndarray
    noise: float


def robust_noise(y) -> float:
    """White-noise standard deviation from first differences: 1.4826 MAD(diff y) / sqrt 2."""
    d = np.diff(np.asarray(y, dtype=np.float64))
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2))


def gaussian_smooth(t, y, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian kernel smoother of fixed ``width`` [s] (kernel cut at 4 widths) on any sampling.

    Returns the smoothed values and the noise gain sqrt(sum w^2) / sum w of each output sample.
    """
    t, y = np.asarray(t, dtype=np.float64), np.asarray(y, dtype=np.float64)
    lo = np.searchsorted(t, t - 4 * width, "left")
    hi = np.searchsorted(t, t + 4 * width, "right")
    span = int((hi - lo).max())
    out, gain = np.empty_like(y), np.empty_like(y)
    rows = max(1, 2_000_000 // span)
    for s in range(0, t.size, rows):
        e = min(s + rows, t.size)
        idx = lo[s:e, None] + np.arange(span)
        valid = idx < hi[s:e, None]
        idx = np.minimum(idx, t.size - 1)
        w = np.exp(-0.5 * ((t[idx] - t[s:e, None]) / width) ** 2) * valid
        sw = w.sum(axis=1)
        out[s:e] = (w * y[idx]).sum(axis=1) / sw
        gain[s:e] = np.sqrt((w * w).sum(axis=1)) / sw
    return out, gain


def adaptive_gaussian(t, force, *, min_width: float | None = None, max_width: float | None = None,
                      gamma: float = 1.5, noise: float | None = None) -> Smoothed:
    """Adaptive Gaussian filter of ``force`` [N] sampled at increasing times ``t`` [s] (module docstring).

    Args:
        min_width: narrowest kernel [s]; default the median sample spacing.
        max_width: widest kernel [s]; default 64 times ``min_width``.
        gamma: confidence-interval half-width in noise standard deviations (1-2: smaller follows curvature more
            closely, larger smooths flat stretches more).
        noise: white-noise standard deviation of ``force`` [N]; default ``robust_noise(force)``.
    """
    t, y = np.asarray(t, dtype=np.float64), np.asarray(force, dtype=np.float64)
    if t.ndim != 1 or t.shape != y.shape or t.size < 3:
        raise ValueError(f"adaptive_gaussian: t and force must be 1-D of one length >= 3; got {t.shape}, "
                         f"{y.shape}")
    if not np.all(np.diff(t) > 0):
        raise ValueError("adaptive_gaussian: t must increase strictly")
    h0 = float(np.median(np.diff(t))) if min_width is None else min_width
    h1 = 64 * h0 if max_width is None else max_width
    if not 0 < h0 <= h1:
        raise ValueError(f"adaptive_gaussian: need 0 < min_width ({h0} s) <= max_width ({h1} s)")
    sigma = robust_noise(y) if noise is None else noise
    widths = h0 * np.sqrt(2.0) ** np.arange(int(math.floor(2 * math.log2(h1 / h0) + 1e-9)) + 1)
    lower = np.full_like(y, -np.inf)
    upper = np.full_like(y, np.inf)
    alive = np.ones(y.shape, dtype=bool)
    chosen = np.zeros_like(y)
    width = np.zeros_like(y)
    for h in widths:
        est, gain = gaussian_smooth(t, y, float(h))
        lower = np.maximum(lower, est - gamma * sigma * gain)
        upper = np.minimum(upper, est + gamma * sigma * gain)
        alive &= lower <= upper
        chosen = np.where(alive, est, chosen)
        width = np.where(alive, h, width)
    return Smoothed(chosen, width, sigma)
