"""How fast a trajectory stirs: its stirring frequency from the path of the rod's axis."""

from __future__ import annotations

import math

import numpy as np

MIN_STIR_AMPLITUDE = 1e-3  # m: a rod whose axis stays closer than this to its mean position does not stir


def stirring_frequency(t: np.ndarray, x: np.ndarray, y: np.ndarray) -> float:
    """Stirring frequency [Hz] of the rod axis at positions (x, y) [m] and times t [s] (strictly increasing).

    f = <|v|> / (2 pi <|r - c|>): mean speed (path length / duration) over 2 pi times the time-averaged
    distance of the axis from its time-averaged position c. Exact for a circle at constant speed
    (2 pi R f / 2 pi R) and for a sinusoidal back-and-forth stroke of amplitude a (4 a f / 2 pi (2 a / pi)).
    The path is measured along chords, which under-estimates f by sin(pi/n)/(pi/n) at n samples per period
    (1.6 % at n = 10); position noise lengthens the path and over-estimates f. Time averages use the
    trapezoid rule on the samples.
    Returns 0 when the mean distance is below MIN_STIR_AMPLITUDE (1 mm): the rod does not stir.
    """
    t, x, y = (np.asarray(a, dtype=np.float64) for a in (t, x, y))
    if t.size < 2:
        return 0.0
    duration = float(t[-1] - t[0])
    weight = np.diff(t, prepend=t[0]) / 2 + np.diff(t, append=t[-1]) / 2  # trapezoid rule on the samples
    r = np.stack([x, y], axis=-1)
    centre = (weight[:, None] * r).sum(0) / duration
    amplitude = float((weight * np.linalg.norm(r - centre, axis=-1)).sum() / duration)
    if amplitude < MIN_STIR_AMPLITUDE:
        return 0.0
    speed = float(np.hypot(np.diff(x), np.diff(y)).sum() / duration)
    return speed / (2.0 * math.pi * amplitude)
