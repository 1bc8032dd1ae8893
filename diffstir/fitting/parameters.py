"""Parameters fitted as θ, and the protocols of what the fitting engine reads of them.

A parameter is fitted as θ: the natural log of its SI value for a log-scaled parameter (viscosities, times,
stresses, moduli) and the value itself for a linear one (dimensionless indices, offsets), inside bounds. Steps in θ
are relative changes of scale parameters, which keeps Gauss-Newton well conditioned across decades of viscosity,
and confidence intervals in θ map to intervals that stay positive.

``ThetaParameters`` holds the θ <-> SI maps that every parameter set shares (``models.FitModel``, the diagnosis's
candidates); ``ParameterSet`` is what ``uncertainty.laplace`` reads of one, ``MaterialParameters`` what
``optimise.fit_model`` reads of a parameter set that makes a simulator material.
"""

from __future__ import annotations

import math
from typing import Protocol, Sequence, runtime_checkable

import numpy as np
from torch import nn


def theta_of(value: float, scale: str) -> float:
    """θ of the SI ``value``: ln value for a ``"log"`` ``scale``, the value itself for a ``"linear"`` one."""
    return math.log(value) if scale == "log" else float(value)


def value_of(theta: float, scale: str) -> float:
    """The SI value of ``theta`` on ``scale`` (the inverse of ``theta_of``)."""
    return math.exp(theta) if scale == "log" else float(theta)


@runtime_checkable
class ParameterSet(Protocol):
    """What ``uncertainty.laplace`` reads of the parameters it gives intervals for.

    Attributes:
        names: the parameters in θ's order.
        units: each parameter's SI unit, by name.
        scales: each parameter's scale, ``"log"`` (θ = ln value) or ``"linear"`` (θ = value), in order.
        lower, upper: bounds of θ, (k,).
    """

    names: list[str]
    units: dict[str, str]
    scales: list[str]
    lower: np.ndarray
    upper: np.ndarray

    @property
    def size(self) -> int:
        """k, the number of parameters."""
        ...

    def si_of_theta(self, theta: np.ndarray) -> np.ndarray:
        """SI values of ``theta`` (k,), element-wise and unclipped."""
        ...


@runtime_checkable
class MaterialParameters(ParameterSet, Protocol):
    """A parameter set that makes a simulator material: what ``optimise.fit_model``, ``optimise.Readings`` and the
    fit jobs read of a model. ``models.FitModel`` (a law or the corotated baseline) and the diagnosis's physics
    candidates implement it.

    Attributes:
        name: the model's name (``"newtonian"``, ``"carreau"``, ..., ``"corotated"``, a candidate's name).
        material: the module the simulator is handed, following θ (``set_theta``).
        is_baseline: whether its viscosity depends on the simulation's step (the corotated baseline: μ Δt).
        dt: the step [s] a baseline's viscosity is taken at; None for any other model.
    """

    name: str
    material: nn.Module
    is_baseline: bool
    dt: float | None

    def theta(self) -> np.ndarray:
        """The current θ, (k,)."""
        ...

    def set_theta(self, theta: np.ndarray) -> None:
        """Set the parameters (and ``material``) from ``theta``, clipped into the bounds."""
        ...

    def params_si(self) -> dict[str, float]:
        """The current SI values, by name."""
        ...


class ThetaParameters:
    """Named parameters fitted as θ inside bounds, with the θ <-> SI maps every parameter set shares; a
    ``ParameterSet``.

    Args:
        names: the parameters in θ's order.
        units: each parameter's SI unit, by name.
        scales: each parameter's scale, ``"log"`` or ``"linear"``, in order.
        bounds: each parameter's (lowest, highest) SI value, in order.
    """

    def __init__(self, names: Sequence[str], units: dict[str, str], scales: Sequence[str],
                 bounds: Sequence[tuple[float, float]]):
        self.names, self.units, self.scales = list(names), dict(units), list(scales)
        self.lower = np.array([theta_of(lo, s) for (lo, _), s in zip(bounds, self.scales)])
        self.upper = np.array([theta_of(hi, s) for (_, hi), s in zip(bounds, self.scales)])

    @property
    def size(self) -> int:
        """k, the number of parameters."""
        return len(self.names)

    def si_of_theta(self, theta: np.ndarray) -> np.ndarray:
        """SI values of θ (element-wise, no clipping: interval ends may lie outside the bounds)."""
        theta = np.asarray(theta, dtype=np.float64)
        return np.where(np.array(self.scales) == "log", np.exp(theta), theta)

    def values_of(self, theta: np.ndarray) -> dict[str, float]:
        """SI values of θ clipped into the bounds, by name."""
        theta = np.clip(np.asarray(theta, dtype=np.float64), self.lower, self.upper)
        return {k: value_of(t, s) for k, t, s in zip(self.names, theta, self.scales)}
