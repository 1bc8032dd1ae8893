"""Aligning a device's clock (the ADC's, the robot controller's) to the host's monotonic clock.

Each sample carries its device time tau_i and the host time h_i at which it arrived:

    h_i = offset + rate * tau_i + delta_i,    delta_i >= 0,

where delta_i is the transport latency (conversion, USB polling, serial buffering, OS scheduling), which can
only delay. The line is estimated as the lower envelope of the points: of all lines below every point, the one
minimising sum_i (h_i - offset - rate tau_i) (the linear programme of Moon, Skelly and Towsley, 1999). Its
optimum is the edge of the points' lower convex hull that spans the mean tau; the hull is kept incrementally
as device times arrive in increasing order, so adding a point costs O(1) amortised.

The mapped time is the earliest host time consistent with the data, i.e. the sampling instant plus the
minimum latency delta_min, which no timing data can reveal. Pass ``latency`` [s] when it is known (ADC
conversion time, USB frame): it is subtracted. Clock drift is assumed constant over a session (a crystal
drifts by less than 1e-4 over minutes).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ClockFit:
    """h = offset + rate tau - latency: host time [s] of device time tau [s], from ``points`` samples."""

    offset: float
    rate: float
    latency: float
    points: int

    def to_host(self, t_device):
        """Host time [s] of device time(s) ``t_device`` [s]."""
        return self.offset + self.rate * np.asarray(t_device, dtype=np.float64) - self.latency


class ClockAligner:
    """Online lower-envelope fit of host arrival time against device time (module docstring).

    Args:
        latency: known minimum latency from sampling to arrival [s], subtracted from mapped times.
    """

    def __init__(self, latency: float = 0.0) -> None:
        self.latency = latency
        self._hx: list[float] = []  # lower hull, device times [s]
        self._hy: list[float] = []  # lower hull, host times [s]
        self._n = 0
        self._sum_x = 0.0

    def add(self, t_device: float, t_host: float) -> None:
        """Add one sample; device times must not decrease."""
        hx, hy = self._hx, self._hy
        if hx and t_device <= hx[-1]:
            if t_device < hx[-1]:
                raise ValueError(f"clock alignment: device time went back from {hx[-1]} s to {t_device} s")
            if t_host >= hy[-1]:
                self._n += 1
                self._sum_x += t_device
                return
            hx.pop(), hy.pop()
        while len(hx) >= 2 and ((hx[-1] - hx[-2]) * (t_host - hy[-2])
                                - (hy[-1] - hy[-2]) * (t_device - hx[-2])) <= 0:
            hx.pop(), hy.pop()
        hx.append(t_device)
        hy.append(t_host)
        self._n += 1
        self._sum_x += t_device

    def fit(self) -> ClockFit:
        """The current estimate; needs at least one sample."""
        hx, hy = self._hx, self._hy
        if not hx:
            raise ValueError("clock alignment: no samples yet")
        if len(hx) == 1:
            return ClockFit(hy[0] - hx[0], 1.0, self.latency, self._n)
        i = min(max(bisect.bisect_right(hx, self._sum_x / self._n) - 1, 0), len(hx) - 2)
        rate = (hy[i + 1] - hy[i]) / (hx[i + 1] - hx[i])
        return ClockFit(hy[i] - rate * hx[i], rate, self.latency, self._n)


def align_clocks(t_device, t_host, *, latency: float = 0.0) -> ClockFit:
    """Batch lower-envelope fit of host times [s] against increasing device times [s]."""
    aligner = ClockAligner(latency)
    for tau, h in zip(np.asarray(t_device, dtype=np.float64), np.asarray(t_host, dtype=np.float64)):
        aligner.add(float(tau), float(h))
    return aligner.fit()
