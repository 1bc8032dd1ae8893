"""Where a fit's residual r(t) = measured − simulated [N] sits: in time, in regime and in frequency.

* **Time.** Each sample gets the phase of the rod's programme: ``stop`` (speed below 5 % of the top speed),
  ``reversal`` and ``start-up`` (the first T_tr after motion starts, in the opposite or the first direction),
  ``speed change`` (|d speed/dt| above 10 % of its largest value) or ``steady``. T_tr = 2a/U_max, the time the
  rod takes to travel its own diameter, over which the flow around it develops. Per phase: the rms residual in
  units of the noise σ. Suspicious windows are runs where the residual's running rms over T_tr/2 exceeds 2σ
  (white noise averaged over n ≥ 10 samples stays below that with a probability above 99 %).
* **Regime.** Pearson correlation of r with the rod's speed |v|, acceleration |a|, elapsed time, accumulated
  strain γ = ∫ |v|/a dt and direction (the sign of the angular velocity about the cup's axis).
* **Frequency.** f0 = |ω|/2π of the rod on its circle; the share of the residual's variance at the harmonics
  k f0 (k = 1, 2, 3; least squares on cos/sin of k times the rod's phase, which follows reversals), and the lag
  of the measured reading behind the simulated one, from the peak of their cross-correlation within ±1/(4 f0).
"""

from __future__ import annotations

import math

import numpy as np

PHASES = ("start-up", "steady", "speed change", "reversal", "stop")
STOP_FRACTION = 0.05      # of the top speed: slower counts as at rest
CHANGE_FRACTION = 0.10    # of the largest |d speed/dt|: faster changes count as a speed change
WINDOW_SIGMA = 2.0        # running rms above this many σ marks a suspicious window
HARMONICS = (1, 2, 3)


def kinematics(times: np.ndarray, xy: np.ndarray, velocity: np.ndarray, rod_radius: float) -> dict[str, np.ndarray]:
    """Speed [m/s], |acceleration| [m/s²], tangential acceleration [m/s²], elapsed time [s], accumulated strain [1],
    direction (±1, 0 at rest) and the rod's phase on its circle [rad], per sample."""
    speed = np.linalg.norm(velocity, axis=1)
    accel = np.gradient(velocity, times, axis=0)
    r2 = np.maximum(np.sum(xy**2, axis=1), 1e-12)
    omega = (xy[:, 0] * velocity[:, 1] - xy[:, 1] * velocity[:, 0]) / r2
    moving = speed > STOP_FRACTION * max(speed.max(), 1e-12)
    dt = np.diff(times, prepend=times[0])
    return {"speed": speed, "acceleration": np.linalg.norm(accel, axis=1),
            "speed_change": np.gradient(speed, times), "elapsed_time": times - times[0],
            "strain": np.cumsum(speed * dt) / rod_radius, "direction": np.where(moving, np.sign(omega), 0.0),
            "phase": np.cumsum(omega * dt), "omega": omega}


def phases(times: np.ndarray, kin: dict[str, np.ndarray], rod_radius: float) -> tuple[np.ndarray, float]:
    """The programme phase of every sample (``PHASES``) and the transient time T_tr = 2a/U_max [s]."""
    speed = kin["speed"]
    top = max(speed.max(), 1e-12)
    transient = 2.0 * rod_radius / top
    label = np.full(times.size, "steady", dtype=object)
    change = np.abs(kin["speed_change"])
    label[change > CHANGE_FRACTION * max(change.max(), 1e-12)] = "speed change"
    direction = kin["direction"]
    previous = 0.0
    for i in np.flatnonzero(np.diff(np.concatenate([[0.0], (direction != 0).astype(float)])) > 0):
        kind = "start-up" if previous == 0.0 else ("reversal" if direction[i] != previous else "speed change")
        label[(times >= times[i]) & (times < times[i] + transient)] = kind
        # the direction this motion ends with, for the next start
        stop = np.flatnonzero(direction[i:] == 0)
        previous = direction[i + stop[0] - 1] if stop.size else direction[-1]
    label[direction == 0] = "stop"
    return label, transient


def suspicious_windows(times: np.ndarray, residual: np.ndarray, noise: float, width: float,
                       label: np.ndarray) -> list[dict]:
    """Runs of samples whose running rms residual over ``width`` [s] exceeds WINDOW_SIGMA σ: start, end [s],
    rms [N], and the phase most of their samples are in."""
    dt = float(np.median(np.diff(times)))
    n = max(1, int(round(width / dt)))
    running = np.sqrt(np.convolve(residual**2, np.ones(n) / n, mode="same"))
    flagged = running > WINDOW_SIGMA * noise
    windows = []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], flagged.astype(int), [0]])))
    for start, stop in zip(edges[::2], edges[1::2]):
        phases_in, counts = np.unique(label[start:stop].astype(str), return_counts=True)
        windows.append({"start": float(times[start]), "end": float(times[stop - 1]),
                        "rms": float(np.sqrt(np.mean(residual[start:stop] ** 2))),
                        "phase": str(phases_in[np.argmax(counts)])})
    return windows


def harmonic_shares(residual: np.ndarray, phase: np.ndarray) -> dict[str, float]:
    """Share of the residual's variance [1] that the harmonic k of the rod's phase explains: 1 − RSS_k/RSS_0, with
    RSS_k that of least squares on (1, cos kφ, sin kφ) and RSS_0 that of the mean alone."""
    r0 = residual - residual.mean()
    total = float(r0 @ r0)
    out = {}
    for k in HARMONICS:
        basis = np.stack([np.ones_like(phase), np.cos(k * phase), np.sin(k * phase)], axis=1)
        coef, *_ = np.linalg.lstsq(basis, residual, rcond=None)
        left = residual - basis @ coef
        out[f"harmonic_{k}"] = 1.0 - float(left @ left) / total if total > 0 else 0.0
    return out


def reading_lag(times: np.ndarray, measured: np.ndarray, simulated: np.ndarray, max_lag: float) -> float:
    """Lag [s] of ``measured`` behind ``simulated`` (positive: the measurement is late), the peak of their
    cross-correlation (mean product over the overlap) within ±``max_lag`` [s], refined by a parabola
    through the peak."""
    dt = float(np.median(np.diff(times)))
    m, s = measured - measured.mean(), simulated - simulated.mean()
    lags = np.arange(-int(max_lag / dt), int(max_lag / dt) + 1)
    if lags.size < 3:
        return 0.0
    corr = np.array([np.mean(m[max(0, k):m.size + min(0, k)] * s[max(0, -k):s.size - max(0, k)]) for k in lags])
    i = int(np.argmax(corr))
    shift = 0.0
    if 0 < i < lags.size - 1:
        denominator = corr[i - 1] - 2 * corr[i] + corr[i + 1]
        shift = 0.5 * (corr[i - 1] - corr[i + 1]) / denominator if denominator != 0 else 0.0
    return float((lags[i] + shift) * dt)


def locate(times: np.ndarray, xy: np.ndarray, velocity: np.ndarray, measured: np.ndarray, simulated: np.ndarray,
           noise: float, rod_radius: float) -> dict:
    """Where the residual measured − simulated [N] lies (see the module docstring), as JSON-ready data; also the
    per-sample ``label`` and ``residual`` under keys starting with an underscore (for plots)."""
    residual = measured - simulated
    kin = kinematics(times, xy, velocity, rod_radius)
    label, transient = phases(times, kin, rod_radius)
    by_phase = {}
    for phase in PHASES:
        mask = label == phase
        if mask.any():
            by_phase[phase] = {"samples": int(mask.sum()), "seconds": float(mask.sum() * np.median(np.diff(times))),
                               "rms_over_noise": float(np.sqrt(np.mean(residual[mask] ** 2)) / noise),
                               "mean": float(residual[mask].mean())}
    regime = {}
    for key in ("speed", "acceleration", "elapsed_time", "strain", "direction"):
        x = kin[key]
        regime[key] = float(np.corrcoef(x, residual)[0, 1]) if x.std() > 0 and residual.std() > 0 else 0.0
    moving = kin["direction"] != 0
    omega = float(np.mean(np.abs(kin["omega"][moving]))) if moving.any() else 0.0
    f0 = omega / (2 * math.pi)
    period = 1.0 / f0 if f0 > 0 else math.inf
    frequency = {"stirring_frequency": f0, "period": period,
                 **harmonic_shares(residual, kin["phase"]),
                 "lag": reading_lag(times, measured, simulated, min(period / 4, (times[-1] - times[0]) / 4))}
    worst = max(by_phase, key=lambda p: by_phase[p]["rms_over_noise"])
    strongest = max(regime, key=lambda k: abs(regime[k]))
    return {"noise": noise, "rms_over_noise": float(np.sqrt(np.mean(residual**2)) / noise),
            "transient_time": transient, "phases": by_phase, "worst_phase": worst,
            "windows": suspicious_windows(times, residual, noise, transient / 2, label),
            "regime": regime, "strongest_correlation": strongest, "frequency": frequency,
            "units": {"noise": "N", "transient_time": "s", "stirring_frequency": "Hz", "period": "s", "lag": "s",
                      "windows": "s, N"},
            "_label": label, "_residual": residual}
