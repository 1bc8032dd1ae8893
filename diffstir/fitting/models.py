"""Fluid models as vectors of fitted parameters θ (``parameters``): a rheology law's, or the corotated baseline's.

Each kind of material has its adapter, which reads and writes the material's SI values and gives its viscosity:
``LawParameters`` for a rheology law, ``CorotatedParameters`` for the baseline. ``FitModel`` chooses it once.
"""

from __future__ import annotations

import copy
import math

import numpy as np
import torch
from torch import Tensor, nn

from ..mpm import Corotated
from ..rheology import LAWS, RheologyLaw, make_law
from .parameters import ThetaParameters, theta_of

#: Bounds of the corotated baseline's shear modulus μ [Pa]; its apparent viscosity is μ Δt.
COROTATED_BOUNDS = (1e-3, 1e9)

#: Units of the parameters that carry a law's stress scale: multiplied together by c, they make its stress at every
#: shear rate c times what it was (``FitModel.stress_scaled``).
STRESS_UNITS = ("Pa", "Pa·s", "Pa·s^n")


class LawParameters:
    """A rheology law's fitted parameters: its names, units, scales and bounds, its SI values read and written
    through the law's bounded parameters, and its viscosity."""

    is_baseline = False

    def __init__(self, law: RheologyLaw):
        self.law = law
        self.name = law.name
        self.names = list(law.params)
        self.units = {k: p.unit for k, p in law.params.items()}
        self.scales = [p.scale for p in law.params.values()]
        self.bounds = [(p.lo, p.hi) for p in law.params.values()]

    def values(self) -> dict[str, float]:
        """The law's SI values, by name."""
        return self.law.parameters_si()

    def set_values(self, values: dict[str, float]) -> None:
        """Set the law's SI ``values`` (by name), clipped into its bounds."""
        lo_hi = self.law.bounds()
        self.law.set_parameters_si(**{k: min(max(v, lo_hi[k][0]), lo_hi[k][1]) for k, v in values.items()})

    def viscosity(self, shear_rate: Tensor, values: dict[str, Tensor]) -> Tensor:
        """η [Pa·s] at ``shear_rate`` [1/s] for SI parameter tensors ``values``, differentiable in them."""
        return self.law.viscosity(shear_rate, values)

    def zero_shear_viscosity(self) -> float:
        """η at zero shear rate [Pa·s] (the regularised value for a yield-stress law)."""
        return float(self.law.zero_shear_viscosity().detach())

    def theta_gradient(self, grads: list[Tensor]) -> np.ndarray:
        """d loss / d θ from ``grads``, d loss / d raw of the law's bounded raw parameters, in order:
        θ = ln lo + span·sigmoid(raw) (log-scaled) or lo + span·sigmoid(raw) (linear)."""
        out = []
        for bounded, grad in zip(self.law.params.values(), grads):
            frac = float(torch.sigmoid(bounded.raw.detach()))
            span = (math.log(bounded.hi) - math.log(bounded.lo)) if bounded.scale == "log" else bounded.hi - bounded.lo
            out.append(float(grad) / max(span * frac * (1.0 - frac), 1e-300))
        return np.array(out)


class CorotatedParameters:
    """The corotated baseline's fitted parameter, its shear modulus μ [Pa] (stored as ln μ), whose viscosity is
    μ Δt at every shear rate, Δt = ``dt`` [s] the simulation's step."""

    is_baseline = True
    name = "corotated"
    names = ["shear_modulus"]
    units = {"shear_modulus": "Pa"}
    scales = ["log"]
    bounds = [COROTATED_BOUNDS]

    def __init__(self, material: Corotated, dt: float | None):
        if dt is None:
            raise ValueError("the corotated baseline needs the simulation's time step dt [s] to state its "
                             "apparent viscosity mu * dt")
        self.material, self.dt = material, dt

    def values(self) -> dict[str, float]:
        """{"shear_modulus": μ [Pa]}."""
        return {"shear_modulus": float(self.material.shear_modulus.detach())}

    def set_values(self, values: dict[str, float]) -> None:
        """Set μ from ``values["shear_modulus"]`` [Pa]."""
        with torch.no_grad():
            self.material.log_shear_modulus.fill_(math.log(values["shear_modulus"]))

    def viscosity(self, shear_rate: Tensor, values: dict[str, Tensor]) -> Tensor:
        """μ Δt [Pa·s] at every ``shear_rate`` [1/s], for the SI tensor ``values["shear_modulus"]``."""
        return values["shear_modulus"] * self.dt * torch.ones_like(shear_rate)

    def zero_shear_viscosity(self) -> float:
        """μ Δt [Pa·s]."""
        return self.material.apparent_viscosity(self.dt)

    def theta_gradient(self, grads: list[Tensor]) -> np.ndarray:
        """d loss / d θ from ``grads``, [d loss / d ln μ]: θ is ln μ itself."""
        return np.array([float(grads[0])])


class FitModel(ThetaParameters):
    """A fluid model (a rheology law, or the corotated baseline) seen as θ; a ``parameters.MaterialParameters``.

    Attributes:
        name: ``"newtonian"``, ``"carreau"``, ... or ``"corotated"``.
        material: the module handed to the simulator (the law itself, or ``Corotated``).
        names, units, scales: the fitted parameters in order, their SI units and scales.
        lower, upper: bounds of θ.
        dt: the corotated baseline's simulation step [s] (None for a law).
    """

    def __init__(self, material: nn.Module, dt: float | None = None):
        if isinstance(material, RheologyLaw):
            kind = LawParameters(material)
        elif isinstance(material, Corotated):
            kind = CorotatedParameters(material, dt)
        else:
            raise TypeError(f"cannot fit {type(material).__name__}; expected a rheology law or Corotated")
        super().__init__(kind.names, kind.units, kind.scales, kind.bounds)
        self.material, self.dt, self.kind, self.name = material, dt, kind, kind.name

    @property
    def is_baseline(self) -> bool:
        """Whether this is the corotated baseline, whose viscosity μ Δt depends on the simulation's step."""
        return self.kind.is_baseline

    @classmethod
    def named(cls, name: str, dt: float | None = None, **params: float) -> "FitModel":
        """A model by name (a law in ``diffstir.rheology.LAWS`` or ``"corotated"``) with initial SI values."""
        if name == CorotatedParameters.name:
            return cls(Corotated(params.get("shear_modulus", 1e3)), dt=dt)
        if name not in LAWS:
            raise ValueError(f"model {name!r} is unknown; choose from {sorted(LAWS) + ['corotated']}")
        return cls(make_law(name, **params))

    def copy(self) -> "FitModel":
        return FitModel(copy.deepcopy(self.material), self.dt)

    def params_si(self) -> dict[str, float]:
        """Current values in SI units, by name."""
        return self.kind.values()

    def theta(self) -> np.ndarray:
        values = self.params_si()
        return np.array([theta_of(values[k], s) for k, s in zip(self.names, self.scales)])

    def set_theta(self, theta: np.ndarray) -> None:
        """Set the parameters from θ (clipped into the bounds)."""
        self.kind.set_values(self.values_of(theta))

    def theta_gradient(self, grads: list[Tensor]) -> np.ndarray:
        """d loss / d θ, (k,), from ``grads``, d loss / d each of ``material.parameters()``."""
        return self.kind.theta_gradient(grads)

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

    def viscosity(self, shear_rate: np.ndarray, theta: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Apparent viscosity [Pa·s] at ``shear_rate`` [1/s] and its gradient d ln η / dθ, (S,) and (S, k),
        at θ (default: the current parameters). The corotated baseline's viscosity is μ Δt at every rate."""
        theta = self.theta() if theta is None else np.asarray(theta, dtype=np.float64)
        rate = torch.as_tensor(np.asarray(shear_rate, dtype=np.float64))
        t = torch.tensor(theta, dtype=torch.float64)
        gradient = torch.autograd.functional.jacobian(lambda u: self._viscosity(rate, u).log(), t, vectorize=True)
        return self.viscosity_values(shear_rate, theta), gradient.numpy().reshape(*rate.shape, len(theta))

    def viscosity_values(self, shear_rate: np.ndarray, theta: np.ndarray | None = None) -> np.ndarray:
        """Apparent viscosity [Pa·s] at ``shear_rate`` [1/s] at θ (default: the current parameters), without its
        gradient."""
        theta = self.theta() if theta is None else np.asarray(theta, dtype=np.float64)
        with torch.no_grad():
            rate = torch.as_tensor(np.asarray(shear_rate, dtype=np.float64))
            return self._viscosity(rate, torch.as_tensor(theta, dtype=torch.float64)).numpy()

    def _viscosity(self, rate: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        values = {k: (t[i].exp() if s == "log" else t[i]) for i, (k, s) in enumerate(zip(self.names, self.scales))}
        return self.kind.viscosity(rate, values)

    def zero_shear_viscosity(self) -> float:
        """η at zero shear rate [Pa·s] (the law's regularised value for yield-stress laws; μ Δt for corotated)."""
        return self.kind.zero_shear_viscosity()
