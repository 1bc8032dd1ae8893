"""Constant-speed windows of a stirring recording: the stretches where the rod holds one speed.

A sample is steady when the rod's speed s(t) [m/s] would change by less than ``tolerance`` · s over ``min_duration``
at its current rate, |ds/dt| · T_min < tol · s, so ramps between the speeds of a programme (and the start from
rest) are left out. Runs of steady samples that last at least ``min_duration`` [s] and move faster than
``pause_speed`` [m/s] (a rod held still is not stirring) are the windows. The pause is an absolute speed, not a
share of the top speed: a programme may span any range of speeds, and its slowest, where a yield stress shows,
must not be dropped for being slow.

s is the speed of the rod's path as the arm moved it, the GCV smoothing spline of the recorded positions
(``diffstir.recording.smoothing``, the path the fit replays): differentiating the samples twice turns 1 µm rounding
at 200 Hz, or an arm's 10-50 µm jitter, into rates of change far beyond any tolerance. ds/dt is the change of s
across a span τ about each sample, the shortest (at least one sample spacing, at most ``min_duration``) over which
its noise sqrt(2) σ_v / τ is a fifth of the tolerance's rate tol · s / T_min, σ_v the speed noise the smoothing
leaves; a window therefore starts and ends up to τ / 2 inside the steady stretch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..recording import Recording, RecordingError
from ..recording.files import warn
from ..recording.smoothing import smooth_path


@dataclass(frozen=True)
class SpeedWindow:
    """Samples of ``recording`` in (``start``, ``end``] [s], where the rod's axis moves at ``speed`` [m/s] (mean
    over the window)."""

    recording: Recording
    start: float
    end: float
    speed: float

    @property
    def label(self) -> str:
        """``<recording>@<start>-<end>s``, for reports and messages."""
        name = str(self.recording.path) if self.recording.path else (self.recording.name or "recording")
        return f"{name}@{self.start:.3g}-{self.end:.3g}s"


#: The rate of change of the speed is read over the span where its noise is 1/RATE_SIGMAS of the tolerance's rate:
#: noise alone then marks a steady sample unsteady with probability 6e-7 (5 σ, two-sided), once in hours of
#: stirring at the spans' correlation times of 10-100 ms.
RATE_SIGMAS = 5.0

#: m/s: the rod moving slower than this is held still (1 mm/s is 10 µm between samples at 100 Hz, the size of an
#: arm's position jitter), not stirring.
PAUSE_SPEED = 1e-3


def speed_windows(recording: Recording, *, tolerance: float = 0.05, min_duration: float = 0.3,
                  pause_speed: float = PAUSE_SPEED) -> list[SpeedWindow]:
    """The constant-speed windows of ``recording`` in time order (see the module docstring).

    Args:
        tolerance: relative speed change [1] that still counts as one speed (the arm's speed regulation).
        min_duration: shortest window [s].
        pause_speed: slower than this [m/s] the rod is held still.

    Raises:
        RecordingError: no window (naming the recording's time column and the speeds it holds).
    """
    if not 0 < tolerance < 1:
        raise ValueError(f"behaviour.speed_tolerance = {tolerance}; expected a relative change in (0, 1)")
    if not min_duration > 0:
        raise ValueError(f"behaviour.min_window = {min_duration}; expected a positive duration in s")
    if not pause_speed >= 0:
        raise ValueError(f"behaviour.pause_speed = {pause_speed}; expected a speed in m/s, >= 0")
    t = recording.t
    if t.size < 2:
        raise RecordingError(f"{recording.source('csv')}: {t.size} rows; speed windows need at least 2")
    path = smooth_path(t, np.stack([recording.x, recording.y], axis=-1))
    message = path.jitter_message(recording.source("csv"))
    if message is not None:
        warn(message)
    speed = path.speed(t)
    # the rate over the span where its noise, sqrt(2) σ_v / span, is a fifth of the tolerance's rate
    span = np.clip(RATE_SIGMAS * math.sqrt(2.0) * path.speed_noise * min_duration
                   / (tolerance * np.maximum(speed, max(pause_speed, 1e-12))),
                   np.median(np.diff(t)), min_duration)
    before, after = np.maximum(t - span / 2, t[0]), np.minimum(t + span / 2, t[-1])
    rate = np.abs(path.speed(after) - path.speed(before)) / (after - before)
    steady = (rate * min_duration < tolerance * speed) & (speed > pause_speed)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], steady.astype(np.int8), [0]])))
    windows = []
    for first, stop in zip(edges[::2], edges[1::2]):
        start, end = float(t[max(first - 1, 0)]), float(t[stop - 1])
        if end - start >= min_duration:
            windows.append(SpeedWindow(recording, start, end, float(np.mean(speed[first:stop]))))
    if not windows:
        raise RecordingError(f"{recording.source('csv')}: columns 'x', 'y' hold no stretch of {min_duration} s at "
                             f"one speed (within {tolerance:.0%}); speeds range {speed.min():.3g}-"
                             f"{speed.max():.3g} m/s")
    return windows
