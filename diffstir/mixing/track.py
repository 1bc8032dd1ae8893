"""The apparent viscosity of a fluid being mixed, over time, from consecutive windows of one recording.

The steady-speed stretches of the recording (``behaviour.speed_windows``) are cut into windows of ``window``
seconds; each window's apparent viscosity η_i ± σ_i (σ_i of ln η_i) comes from a Newtonian fit through the
simulator (``behaviour.window_viscosity``), simulated from the recording's start with a homogeneous fluid. The
time course is summarised by an exponential approach to a plateau, fitted by weighted least squares in ln η at the
windows' mid-times t_i,

    ln η(t) = ln η_∞ + Δ exp(−(t − t_0)/τ),

whose covariance is scaled by the Birge ratio as in ``behaviour.classify``, with τ between half the windows'
spacing and the recording's span (what the windows can resolve). The fluid is homogeneous, as far as
the viscosity tells, once the excess has fallen below the plateau's 95 % half-width,
t_h = t_0 + τ ln(|Δ| / (1.96 σ(ln η_∞))) (t_0 when it starts there), with a delta-method 95 % interval from the
covariance of (Δ, ln τ): ∂t_h/∂Δ = τ/Δ, ∂t_h/∂ln τ = t_h − t_0 (never before t_0; none when t_h = t_0). A course
the approach cannot describe (flat, Δ and τ not separable, or τ on a bound) gets the weighted mean of ln η as its
plateau, t_h = t_0 and τ unknown; the report's time course shows whether that is a plateau or a drift.

The simulator's own force error (``fitting.apparent``: σ_m / e in ln η) is common to every window of one speed:
it does not average out over the windows, so the plateau's interval adds it in full, in quadrature, while the
half-width that decides homogeneity is the noise's alone (a bias of the simulator moves the whole course, not its
shape).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from functools import partial

import numpy as np
from scipy import optimize

from ..errors import ConfigError
from ..fitting import (MODEL_FORCE_ERROR, Z95, Progress, SpeedWindow, ViscosityPoint, WindowsJob, speed_windows,
                       window_event, window_simulations)
from ..mpm import SimConfig
from ..recording import Recording


#: Windows the time course needs: the approach's three parameters and one degree of freedom (``fit_approach``).
MIN_WINDOWS = 4


def time_windows(recording: Recording, window: float) -> list[SpeedWindow]:
    """Consecutive windows of ``window`` [s] (the last one of a stretch may be up to 1.5 times longer) over the
    recording's steady-speed stretches; a recording with fewer than ``MIN_WINDOWS`` of them is refused
    (``ConfigError`` naming the recording and ``mixing.window``), before any simulation."""
    if not window > 0:
        raise ConfigError(f"mixing.window = {window}; expected a positive duration in s")
    out, steady = [], 0.0
    for stretch in speed_windows(recording, min_duration=window):
        count = max(1, int((stretch.end - stretch.start) / window))
        edges = np.linspace(stretch.start, stretch.end, count + 1)
        out += [SpeedWindow(recording, float(a), float(b), stretch.speed) for a, b in zip(edges[:-1], edges[1:])]
        steady += stretch.end - stretch.start
    if len(out) < MIN_WINDOWS:
        raise ConfigError(f"{recording.source('csv')}: {len(out)} window{'' if len(out) == 1 else 's'} of "
                          f"mixing.window = {window:g} s in its {steady:.3g} s of steady stirring; the time course "
                          f"needs at least {MIN_WINDOWS}: record at least {MIN_WINDOWS * window:g} s at one speed, "
                          "or shorten mixing.window")
    return out


@dataclass(frozen=True)
class Approach:
    """The fitted approach ln η(t) = ln η_∞ + Δ exp(−(t − t_0)/τ): ``plateau`` η_∞ [Pa·s] with ``plateau_ci95``,
    ``excess`` Δ [1], ``time_constant`` τ [s] with ``time_constant_ci95``, ``start`` t_0 [s] and the
    ``homogeneity_time`` t_h [s] with ``homogeneity_time_ci95`` (module docstring)."""

    plateau: float
    plateau_ci95: tuple[float, float]
    excess: float
    time_constant: float
    time_constant_ci95: tuple[float, float]
    start: float
    homogeneity_time: float
    homogeneity_time_ci95: tuple[float, float]
    birge: float

    def curve(self, t: np.ndarray) -> np.ndarray:
        """η(t) [Pa·s] at times ``t`` [s]."""
        if not math.isfinite(self.time_constant):
            return np.full(np.shape(t), self.plateau)
        return self.plateau * np.exp(self.excess * np.exp(-(np.asarray(t) - self.start) / self.time_constant))

    @property
    def homogeneity_interval(self) -> tuple[float, float] | None:
        """The 95 % interval of the homogeneity time [s], None where there is none (t_h = t_0)."""
        return self.homogeneity_time_ci95 if all(map(math.isfinite, self.homogeneity_time_ci95)) else None

    def summary(self) -> dict:
        finite = math.isfinite(self.time_constant)
        interval = self.homogeneity_interval
        return {"plateau": self.plateau, "plateau_ci95": list(self.plateau_ci95), "excess_log": self.excess,
                "time_constant": self.time_constant if finite else None,
                "time_constant_ci95": list(self.time_constant_ci95) if finite else None,
                "start": self.start, "homogeneity_time": self.homogeneity_time,
                "homogeneity_time_ci95": list(interval) if interval else None,
                "birge_ratio": self.birge,
                "units": {"plateau": "Pa s", "time_constant": "s", "start": "s", "homogeneity_time": "s"}}


def fit_approach(times, viscosity, log_std, systematic: float = 0.0) -> Approach:
    """The exponential approach (module docstring) to viscosities ``viscosity`` [Pa·s] with standard errors
    ``log_std`` of ln η at ``times`` [s]; needs four windows or more (three parameters and one degree of
    freedom). ``systematic``: a standard error of ln η common to every window [1] (the simulator's), which the
    plateau's interval carries in full and the shape of the course (Δ, τ, the time to homogeneity) does not."""
    t, eta, s = (np.asarray(v, dtype=np.float64) for v in (times, viscosity, log_std))
    if not systematic >= 0.0:
        raise ValueError(f"mixing: systematic = {systematic!r}; expected a standard error of ln eta >= 0")
    if t.size < MIN_WINDOWS:
        raise ValueError(f"mixing: {t.size} windows; the time course needs at least {MIN_WINDOWS} (shorten "
                         "mixing.window)")
    if not (np.all(eta > 0) and np.all(np.isfinite(s)) and np.all(s > 0)):
        raise ValueError("mixing: every window's viscosity (Pa s) and its standard error must be finite and > 0")
    y, t0, span = np.log(eta), float(t[0]), float(t[-1] - t[0])

    def model(tt, a, b, log_tau):
        return a + b * np.exp(-(tt - t0) / np.exp(log_tau))

    # time constants the windows resolve: from half their spacing to the recording's span
    lo, hi = math.log(0.5 * float(np.min(np.diff(t)))), math.log(span)
    starts = [(y[-1], y[0] - y[-1], math.log(span * f)) for f in (0.1, 0.3, 0.9)]
    best = None
    for p0 in starts:
        try:
            with warnings.catch_warnings(), np.errstate(over="ignore"):  # a degenerate fit is handled below
                warnings.simplefilter("ignore", optimize.OptimizeWarning)
                p, cov = optimize.curve_fit(model, t, y, p0=p0, sigma=s, absolute_sigma=True, maxfev=2000,
                                            bounds=([-np.inf, -np.inf, lo], [np.inf, np.inf, hi]))
        except (RuntimeError, ValueError):
            continue
        chi2 = float(np.sum(((y - model(t, *p)) / s) ** 2))
        if best is None or chi2 < best[2]:
            best = (p, cov, chi2)
    if best is None or not np.all(np.isfinite(best[1])) or not lo + 1e-6 < best[0][2] < hi - 1e-6:  # on a bound
        return _constant(t, y, s, systematic)
    p, cov, chi2 = best
    birge2 = max(1.0, chi2 / (t.size - 3))
    se = np.sqrt(np.diag(cov) * birge2)
    a, b, log_tau = p
    tau = math.exp(log_tau)
    half = Z95 * se[0]
    plateau_half = Z95 * math.hypot(se[0], systematic)
    ratio = abs(b) / half if half > 0 else math.inf
    after = tau * math.log(ratio) if ratio > 1 else 0.0  # t_h - t_0
    if after > 0:
        gradient = np.array([0.0, tau / b, after])  # d t_h / d (a, Δ, ln τ)
        spread = Z95 * math.sqrt(float(gradient @ (cov * birge2) @ gradient))
    else:  # an excess within the plateau's half-width from the start: homogeneous from t_0 on, no interval to give
        spread = math.nan
    return Approach(plateau=math.exp(a), plateau_ci95=(math.exp(a - plateau_half), math.exp(a + plateau_half)),
                    excess=float(b),
                    time_constant=tau, time_constant_ci95=(tau * math.exp(-Z95 * se[2]), tau * math.exp(Z95 * se[2])),
                    start=t0, homogeneity_time=t0 + after,
                    homogeneity_time_ci95=(t0 + max(after - spread, 0.0), t0 + after + spread),
                    birge=math.sqrt(birge2))


def _constant(t: np.ndarray, y: np.ndarray, s: np.ndarray, systematic: float) -> Approach:
    """No resolvable approach (a flat course, or Δ and τ not separable): the weighted mean of ln η as the plateau,
    homogeneous from the first window, τ unknown (nan)."""
    w = 1.0 / s**2
    mean = float(np.sum(w * y) / w.sum())
    birge = math.sqrt(max(1.0, float(np.sum(w * (y - mean) ** 2)) / (t.size - 1)))
    half = Z95 * math.hypot(birge / math.sqrt(w.sum()), systematic)
    return Approach(plateau=math.exp(mean), plateau_ci95=(math.exp(mean - half), math.exp(mean + half)), excess=0.0,
                    time_constant=math.nan, time_constant_ci95=(math.nan, math.nan), start=float(t[0]),
                    homogeneity_time=float(t[0]), homogeneity_time_ci95=(math.nan, math.nan), birge=birge)


def track_viscosity(windows: list[SpeedWindow], config: SimConfig, density: float, *,
                    iterations: int = 3, model_error: float = MODEL_FORCE_ERROR,
                    progress: bool = False) -> list[ViscosityPoint]:
    """The apparent viscosity of each of a recording's ``windows`` (``time_windows``; module docstring), with
    ``model_error`` the relative force error of ``config`` (``behaviour.window_viscosity``); ``progress`` shows a
    progress bar of the simulations, one task per window (``fitting.progress``)."""
    expected = {w.label: window_simulations(k > 0, iterations) for k, w in enumerate(windows)}
    with Progress(expected, bar=progress, label="mixing") as tracker:
        job = WindowsJob("windows", "mixing", windows, config, density, iterations, model_error)
        points = job.run(partial(window_event, tracker))
        tracker.close(f"{len(points)} windows")
    return points
