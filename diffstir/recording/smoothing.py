"""The rod's path as the arm moved it, from recorded positions that carry the encoder's or tracker's jitter.

A recorded coordinate y_k = p(t_k) + e_k [m] carries white noise e_k: the rounding of the written values (step q,
rms q / sqrt(12)) and the arm's encoder or tracker jitter (σ_p ~ 10-50 µm). Differentiating the samples, or a
spline through them, turns σ_p into velocity noise of order σ_p / h at sample spacing h [s] (20 µm at 1 kHz:
0.17 m/s peaks on a 0.05 m/s stir) and accelerations of order σ_p / h² (hundreds of m/s²).

``smoothing_spline`` fits the cubic smoothing spline g minimising

    Σ_k (y_k − g(t_k))² + α ∫ g''(t)² dt,

α [s³] chosen by generalized cross-validation (Craven & Wahba 1979), the minimum over α of

    GCV(α) = n RSS(α) / (n − tr A(α))²,

A(α) the hat matrix (g = A y), RSS the residual sum of squares. It needs no noise level: a path sampled to machine
precision gets α → 0 (the interpolating spline), a jittered one the α that balances the noise against the
smoothing's bias. g is found by Reinsch's algorithm (Green & Silverman 1994, ch. 2), a banded solve; tr A from the
band of the inverse of that banded matrix (Hutchinson & de Hoog 1985), for a grid of α at once: O(n) per α, 0.36 s
for 10⁴ samples (scipy's ``make_smoothing_spline`` with ``lam=None``, the same search, 3.6 s; docs/recording-format.md).

For uniform spacing h the spline is the filter G(ω) = Y(ω) / (1 + α h ω⁴): it shrinks a stir of angular
frequency ω by α h ω⁴ and leaves velocity noise of rms σ_v = σ_p (h (α h)^(−3/4) / (8 √2))^(1/2) (from
∫ u² / (1 + u⁴)² du = π / (4 √2)); the tests hold the replayed speed to these.

``smooth_path`` smooths a rod path (t, x, y), each coordinate by ``smoothing_spline``. A circular programme could
instead be smoothed as a circle (fitted centre and radius, the unwrapped phase smoothed); measured on the virtual
lab's programmes (15 mm circle, docs/recording-format.md) that gains at most a third of the speed error at constant
speed and loses a seventh on speed steps, so the coordinates are smoothed, which assumes no shape of the path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.linalg import cho_solve_banded, cholesky_banded

from diffstir.recording.errors import RecordingError

#: Samples per decade of the equivalent kernel's half-width b = (α / h̄)^(1/4) [s] in the coarse GCV grid.
GRID_PER_DECADE = 8
#: Smallest and largest kernel half-width searched, in sample spacings: from the interpolating spline (GCV's
#: minimum there: no noise to remove) to a fifth of the record (a wider kernel smooths nothing GCV would keep).
MIN_WIDTH, MAX_SHARE = 0.25, 0.2
#: A recorded coordinate is not resolved finer than this [m] (no arm's encoder or tracker resolves a nanometre);
#: data written to every digit of a float count as rounded to it.
FINEST_STEP = 1e-9
#: The residual of pure rounding is q / sqrt(12) within a few per cent for n ≥ 100 samples; beyond this factor the
#: residual holds jitter (or the smoothing's bias) and ``smooth_path`` reports it.
JITTER_FACTOR = 1.5
#: Jitter is reported when a path through the raw samples would move the rod this much faster or slower than the
#: arm [1 of the mean speed]: sqrt(2) σ / h, the speed noise of a difference of two samples h apart.
JITTER_SPEED_SHARE = 0.01


def _reinsch_bands(h: np.ndarray):
    """Q^T's three diagonals (n − 2 rows) and the bands of R and M = Q^T Q for knot spacings ``h`` [s]."""
    a, b, c = 1.0 / h[:-1], -1.0 / h[:-1] - 1.0 / h[1:], 1.0 / h[1:]
    r = ((h[:-1] + h[1:]) / 3.0, h[1:-1] / 6.0)
    m = (a**2 + b**2 + c**2, b[:-1] * a[1:] + c[:-1] * b[1:], c[:-2] * a[2:])
    return (a, b, c), r, m


def _apply_q(q: tuple, gamma: np.ndarray) -> np.ndarray:
    """Q γ (n values) for γ of length n − 2."""
    a, b, c = q
    out = np.zeros(gamma.size + 2)
    out[:-2] += a * gamma
    out[1:-1] += b * gamma
    out[2:] += c * gamma
    return out


def _fit(bands: tuple, y: np.ndarray, alphas: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each α: GCV(α), the fitted values g (len(alphas), n) and tr A(α)."""
    q, (r0, r1), (m0, m1, m2) = bands
    n, m = y.size, y.size - 2
    qty = q[0] * y[:-2] + q[1] * y[1:-1] + q[2] * y[2:]
    fitted = np.empty((alphas.size, n))
    inv_d, l1, l2 = np.empty((alphas.size, m)), np.zeros((alphas.size, m)), np.zeros((alphas.size, m))
    for k, alpha in enumerate(alphas):
        ab = np.zeros((3, m))
        ab[0], ab[1, :-1], ab[2, :-2] = r0 + alpha * m0, r1 + alpha * m1, alpha * m2
        chol = cholesky_banded(ab, lower=True)  # B = R + α M = C Cᵀ = L D Lᵀ, L = C diag(1/c)
        fitted[k] = y - alpha * _apply_q(q, cho_solve_banded((chol, True), qty))
        inv_d[k] = chol[0] ** -2.0
        l1[k, :-1], l2[k, :-2] = chol[1, :-1] / chol[0, :-1], chol[2, :-2] / chol[0, :-2]
    # the band of S = B⁻¹ from S = D⁻¹ L⁻¹ + (I − Lᵀ) S, last row first (Hutchinson & de Hoog)
    s0, s1, s2 = np.zeros((alphas.size, m + 2)), np.zeros((alphas.size, m + 2)), np.zeros((alphas.size, m + 2))
    for i in range(m - 1, -1, -1):
        a1, a2 = l1[:, i], l2[:, i]
        s2[:, i] = -(a1 * s1[:, i + 1] + a2 * s0[:, i + 2])
        s1[:, i] = -(a1 * s0[:, i + 1] + a2 * s1[:, i + 1])
        s0[:, i] = inv_d[:, i] - a1 * s1[:, i] - a2 * s2[:, i]
    trace_sm = (s0[:, :m] * m0).sum(1) + 2 * (s1[:, :m - 1] * m1).sum(1) + 2 * (s2[:, :m - 2] * m2).sum(1)
    trace = n - alphas * trace_sm
    rss = ((y[None, :] - fitted) ** 2).sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        gcv = np.where(trace < n - 1e-9, n * rss / (n - trace) ** 2, np.inf)
    return gcv, fitted, trace


@dataclass(frozen=True)
class SmoothFit:
    """A smoothing spline of samples y_k [unit] at times t_k [s]: ``spline`` of t − ``t0`` (natural cubic through
    the fitted values), ``alpha`` [s³] the penalty weight, ``dof`` = tr A [1] its degrees of freedom, ``residual``
    the rms of y − g [unit], ``samples`` n."""

    spline: CubicSpline
    t0: float
    alpha: float
    dof: float
    residual: float
    samples: int

    @property
    def noise(self) -> float:
        """The samples' noise σ [unit] per sample, sqrt(RSS / (n − dof)); 0 for the interpolating spline."""
        return self.residual * math.sqrt(self.samples / (self.samples - self.dof)) if self.alpha > 0 else 0.0

    def velocity_noise(self, spacing: float) -> float:
        """rms velocity noise σ_v [unit/s] the spline leaves on samples ``spacing`` h [s] apart:
        σ (h (α h)^(−3/4) / (8 √2))^(1/2); 0 for the interpolating spline."""
        if self.alpha == 0:
            return 0.0
        return self.noise * math.sqrt(spacing * (self.alpha * spacing) ** -0.75 / (8 * math.sqrt(2)))

    def __call__(self, times: np.ndarray, nu: int = 0) -> np.ndarray:
        """The spline's ``nu``-th derivative at ``times`` [s] (float64, compared relative to t0)."""
        return self.spline(np.asarray(times, dtype=np.float64) - self.t0, nu)


def smoothing_spline(t: np.ndarray, y: np.ndarray) -> SmoothFit:
    """The GCV cubic smoothing spline of ``y`` at strictly increasing times ``t`` [s] (see the module docstring).

    Where GCV falls all the way to the interpolating end of its range (the samples carry no noise that the spline
    tells from the path: a path known to every digit), and for fewer than 8 samples or a constant ``y``, the
    result is the cubic spline through the samples (not-a-knot ends; natural ones would bend a path whose
    curvature at the ends is not zero).
    """
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    t0 = float(t[0])
    rel = t - t0
    if y.size < 8 or np.ptp(y) == 0:
        return SmoothFit(CubicSpline(rel, y), t0, 0.0, float(y.size), 0.0, y.size)
    spacing = float(np.median(np.diff(rel)))
    tau = rel / spacing  # the fit runs in units of the median spacing, where R and α M are of one order
    bands = _reinsch_bands(np.diff(tau))
    widths = np.logspace(math.log10(MIN_WIDTH), math.log10(max(MIN_WIDTH * 10, MAX_SHARE * y.size)),
                         int(GRID_PER_DECADE * math.log10(max(10, MAX_SHARE * y.size / MIN_WIDTH))) + 1)
    gcv, _, _ = _fit(bands, y, widths**4)
    best = int(np.argmin(gcv))
    if best == 0:  # no noise that the spline tells from the path: the interpolating spline
        return SmoothFit(CubicSpline(rel, y), t0, 0.0, float(y.size), 0.0, y.size)
    lo, hi = widths[max(best - 1, 0)], widths[min(best + 1, widths.size - 1)]
    fine = np.geomspace(lo, hi, 9) ** 4
    gcv, fitted, trace = _fit(bands, y, fine)
    best = int(np.argmin(gcv))
    g = fitted[best]
    residual = float(np.sqrt(np.mean((y - g) ** 2)))
    return SmoothFit(CubicSpline(rel, g, bc_type="natural"), t0, float(fine[best] * spacing**3),
                     float(trace[best]), residual, y.size)


def position_step(values: np.ndarray) -> float:
    """The step [m] the recorded ``values`` [m] are written to: the least spacing of their distinct values when
    every value lies on that grid (within 1 % of a step), else FINEST_STEP; never below FINEST_STEP."""
    distinct = np.unique(np.asarray(values, dtype=np.float64))
    if distinct.size < 2:
        return FINEST_STEP
    step = float(np.min(np.diff(distinct)))
    if step <= FINEST_STEP:
        return FINEST_STEP
    steps = (distinct - distinct[0]) / step
    return step if float(np.max(np.abs(steps - np.round(steps)))) < 0.01 else FINEST_STEP


class SmoothPath:
    """A rod path (``t`` [s], x, y [m]) smoothed as the arm moved: each coordinate by ``smoothing_spline``;
    ``jitter`` the rms position residual per axis [m] that the smoothing removed, ``step`` the step [m] the
    positions are written to."""

    def __init__(self, t: np.ndarray, xy: np.ndarray):
        t = np.asarray(t, dtype=np.float64)
        xy = np.asarray(xy, dtype=np.float64).reshape(t.size, 2)
        self.t = t
        self.step = min(position_step(xy[:, 0]), position_step(xy[:, 1]))
        self.axes = (smoothing_spline(t, xy[:, 0]), smoothing_spline(t, xy[:, 1]))
        self.jitter = math.sqrt(0.5 * (self.axes[0].residual ** 2 + self.axes[1].residual ** 2))

    def position(self, times: np.ndarray) -> np.ndarray:
        """Rod axis position [m] (T, 2) at ``times`` [s]."""
        return np.stack([f(times) for f in self.axes], axis=-1)

    def velocity(self, times: np.ndarray) -> np.ndarray:
        """Rod axis velocity [m/s] (T, 2) at ``times`` [s]."""
        return np.stack([f(times, 1) for f in self.axes], axis=-1)

    def acceleration(self, times: np.ndarray) -> np.ndarray:
        """Rod axis acceleration [m/s²] (T, 2) at ``times`` [s]."""
        return np.stack([f(times, 2) for f in self.axes], axis=-1)

    def speed(self, times: np.ndarray) -> np.ndarray:
        """Speed |v| [m/s] at ``times`` [s]."""
        return np.linalg.norm(self.velocity(times), axis=-1)

    @property
    def speed_noise(self) -> float:
        """rms noise [m/s] of ``speed``, at most: the larger of the two axes' velocity noise (the speed error is the
        velocity error along the path, which turns from one axis to the other), and at least the noise that the
        positions' rounding (σ = q / sqrt(12)) leaves on the difference of two samples h apart, sqrt(2) σ / h:
        where GCV keeps the interpolating spline, that rounding is still in the samples it passes through."""
        h = float(np.median(np.diff(self.t)))
        rounding = math.sqrt(2.0) * self.step / math.sqrt(12.0) / h
        return max(rounding, *(f.velocity_noise(h) for f in self.axes))

    def jitter_message(self, where: str) -> str | None:
        """One line stating the jitter removed, when it exceeds the rounding of the data and would change the
        replayed speed by more than ``JITTER_SPEED_SHARE`` of its mean (``where``: the source)."""
        if self.jitter <= JITTER_FACTOR * self.step / math.sqrt(12.0):
            return None
        h = float(np.median(np.diff(self.t)))
        mean_speed = float(np.mean(self.speed(self.t)))
        if math.sqrt(2.0) * self.jitter / h <= JITTER_SPEED_SHARE * mean_speed:
            return None
        return (f"{where}: columns 'x', 'y' carry {self.jitter * 1e6:.3g} µm rms of position jitter, more than "
                f"their {self.step * 1e6:.3g} µm steps explain; the rod is replayed along the smoothing spline of "
                f"its path, which removes it (docs/recording-format.md)")


def smooth_path(t: np.ndarray, xy: np.ndarray) -> SmoothPath:
    """The smoothed rod path of times ``t`` [s] (strictly increasing) and positions ``xy`` [m] (K, 2)."""
    t = np.asarray(t, dtype=np.float64)
    if t.size < 2 or not np.all(np.diff(t) > 0):
        raise RecordingError("rod path: column 't' needs at least 2 strictly increasing times (s)")
    return SmoothPath(t, xy)
