"""Stirring programmes: the rod's axis on a circle about the cup's axis, at a sequence of speeds.

A programme is a list of segments, each a tangential ``speed`` [m/s] held for a ``duration`` [s]: positive speeds
turn counter-clockwise seen from above, negative ones clockwise (a direction reversal), 0 is a pause. The rod
starts at rest; between segments the speed changes smoothly over ``ramp_time`` [s] (the cosine ramp of
``diffstir.trajectory``), so the speed is

    v(t) = Σ_i (s_i − s_{i−1}) ramp(t − T_i),      ramp(u) = (1 − cos(π u / t_ramp)) / 2 on [0, t_ramp], 1 after,

with s_{−1} = 0 and T_i the start of segment i, and the phase is its exact integral over the circle's radius.
The radius is fixed over a programme (the rod never moves radially).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from diffstir.errors import is_number
from diffstir.trajectory import Trajectory, _ramp, _ramp_integral


@dataclass(frozen=True)
class Segment:
    """Hold tangential ``speed`` [m/s] (negative: clockwise, 0: pause) for ``duration`` [s]."""

    speed: float
    duration: float

    def __post_init__(self) -> None:
        if not (is_number(self.speed) and abs(self.speed) <= 1.0):
            raise ValueError(f"programme segment speed = {self.speed!r}; expected a speed in m/s, |speed| <= 1")
        if not (is_number(self.duration) and self.duration > 0):
            raise ValueError(f"programme segment duration = {self.duration!r}; expected a positive time in s")


def _segments(segments: Sequence[Segment | Mapping]) -> list[Segment]:
    out = [s if isinstance(s, Segment) else Segment(**dict(s)) for s in segments]
    if not out:
        raise ValueError("programme.segments is empty; give at least one {speed: m/s, duration: s}")
    return out


def programme_speed(t: np.ndarray, segments: Sequence[Segment | Mapping], ramp_time: float) -> np.ndarray:
    """Signed tangential speed v(t) [m/s] of the programme at times ``t`` [s] (see the module docstring)."""
    segs = _segments(segments)
    starts = np.cumsum([0.0] + [s.duration for s in segs[:-1]])
    previous = np.concatenate([[0.0], [s.speed for s in segs[:-1]]])
    t = np.asarray(t, dtype=np.float64)
    return sum((s.speed - p) * _ramp(np.clip(t - t0, 0.0, None), ramp_time)
               for s, p, t0 in zip(segs, previous, starts))


def stirring_programme(segments: Sequence[Segment | Mapping], *, radius: float, ramp_time: float = 0.2,
                       sample_rate: float = 1000.0, start_angle: float = 0.0) -> Trajectory:
    """The rod's axis on a circle of ``radius`` [m] following ``segments`` ({speed [m/s], duration [s]}), with
    speed changes smoothed over ``ramp_time`` [s], sampled at ``sample_rate`` [Hz], starting at ``start_angle``
    [rad] from the x axis."""
    segs = _segments(segments)
    if not (is_number(radius) and 0 < radius < 1.0):
        raise ValueError(f"programme.radius = {radius!r}; expected a circle radius in m (0 < radius < 1)")
    if not (is_number(ramp_time) and 0 <= ramp_time <= min(s.duration for s in segs)):
        raise ValueError(f"programme.ramp_time = {ramp_time!r} s; expected 0 <= ramp_time <= the shortest "
                         f"segment ({min(s.duration for s in segs)} s)")
    if not (is_number(sample_rate) and sample_rate > 0):
        raise ValueError(f"programme.sample_rate = {sample_rate!r}; expected a positive rate in Hz")
    duration = sum(s.duration for s in segs)
    t = np.linspace(0.0, duration, max(2, int(round(duration * sample_rate)) + 1))
    starts = np.cumsum([0.0] + [s.duration for s in segs[:-1]])
    previous = np.concatenate([[0.0], [s.speed for s in segs[:-1]]])
    arc = sum((s.speed - p) * _ramp_integral(np.clip(t - t0, 0.0, None), ramp_time)
              for s, p, t0 in zip(segs, previous, starts))
    phase = start_angle + arc / radius
    return Trajectory(t, radius * np.stack([np.cos(phase), np.sin(phase)], -1), 0.0, 0.0)


def programme_path(programme: Mapping, sample_rate: float = 1000.0) -> Trajectory:
    """The rod's path of a ``conf/lab/programme`` mapping (``segments``, ``radius`` [m], ``ramp_time`` [s] and,
    optionally, ``start_angle`` [rad]) sampled at ``sample_rate`` [Hz] (``stirring_programme``)."""
    return stirring_programme(programme["segments"], radius=programme["radius"], ramp_time=programme["ramp_time"],
                              start_angle=programme.get("start_angle", 0.0), sample_rate=sample_rate)
