"""Moving between recording and simulation time: the rod trajectory at simulation times, the simulated force at
recording times.

Both interpolate linearly. Linear positions never overshoot (the rod stays on chords of the recorded path, so it
cannot reach the wall if the recording does not), and velocities are Recording.velocity() interpolated, so at
the recorded times they are exactly the recording's velocities. Neither extrapolates: times outside the other
series' span, beyond TIME_TOLERANCE plus four float64 spacings at the times' magnitude, raise RecordingError.
"""

from __future__ import annotations

import numpy as np
import torch

from diffstir.recording.errors import RecordingError
from diffstir.recording.format import Recording

TIME_TOLERANCE = 1e-9  # s: times this far outside a series' span are clamped to it rather than refused


def _times(values) -> np.ndarray:
    """Times [s] as a float64 numpy vector, from a tensor, an array or a list."""
    if torch.is_tensor(values):
        values = values.detach().cpu().double().numpy()
    return np.asarray(values, dtype=np.float64).reshape(-1)


def _check_span(times: np.ndarray, start: float, end: float, what: str) -> None:
    tolerance = TIME_TOLERANCE + 4 * float(np.spacing(max(abs(start), abs(end))))  # s: the times' own rounding
    outside = (times < start - tolerance) | (times > end + tolerance)
    if np.any(outside):
        i = int(np.flatnonzero(outside)[0])
        raise RecordingError(f"{what}: time {float(times[i])!r} s (index {i}) lies outside [{float(start)!r}, "
                             f"{float(end)!r}] s; interpolation does not extrapolate")


def trajectory_at(rec: Recording, times) -> tuple[np.ndarray, np.ndarray]:
    """Rod axis positions [m] and velocities [m/s], each (T, 2), at ``times`` [s] (T,), inside the recording.

    Positions: linear interpolation of (x, y). Velocities: linear interpolation of rec.velocity().
    """
    times = _times(times)
    if rec.t.size < 2:
        raise RecordingError(f"{rec.source('csv')}: {rec.t.size} rows; interpolation needs at least 2")
    _check_span(times, float(rec.t[0]), float(rec.t[-1]), f"{rec.source('csv')}: column 't'")
    velocity = rec.velocity()
    positions = np.stack([np.interp(times, rec.t, rec.x), np.interp(times, rec.t, rec.y)], axis=-1)
    velocities = np.stack([np.interp(times, rec.t, velocity[:, k]) for k in range(2)], axis=-1)
    return positions, velocities


def resample_force(sim_times, sim_force: torch.Tensor, rec_times) -> torch.Tensor:
    """Simulated force [N] at the recording's times, by linear interpolation; differentiable in ``sim_force``.

    f(t) = (1 - w) f_i + w f_{i+1}, w = (t - t_i) / (t_{i+1} - t_i), t_i <= t <= t_{i+1}.
    ``sim_times`` [s] (S,) strictly increasing; ``sim_force`` (S,) or (S, 2); ``rec_times`` [s] (T,) inside
    the simulated span. Returns (T,) or (T, 2) in ``sim_force``'s dtype and device. Weights are computed in
    float64, so float32 forces do not lose time resolution.
    """
    ts, tr = _times(sim_times), _times(rec_times)
    if sim_force.ndim not in (1, 2) or sim_force.shape[0] != ts.size or (sim_force.ndim == 2
                                                                          and sim_force.shape[1] != 2):
        raise RecordingError(f"resample_force: sim_force has shape {tuple(sim_force.shape)}; expected "
                             f"({ts.size},) or ({ts.size}, 2) to match sim_times (N)")
    if ts.size < 2 or not np.all(np.diff(ts) > 0):
        raise RecordingError("resample_force: sim_times must hold at least 2 strictly increasing times (s)")
    _check_span(tr, ts[0], ts[-1], "resample_force: rec_times")
    tr = np.clip(tr, ts[0], ts[-1])
    i = np.clip(np.searchsorted(ts, tr, side="right") - 1, 0, ts.size - 2)
    w = torch.as_tensor((tr - ts[i]) / (ts[i + 1] - ts[i]), dtype=sim_force.dtype, device=sim_force.device)
    if sim_force.ndim == 2:
        w = w[:, None]
    i = torch.as_tensor(i, device=sim_force.device)
    return (1 - w) * sim_force[i] + w * sim_force[i + 1]
