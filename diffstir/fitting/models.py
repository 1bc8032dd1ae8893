"""Fluid models as vectors of fitted parameters.

A model's parameters are fitted as θ: the natural log of the value for log-scaled parameters (viscosities, times,
stresses, moduli) and the value itself for dimensionless indices, each inside the law's bounds. Steps in θ are
relative changes of scale parameters, which keeps Gauss-Newton well conditioned across decades of viscosity, and
confidence intervals in θ map to intervals that stay positive.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import torch
from torch import nn

from ..mpm import Corotated
from ..rheology import LAWS, RheologyLaw, make_law

#: Bounds of the corotated baseline's shear modulus μ [Pa]; its apparent viscosity is μ Δt.
COROTATED_BOUNDS = (1e-3, 1e9)

#: Units of the parameters that carry a law's stress scale: multiplied together by c, they make its stress at every
#: shear rate c times what it was (``FitModel.stress_scaled``).
STRESS_UNITS = ("Pa", "Pa·s", "Pa·s^n")


class FitModel:
    """A fluid model (a rheology law, or the corotated baseline) seen as θ.

    Attributes:
        name: ``"newtonian"``, ``"carreau"``, ... or ``"corotated"``.
        material: the module handed to the simulator (the law itself, or ``Corotated``).
        names, units, scales: the fitted parameters in order, their SI units and scales.
        lower, upper: bounds of θ.
    """

    def __init__(self, material: nn.Module, dt: float | None = None):
        self.material = material
        if isinstance(material, RheologyLaw):
            self.name = material.name
            self.names = list(material.params)
            self.units = {k: p.unit for k, p in material.params.items()}
            self.scales = [p.scale for p in material.params.values()]
            bounds = [(p.lo, p.hi) for p in material.params.values()]
        elif isinstance(material, Corotated):
            if dt is None:
                raise ValueError("the corotated baseline needs the simulation's time step dt [s] to state its "
                                 "apparent viscosity mu * dt")
            self.name, self.names, self.scales = "corotated", ["shear_modulus"], ["log"]
            self.units = {"shear_modulus": "Pa"}
            bounds = [COROTATED_BOUNDS]
        else:
            raise TypeError(f"cannot fit {type(material).__name__}; expected a rheology law or Corotated")
        self.dt = dt
        self.lower = np.array([_theta(lo, s) for (lo, _), s in zip(bounds, self.scales)])
        self.upper = np.array([_theta(hi, s) for (_, hi), s in zip(bounds, self.scales)])

    @classmethod
    def named(cls, name: str, dt: float | None = None, **params: float) -> "FitModel":
        """A model by name (a law in ``diffstir.rheology.LAWS`` or ``"corotated"``) with initial SI values."""
        if name == "corotated":
            return cls(Corotated(params.get("shear_modulus", 1e3)), dt=dt)
        if name not in LAWS:
            raise ValueError(f"model {name!r} is unknown; choose from {sorted(LAWS) + ['corotated']}")
        return cls(make_law(name, **params))

    def copy(self) -> "FitModel":
        return FitModel(copy.deepcopy(self.material), self.dt)

    @property
    def size(self) -> int:
        return len(self.names)

    def params_si(self) -> dict[str, float]:
        """Current values in SI units, by name."""
        if self.name == "corotated":
            return {"shear_modulus": float(self.material.shear_modulus.detach())}
        return self.material.parameters_si()

    def theta(self) -> np.ndarray:
        values = self.params_si()
        return np.array([_theta(values[k], s) for k, s in zip(self.names, self.scales)])

    def set_theta(self, theta: np.ndarray) -> None:
        """Set the parameters from θ (clipped into the bounds)."""
        theta = np.clip(np.asarray(theta, dtype=np.float64), self.lower, self.upper)
        values = {k: _value(t, s) for k, t, s in zip(self.names, theta, self.scales)}
        if self.name == "corotated":
            with torch.no_grad():
                self.material.log_shear_modulus.fill_(math.log(values["shear_modulus"]))
        else:
            lo_hi = self.material.bounds()
            self.material.set_parameters_si(**{k: min(max(v, lo_hi[k][0]), lo_hi[k][1]) for k, v in values.items()})

    def stress_scaled(self, factor: float) -> "FitModel":
        """A copy whose stress at every shear rate is ``factor`` times this one's: each parameter in a unit of
        stress (``STRESS_UNITS``: a viscosity, a yield stress, a consistency, a modulus) times ``factor`` > 0,
        clipped into its bounds; times and indices unchanged."""
        if not factor > 0:
            raise ValueError(f"a stress scale factor must be > 0, got {factor!r}")
        scaled = self.copy()
        scaled.set_theta(self.theta() + math.log(factor) * self.stress_direction())
        return scaled

    def stress_direction(self) -> np.ndarray:
        """The direction s in θ along which the stress at every shear rate scales, (k,): θ + c s multiplies it by
        exp(c) (``stress_scaled``); 1 for each parameter in a unit of stress (log-scaled: θ = ln value), 0 for
        times and indices. d readings / dθ · s is the readings' viscous part, the force that scales with the
        fluid's stress."""
        return np.array([1.0 if self.units[name] in STRESS_UNITS else 0.0 for name in self.names])

    def si_of_theta(self, theta: np.ndarray) -> np.ndarray:
        """SI values of θ (element-wise, no clipping: interval ends may lie outside the bounds)."""
        theta = np.asarray(theta, dtype=np.float64)
        return np.where(np.array(self.scales) == "log", np.exp(theta), theta)

    def viscosity(self, shear_rate: np.ndarray, theta: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Apparent viscosity [Pa·s] at ``shear_rate`` [1/s] and its gradient d ln η / dθ, (S,) and (S, k),
        at θ (default: the current parameters). The corotated baseline's viscosity is μ Δt at every rate."""
        theta = self.theta() if theta is None else np.asarray(theta, dtype=np.float64)
        t = torch.tensor(theta, dtype=torch.float64, requires_grad=True)
        rate = torch.as_tensor(np.asarray(shear_rate, dtype=np.float64))
        values = {k: (t[i].exp() if s == "log" else t[i]) for i, (k, s) in enumerate(zip(self.names, self.scales))}
        if self.name == "corotated":
            eta = values["shear_modulus"] * self.dt * torch.ones_like(rate)
        else:
            eta = self.material.viscosity(rate, values)
        log_eta = eta.log()
        grads = [torch.autograd.grad(v, t, retain_graph=True)[0] for v in log_eta.reshape(-1)]
        return eta.detach().numpy(), torch.stack(grads).numpy().reshape(*rate.shape, len(theta))

    def zero_shear_viscosity(self) -> float:
        """η at zero shear rate [Pa·s] (the law's regularised value for yield-stress laws; μ Δt for corotated)."""
        if self.name == "corotated":
            return float(self.material.shear_modulus.detach()) * self.dt
        return float(self.material.zero_shear_viscosity().detach())


def _theta(value: float, scale: str) -> float:
    return math.log(value) if scale == "log" else float(value)


def _value(theta: float, scale: str) -> float:
    return math.exp(theta) if scale == "log" else float(theta)
