"""Generalized Newtonian fluids: apparent viscosity eta [Pa·s] as a function of shear rate g [1/s].

Every law is an ``nn.Module`` whose physical parameters are bounded ``nn.Parameter``s (see
:mod:`diffstir.rheology.parameters`); ``law(g)`` is differentiable with respect to them and to ``g``, works on any
device and floating dtype, and never synchronises with the host.

Laws with a yield stress or a power-law singularity at g = 0 are regularised with a shear rate g_c [1/s]
(``shear_rate_reg``, a constructor argument, never fitted) so that eta stays finite:

    power law          eta = k (g^2 + g_c^2)^((n-1)/2)
    Papanastasiou      tau_y / g  ->  tau_y (1 - exp(-g/g_c)) / g,   which tends to tau_y / g_c as g -> 0

For g >> g_c both are the unregularised laws to relative order (g_c/g)^2 and exp(-g/g_c). The largest viscosity,
about tau_y / g_c, sets the explicit viscous time step of the simulator: a smaller g_c is more faithful at low
shear rates and costs proportionally more steps.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from typing import ClassVar

import numpy as np
import torch
from numpy.typing import ArrayLike
from torch import Tensor, nn

from diffstir.rheology.parameters import BoundedParameter, ParameterSpec

_VISCOSITY = ParameterSpec("Pa·s", (1e-4, 1e3), "log")
_TIME = ParameterSpec("s", (1e-4, 1e3), "log")
_STRESS = ParameterSpec("Pa", (1e-4, 1e3), "log")
_CONSISTENCY = ParameterSpec("Pa·s^n", (1e-4, 1e3), "log")
_FLOW_INDEX = ParameterSpec("1", (0.05, 2.0), "linear")
_CROSS_INDEX = ParameterSpec("1", (0.01, 2.0), "linear")

#: Default regularisation shear rate g_c [1/s] of the power-law and yield-stress laws.
DEFAULT_SHEAR_RATE_REG = 1e-2


class RheologyLaw(nn.Module, ABC):
    """Base class: apparent viscosity eta(g) [Pa·s] of shear rate g [1/s].

    Subclasses declare ``name`` and ``specs`` (unit, default bounds and scale of each parameter) and implement
    :meth:`viscosity`, a pure function of the shear rate and a dict of SI parameter tensors.

    Args:
        values: initial SI value of every parameter in ``specs``.
        bounds: optional ``{name: (lo, hi)}`` overrides of the default bounds, in the parameter's unit.
        dtype, device: of the parameters, as for torch layers (default: torch's default dtype, CPU).

    Raises:
        ValueError: unknown parameter name in ``bounds``, invalid bounds, or a value outside its bounds.
    """

    name: ClassVar[str]
    specs: ClassVar[dict[str, ParameterSpec]]
    units: ClassVar[dict[str, str]]

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if "specs" in cls.__dict__:
            cls.units = {key: spec.unit for key, spec in cls.specs.items()}

    def __init__(
        self,
        values: Mapping[str, float],
        bounds: Mapping[str, tuple[float, float]] | None = None,
        *,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__()
        bounds = dict(bounds or {})
        unknown = sorted(set(bounds) - set(self.specs))
        if unknown:
            raise ValueError(
                f"bounds given for unknown parameter(s) {unknown} of {self.name}; valid: {list(self.specs)}"
            )
        self.params = nn.ModuleDict(
            {
                key: BoundedParameter(
                    key, values[key], bounds.get(key, spec.bounds), spec.scale, spec.unit, dtype=dtype, device=device
                )
                for key, spec in self.specs.items()
            }
        )

    @abstractmethod
    def viscosity(self, shear_rate: Tensor, params: Mapping[str, Tensor]) -> Tensor:
        """Apparent viscosity [Pa·s] at ``shear_rate`` [1/s] for SI parameter tensors ``params`` (pure function).

        Each parameter may be 0-d or broadcastable against ``shear_rate`` (one value per point, say).
        """

    def forward(self, shear_rate: Tensor) -> Tensor:
        """Apparent viscosity [Pa·s] at ``shear_rate`` [1/s, >= 0, any shape]; same shape, dtype and device."""
        if not shear_rate.is_floating_point():
            raise TypeError(f"shear_rate must be a floating-point tensor in 1/s, got dtype {shear_rate.dtype}")
        params = {key: value.to(dtype=shear_rate.dtype) for key, value in self.constrained().items()}
        return self.viscosity(shear_rate, params)

    def stress(self, shear_rate: Tensor) -> Tensor:
        """Shear stress tau = eta(g) g [Pa] at ``shear_rate`` [1/s]."""
        return self.forward(shear_rate) * shear_rate

    def constrained(self) -> dict[str, Tensor]:
        """Differentiable 0-d SI tensors of the parameters, by name (what :meth:`forward` uses)."""
        return {key: param() for key, param in self.params.items()}

    def parameters_si(self) -> dict[str, float]:
        """Current parameter values in SI units, by name."""
        return {key: float(value.detach()) for key, value in self.constrained().items()}

    def set_parameters_si(self, **values: float) -> None:
        """Set some or all parameters from SI values; nothing is changed if any name or value is invalid.

        Raises:
            ValueError: unknown name (valid names are listed), or a value outside its bounds (the message gives the
                parameter, the value, the bounds and the unit).
        """
        unknown = sorted(set(values) - set(self.params))
        if unknown:
            raise ValueError(f"unknown parameter(s) {unknown} for {self.name}; valid: {list(self.params)}")
        checked = {key: self.params[key].check(value) for key, value in values.items()}
        for key, value in checked.items():
            self.params[key].set_si(value)

    def bounds(self) -> dict[str, tuple[float, float]]:
        """Bounds ``(lo, hi)`` of every parameter in its SI unit."""
        return {key: (param.lo, param.hi) for key, param in self.params.items()}

    def max_viscosity(self, shear_rate_max: float) -> float:
        """Upper bound of eta [Pa·s] over shear rates [0, ``shear_rate_max``] [1/s], without gradient.

        The default, max(eta(0), eta(shear_rate_max)), is exact for laws monotone in the shear rate.
        """
        with torch.no_grad():
            return float(self.forward(self._shear_rates(0.0, _check_rate_max(shear_rate_max))).max())

    def zero_shear_viscosity(self) -> Tensor:
        """eta(0) [Pa·s] as a differentiable 0-d tensor (finite for every law, see the module docstring)."""
        return self.forward(self._shear_rates(0.0)[0])

    def _shear_rates(self, *values: float) -> Tensor:
        """A 1-d tensor of shear rates [1/s] with the dtype and device of the law's parameters (or buffers)."""
        ref = next(iter(self.parameters()), None)
        if ref is None:
            ref = next(iter(self.buffers()))
        return torch.tensor(values, dtype=ref.dtype, device=ref.device)

    def __repr__(self) -> str:
        fields = [f"{key}={value:.6g}{_unit_suffix(self.units[key])}" for key, value in self.parameters_si().items()]
        return f"{type(self).__name__}({', '.join(fields + self._extra_fields())})"

    def _extra_fields(self) -> list[str]:
        return []


class RegularisedLaw(RheologyLaw):
    """A law with a regularisation shear rate g_c [1/s] that keeps eta finite at g = 0 (see the module docstring).

    Args:
        values, bounds, dtype, device: as for :class:`RheologyLaw`.
        shear_rate_reg: g_c [1/s], > 0. Not a fitted parameter.
    """

    def __init__(
        self,
        values: Mapping[str, float],
        bounds: Mapping[str, tuple[float, float]] | None,
        shear_rate_reg: float,
        *,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        shear_rate_reg = float(shear_rate_reg)
        if not (math.isfinite(shear_rate_reg) and shear_rate_reg > 0.0):
            raise ValueError(f"shear_rate_reg must be a finite positive shear rate in 1/s, got {shear_rate_reg}")
        super().__init__(values, bounds, dtype=dtype, device=device)
        self.shear_rate_reg = shear_rate_reg

    def _extra_fields(self) -> list[str]:
        return [f"shear_rate_reg={self.shear_rate_reg:.6g} 1/s"]

    def _regularised_power(self, shear_rate: Tensor, n: Tensor) -> Tensor:
        """(g^2 + g_c^2)^((n-1)/2) [s^(1-n)]."""
        return (shear_rate * shear_rate + self.shear_rate_reg**2) ** ((n - 1.0) / 2.0)

    def _papanastasiou(self, shear_rate: Tensor) -> Tensor:
        """(1 - exp(-g/g_c)) / g [s], equal to 1/g_c at g = 0."""
        return _one_minus_exp_ratio(shear_rate / self.shear_rate_reg) / self.shear_rate_reg


class Newtonian(RheologyLaw):
    """eta = eta [Pa·s], independent of the shear rate."""

    name = "newtonian"
    specs = {"eta": _VISCOSITY}

    def __init__(
        self,
        eta: float = 1.0,
        *,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__({"eta": eta}, bounds, dtype=dtype, device=device)

    def viscosity(self, shear_rate: Tensor, params: Mapping[str, Tensor]) -> Tensor:
        return params["eta"] * torch.ones_like(shear_rate)


class PowerLaw(RegularisedLaw):
    """Ostwald-de Waele, regularised: eta = k (g^2 + g_c^2)^((n-1)/2); k [Pa·s^n], n [1].

    eta = k g^(n-1) for g >> g_c; eta(0) = k g_c^(n-1).
    """

    name = "power_law"
    specs = {"k": _CONSISTENCY, "n": _FLOW_INDEX}

    def __init__(
        self,
        k: float = 1.0,
        n: float = 0.5,
        *,
        shear_rate_reg: float = DEFAULT_SHEAR_RATE_REG,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__({"k": k, "n": n}, bounds, shear_rate_reg, dtype=dtype, device=device)

    def viscosity(self, shear_rate: Tensor, params: Mapping[str, Tensor]) -> Tensor:
        return params["k"] * self._regularised_power(shear_rate, params["n"])


class Carreau(RheologyLaw):
    """eta = eta_inf + (eta0 - eta_inf) (1 + (lam g)^2)^((n-1)/2).

    eta0, eta_inf [Pa·s], lam [s], n [1]. With eta0 > eta_inf, n < 1 thins and n > 1 thickens; eta_inf is not
    constrained below eta0. With eta_inf > eta0 and n > 1 the formula falls without bound and turns negative at
    high shear rates, which no fluid does (and no explicit step survives): eta is floored at 0 there.
    """

    name = "carreau"
    specs = {"eta0": _VISCOSITY, "eta_inf": _VISCOSITY, "lam": _TIME, "n": _FLOW_INDEX}

    def __init__(
        self,
        eta0: float = 1.0,
        eta_inf: float = 1e-3,
        lam: float = 1.0,
        n: float = 0.5,
        *,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__({"eta0": eta0, "eta_inf": eta_inf, "lam": lam, "n": n}, bounds, dtype=dtype, device=device)

    def viscosity(self, shear_rate: Tensor, params: Mapping[str, Tensor]) -> Tensor:
        x = params["lam"] * shear_rate
        shape = (1.0 + x * x) ** ((params["n"] - 1.0) / 2.0)
        return (params["eta_inf"] + (params["eta0"] - params["eta_inf"]) * shape).clamp(min=0.0)


class Cross(RheologyLaw):
    """eta = eta_inf + (eta0 - eta_inf) / (1 + (lam g)^n).

    eta0, eta_inf [Pa·s], lam [s], n [1]. Unlike Carreau, every n > 0 thins here (for eta0 > eta_inf), and as
    n -> 0 the law becomes Newtonian, eta = (eta0 + eta_inf)/2 for g > 0. eta_inf is not constrained below eta0.
    """

    name = "cross"
    specs = {"eta0": _VISCOSITY, "eta_inf": _VISCOSITY, "lam": _TIME, "n": _CROSS_INDEX}

    def __init__(
        self,
        eta0: float = 1.0,
        eta_inf: float = 1e-3,
        lam: float = 1.0,
        n: float = 0.5,
        *,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__({"eta0": eta0, "eta_inf": eta_inf, "lam": lam, "n": n}, bounds, dtype=dtype, device=device)

    def viscosity(self, shear_rate: Tensor, params: Mapping[str, Tensor]) -> Tensor:
        x = params["lam"] * shear_rate
        return params["eta_inf"] + (params["eta0"] - params["eta_inf"]) / (1.0 + _power_from_zero(x, params["n"]))


class HerschelBulkley(RegularisedLaw):
    """Herschel-Bulkley with Papanastasiou regularisation:

        eta = tau_y (1 - exp(-g/g_c)) / g + k (g^2 + g_c^2)^((n-1)/2)

    tau_y [Pa], k [Pa·s^n], n [1]. For g >> g_c the stress is tau_y + k g^n; eta(0) = tau_y / g_c + k g_c^(n-1).
    """

    name = "herschel_bulkley"
    specs = {"tau_y": _STRESS, "k": _CONSISTENCY, "n": _FLOW_INDEX}

    def __init__(
        self,
        tau_y: float = 1.0,
        k: float = 1.0,
        n: float = 0.5,
        *,
        shear_rate_reg: float = DEFAULT_SHEAR_RATE_REG,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__({"tau_y": tau_y, "k": k, "n": n}, bounds, shear_rate_reg, dtype=dtype, device=device)

    def viscosity(self, shear_rate: Tensor, params: Mapping[str, Tensor]) -> Tensor:
        return params["tau_y"] * self._papanastasiou(shear_rate) + params["k"] * self._regularised_power(
            shear_rate, params["n"]
        )

    def max_viscosity(self, shear_rate_max: float) -> float:
        """tau_y / g_c plus the larger power-law term at g = 0 or ``shear_rate_max``: an upper bound [Pa·s]."""
        g = self._shear_rates(0.0, _check_rate_max(shear_rate_max))
        with torch.no_grad():
            p = self.constrained()
            return float(p["tau_y"] / self.shear_rate_reg + (p["k"] * self._regularised_power(g, p["n"])).max())


class Bingham(RegularisedLaw):
    """Bingham plastic with Papanastasiou regularisation: eta = tau_y (1 - exp(-g/g_c)) / g + eta_p.

    tau_y [Pa], eta_p [Pa·s]. For g >> g_c the stress is tau_y + eta_p g; eta(0) = tau_y / g_c + eta_p.
    """

    name = "bingham"
    specs = {"tau_y": _STRESS, "eta_p": _VISCOSITY}

    def __init__(
        self,
        tau_y: float = 1.0,
        eta_p: float = 0.1,
        *,
        shear_rate_reg: float = DEFAULT_SHEAR_RATE_REG,
        bounds: Mapping[str, tuple[float, float]] | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        super().__init__({"tau_y": tau_y, "eta_p": eta_p}, bounds, shear_rate_reg, dtype=dtype, device=device)

    def viscosity(self, shear_rate: Tensor, params: Mapping[str, Tensor]) -> Tensor:
        return params["tau_y"] * self._papanastasiou(shear_rate) + params["eta_p"]


class Tabulated(RheologyLaw):
    """A measured flow curve, not trainable: log eta is interpolated linearly in log g between the points and held
    constant beyond the first and last shear rate.

    Args:
        shear_rate: measured shear rates [1/s], > 0, distinct (any order).
        stress: measured shear stresses [Pa], > 0. Give this or ``viscosity``.
        viscosity: measured apparent viscosities [Pa·s], > 0.

    Attributes:
        shear_rate_range: the first and last tabulated shear rate [1/s].
    """

    name = "tabulated"
    specs = {}

    def __init__(
        self, shear_rate: ArrayLike, *, stress: ArrayLike | None = None, viscosity: ArrayLike | None = None
    ) -> None:
        super().__init__({})
        if (stress is None) == (viscosity is None):
            raise ValueError("Tabulated needs exactly one of stress [Pa] or viscosity [Pa·s]")
        g = _positive_array("shear_rate", shear_rate, "1/s")
        if stress is not None:
            values = _positive_array("stress", stress, "Pa")
        else:
            values = _positive_array("viscosity", viscosity, "Pa·s")
        if len(values) != len(g) or len(g) < 2:
            raise ValueError(
                f"Tabulated needs at least 2 shear rates and as many stress or viscosity values, "
                f"got {len(g)} and {len(values)}"
            )
        eta = values / g if stress is not None else values
        order = np.argsort(g)
        g, eta = g[order], eta[order]
        if np.any(np.diff(g) == 0.0):
            raise ValueError("shear_rate [1/s] has repeated values; average them before tabulating")
        self.shear_rate_range = (float(g[0]), float(g[-1]))
        self.register_buffer("log_shear_rate", torch.from_numpy(np.log(g)))
        self.register_buffer("log_viscosity", torch.from_numpy(np.log(eta)))

    def viscosity(self, shear_rate: Tensor, params: Mapping[str, Tensor]) -> Tensor:
        log_g = self.log_shear_rate.to(dtype=shear_rate.dtype)
        log_eta = self.log_viscosity.to(dtype=shear_rate.dtype)
        x = torch.log(shear_rate.clamp(*self.shear_rate_range))
        upper = torch.searchsorted(log_g, x.contiguous()).clamp(1, len(log_g) - 1)
        lower = upper - 1
        t = (x - log_g[lower]) / (log_g[upper] - log_g[lower])
        return torch.exp(log_eta[lower] + t * (log_eta[upper] - log_eta[lower]))

    def max_viscosity(self, shear_rate_max: float) -> float:
        """Exact maximum of eta [Pa·s] over [0, ``shear_rate_max``] [1/s]: it lies on an end or a table point."""
        g_max = _check_rate_max(shear_rate_max)
        nodes = [g for g in self.log_shear_rate.exp().tolist() if g < g_max]
        with torch.no_grad():
            return float(self.forward(self._shear_rates(0.0, g_max, *nodes)).max())

    def __repr__(self) -> str:
        eta = self.log_viscosity.exp()
        lo, hi = self.shear_rate_range
        return (
            f"Tabulated(n_points={len(eta)}, shear_rate=[{lo:.4g}, {hi:.4g}] 1/s, "
            f"viscosity=[{float(eta.min()):.4g}, {float(eta.max()):.4g}] Pa·s)"
        )


LAWS: dict[str, type[RheologyLaw]] = {
    cls.name: cls for cls in (Newtonian, PowerLaw, Carreau, Cross, HerschelBulkley, Bingham)
}


def has_yield_stress(name: str) -> bool:
    """Whether the law registered as ``name`` has a yield stress τ_y among its parameters (False for a name that is
    not in :data:`LAWS`, such as the corotated baseline)."""
    return name in LAWS and "tau_y" in LAWS[name].specs


def make_law(name: str, **params) -> RheologyLaw:
    """Build the law registered as ``name`` in :data:`LAWS` from SI keyword values (and ``bounds``, ``dtype``,
    ``device``, and ``shear_rate_reg`` for the regularised laws).

    Raises:
        ValueError: unknown name; the message lists the valid names.
    """
    if name not in LAWS:
        raise ValueError(f"unknown rheology law {name!r}; valid names: {sorted(LAWS)}")
    return LAWS[name](**params)


def within_bounds(name: str, params: Mapping[str, float]) -> dict[str, float]:
    """``params`` [SI] of the law registered as ``name``, each clipped into its parameter's default bounds (for a
    rough initial guess, or a value stored in float32 whose round-off crossed a bound)."""
    specs = LAWS[name].specs
    return {key: min(max(float(v), specs[key].bounds[0]), specs[key].bounds[1]) for key, v in params.items()}


def _one_minus_exp_ratio(x: Tensor) -> Tensor:
    """(1 - exp(-x)) / x for x >= 0, equal to 1 at x = 0, with exact values and gradients near 0.

    Below x = 1e-2 the Taylor series to x^5 is used (truncation error x^6/5040 < 2e-16).
    """
    small = x < 1e-2
    safe = torch.where(small, torch.ones_like(x), x)
    exact = -torch.expm1(-safe) / safe
    xs = torch.where(small, x, torch.zeros_like(x))
    series = 1.0 - xs / 2.0 * (1.0 - xs / 3.0 * (1.0 - xs / 4.0 * (1.0 - xs / 5.0 * (1.0 - xs / 6.0))))
    return torch.where(small, series, exact)


def _power_from_zero(x: Tensor, n: Tensor) -> Tensor:
    """x^n for x >= 0 and n > 0, equal to 0 at x = 0 with finite (zero) gradients there."""
    positive = x > 0
    safe = torch.where(positive, x, torch.ones_like(x))
    return torch.where(positive, safe**n, torch.zeros_like(x))


def _check_rate_max(shear_rate_max: float) -> float:
    value = float(shear_rate_max)
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError(f"shear_rate_max must be a finite shear rate >= 0 in 1/s, got {shear_rate_max}")
    return value


def _positive_array(field: str, values: ArrayLike, unit: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64).ravel()
    if not np.all(np.isfinite(array)) or np.any(array <= 0.0):
        raise ValueError(f"{field} must be finite and > 0 in {unit}")
    return array


def _unit_suffix(unit: str) -> str:
    return "" if unit == "1" else f" {unit}"
