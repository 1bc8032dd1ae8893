"""Bounded, positivity-preserving parametrisation of physical parameters.

A physical value v in [lo, hi] is stored as an unconstrained real ``raw`` and recovered as

    log scale:     v = exp(log lo + (log hi - log lo) * sigmoid(raw))    (scales: viscosities, times, stresses)
    linear scale:  v = lo + (hi - lo) * sigmoid(raw)                     (dimensionless indices)

so that any optimiser step on ``raw`` gives a value inside the bounds, and log-scaled values stay positive and move
by relative amounts. Both maps are smooth with nonzero derivative for every finite ``raw``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch
from torch import Tensor, nn

Scale = Literal["log", "linear"]

#: The stored sigmoid fraction is kept in [_EDGE, 1 - _EDGE] so that a value set exactly on a bound has a finite raw.
_EDGE = 1e-12

#: Relative distance [1] within which a value is taken as the bound it rounds to: float32 parameters carry about
#: 6e-8, and a value read back from them goes through exp and a sigmoid.
BOUND_ROUNDING = 1e-6


@dataclass(frozen=True)
class ParameterSpec:
    """What a law declares about one of its parameters.

    Attributes:
        unit: SI unit, e.g. ``"Pa·s"``; ``"1"`` for dimensionless.
        bounds: default ``(lo, hi)`` in that unit.
        scale: ``"log"`` for positive scale parameters, ``"linear"`` for dimensionless indices.
    """

    unit: str
    bounds: tuple[float, float]
    scale: Scale


def check_bounds(name: str, bounds: tuple[float, float], scale: Scale, unit: str) -> tuple[float, float]:
    """Return ``bounds`` as floats, or raise ValueError if they are not finite, ordered and (log scale) positive."""
    try:
        lo, hi = (float(b) for b in bounds)
    except (TypeError, ValueError):
        raise ValueError(f"bounds for {name!r} must be a pair (lo, hi) in {unit}, got {bounds!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"bounds for {name!r} must be finite with lo < hi, got ({lo}, {hi}) {unit}")
    if scale == "log" and lo <= 0.0:
        raise ValueError(f"bounds for {name!r} are log-scaled and need lo > 0, got ({lo}, {hi}) {unit}")
    return lo, hi


def to_raw(value: float, lo: float, hi: float, scale: Scale) -> float:
    """Inverse of :func:`from_raw` for a value in [lo, hi] (a value on a bound maps to a large finite raw)."""
    if scale == "log":
        frac = (math.log(value) - math.log(lo)) / (math.log(hi) - math.log(lo))
    else:
        frac = (value - lo) / (hi - lo)
    frac = min(max(frac, _EDGE), 1.0 - _EDGE)
    return math.log(frac) - math.log1p(-frac)


def from_raw(raw: Tensor, lo: float, hi: float, scale: Scale) -> Tensor:
    """Map an unconstrained ``raw`` tensor to the physical value in [lo, hi] (differentiable)."""
    frac = torch.sigmoid(raw)
    if scale == "log":
        log_lo = math.log(lo)
        return torch.exp(log_lo + (math.log(hi) - log_lo) * frac)
    return lo + (hi - lo) * frac


class BoundedParameter(nn.Module):
    """One physical parameter held as an unconstrained ``nn.Parameter`` named ``raw``.

    Args:
        name: parameter name, used in error messages.
        value: initial value in ``unit``.
        bounds: ``(lo, hi)`` in ``unit``.
        scale: ``"log"`` or ``"linear"`` (see the module docstring).
        unit: SI unit of the value.
        dtype, device: of ``raw`` (default: torch's default dtype, CPU).
    """

    def __init__(
        self,
        name: str,
        value: float,
        bounds: tuple[float, float],
        scale: Scale,
        unit: str,
        *,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        if scale not in ("log", "linear"):
            raise ValueError(f"scale of {name!r} must be 'log' or 'linear', got {scale!r}")
        self.param_name = name
        self.scale = scale
        self.unit = unit
        self.lo, self.hi = check_bounds(name, bounds, scale, unit)
        self.raw = nn.Parameter(torch.zeros((), dtype=dtype, device=device))
        self.set_si(value)

    def forward(self) -> Tensor:
        """The value [unit] as a 0-d tensor, differentiable with respect to ``raw``."""
        return from_raw(self.raw, self.lo, self.hi, self.scale)

    def check(self, value: float) -> float:
        """Return ``value`` as a float; raise ValueError naming the parameter, value, bounds and unit if outside.
        A value within float32 round-off (relative 1e-6) of a bound, as one read back from a fit that ended on the
        bound, is that bound."""
        value = float(value)
        for bound in (self.lo, self.hi):
            if math.isclose(value, bound, rel_tol=BOUND_ROUNDING, abs_tol=1e-12):
                return bound
        if not (self.lo <= value <= self.hi):  # also rejects NaN
            raise ValueError(
                f"{self.param_name} = {value:g} {self.unit} is outside its bounds "
                f"[{self.lo:g}, {self.hi:g}] {self.unit}"
            )
        return value

    def set_si(self, value: float) -> None:
        """Set the value [unit] (checked as in :meth:`check`)."""
        value = self.check(value)
        with torch.no_grad():
            self.raw.fill_(to_raw(value, self.lo, self.hi, self.scale))

    def fraction(self) -> float:
        """Position of the value inside its bounds, sigmoid(raw) in (0, 1), on the parameter's scale."""
        return float(torch.sigmoid(self.raw.detach()))

    def extra_repr(self) -> str:
        return f"{self.param_name}, bounds=({self.lo:g}, {self.hi:g}) {self.unit}, scale={self.scale}"
