"""Hidden physics: what the fitting models (a generalized Newtonian law in the paper's Kelvin-Voigt material) leave
out, as materials of the simulator for the virtual lab's truths and the diagnosis's candidates. Each is a physical
model with parameters, evolved inside the simulation.

``HiddenPhysics(law, ...)`` is a material for ``StirringSimulator``: the shear stress of the Kelvin-Voigt fluid,
2 η dev D with η = η_law(γ̇), changed by

* thixotropy (Moore 1959): a structure parameter λ ∈ [0, 1] per grid cell,
      dλ/dt = (1 − λ)/t_r − k γ̇ λ,        η = η_law(γ̇) (1 + α λ),
  built up at rest (time constant t_r [s]) and broken down by shear (k [1] per unit strain); α [1] is the extra
  viscosity of the fully built structure. Stepped implicitly: λ' = (λ + Δt/t_r) / (1 + Δt/t_r + Δt k γ̇).
* viscoelasticity (Jeffreys fluid): the viscosity splits into a solvent part (1 − β) η and a polymer part β η whose
  stress τ_p relaxes with time θ [s] per grid cell,
      θ dτ_p/dt + τ_p = 2 β η dev D,      σ_dev = 2 (1 − β) η dev D + τ_p,
  stepped implicitly: τ_p' = (τ_p + (Δt/θ) 2 β η dev D) / (1 + Δt/θ). In steady shear σ_dev = 2 η dev D (the law).
* temperature drift: the fluid warms at ``rate`` [K/s] from the recording's start temperature, and its viscosity
  follows η(T) = η(T0) exp(−b (T − T0)), b [1/K] (the linearised Arrhenius law, b = E_a/(R T0²)).

Simplification: λ and τ_p live on the grid cells (Eulerian) and are not advected with the fluid; the polymer stress
has no convected (upper-convected) terms, so there are no normal-stress differences. The fields are carried in
``State.material`` (checkpoint-safe), laid out as [t, λ (cells), τ_p (cells·d·d)], the parts present only when the
model is enabled. Every parameter is a bounded ``nn.Parameter`` (``diffstir.rheology.parameters``), so forces are
differentiable with respect to them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from diffstir.errors import is_number
from diffstir.mpm.materials import deviatoric_rate_of_strain, shear_rate
from diffstir.rheology.parameters import BoundedParameter


def _check(name: str, value: float, lo: float, hi: float, unit: str, *, open_lo: bool = True) -> None:
    ok = is_number(value) and (value > lo if open_lo else value >= lo)
    if not (ok and value <= hi):
        interval = f"({lo}, {hi}]" if open_lo else f"[{lo}, {hi}]"
        raise ValueError(f"{name} = {value!r}; expected a number in {interval} {unit}")


@dataclass(frozen=True)
class Thixotropy:
    """Moore thixotropy: ``alpha`` [1] extra viscosity of the built structure, ``breakdown`` k [1] (per unit
    strain), ``rebuild_time`` t_r [s], ``initial_structure`` λ0 [1] at the start (1: fully rested)."""

    alpha: float
    breakdown: float
    rebuild_time: float
    initial_structure: float = 1.0

    def __post_init__(self) -> None:
        _check("physics.thixotropy.alpha", self.alpha, 0.0, 1e3, "1 (dimensionless)")
        _check("physics.thixotropy.breakdown", self.breakdown, 0.0, 1e2, "1 (per unit strain)")
        _check("physics.thixotropy.rebuild_time", self.rebuild_time, 0.0, 1e4, "s")
        _check("physics.thixotropy.initial_structure", self.initial_structure, 0.0, 1.0, "1", open_lo=False)


@dataclass(frozen=True)
class Viscoelasticity:
    """Jeffreys viscoelasticity: polymer stress relaxation time ``relaxation_time`` θ [s] and the polymer's share
    of the viscosity ``polymer_fraction`` β [1], 0 < β < 1."""

    relaxation_time: float
    polymer_fraction: float = 0.5

    def __post_init__(self) -> None:
        _check("physics.viscoelasticity.relaxation_time", self.relaxation_time, 0.0, 1e2, "s")
        _check("physics.viscoelasticity.polymer_fraction", self.polymer_fraction, 0.0, 0.999, "1")


@dataclass(frozen=True)
class TemperatureDrift:
    """The fluid's temperature changes at ``rate`` [K/s] (positive: warming) and its viscosity by
    exp(−``sensitivity`` ΔT), ``sensitivity`` b [1/K] > 0 (liquids thin when warmed)."""

    rate: float
    sensitivity: float

    def __post_init__(self) -> None:
        _check("physics.temperature.rate", self.rate, -1.0, 1.0, "K/s", open_lo=False)
        _check("physics.temperature.sensitivity", self.sensitivity, 0.0, 0.5, "1/K")


class HiddenPhysics(nn.Module):
    """The paper's Kelvin-Voigt fluid with ``law`` plus optional thixotropy, viscoelasticity and temperature drift
    (see the module docstring), a ``materials.StatefulMaterial``. ``horizon`` [s]: the longest rollout, for the
    viscosity bound of the time step."""

    def __init__(self, law: nn.Module, *, thixotropy: Thixotropy | None = None,
                 viscoelasticity: Viscoelasticity | None = None, temperature: TemperatureDrift | None = None,
                 horizon: float = 60.0):
        super().__init__()
        if not hasattr(law, "max_viscosity"):
            raise TypeError(f"HiddenPhysics needs a rheology law such as Carreau(...), got {type(law).__name__}")
        _check("horizon", horizon, 0.0, 1e5, "s")
        self.law, self.horizon = law, float(horizon)
        self.thixotropy, self.viscoelasticity, self.temperature = thixotropy, viscoelasticity, temperature
        self.params = nn.ModuleDict()
        if thixotropy is not None:
            self.params["alpha"] = BoundedParameter("alpha", thixotropy.alpha, (1e-3, 1e3), "log", "1")
            self.params["breakdown"] = BoundedParameter("breakdown", thixotropy.breakdown, (1e-6, 1e2), "log", "1")
            self.params["rebuild_time"] = BoundedParameter("rebuild_time", thixotropy.rebuild_time, (1e-3, 1e4),
                                                           "log", "s")
        if viscoelasticity is not None:
            self.params["relaxation_time"] = BoundedParameter("relaxation_time", viscoelasticity.relaxation_time,
                                                              (1e-4, 1e2), "log", "s")
            self.params["polymer_fraction"] = BoundedParameter("polymer_fraction", viscoelasticity.polymer_fraction,
                                                               (0.0, 1.0), "linear", "1")
        if temperature is not None:
            self.params["temperature_rate"] = BoundedParameter("temperature_rate", temperature.rate, (-1.0, 1.0),
                                                               "linear", "K/s")
            self.params["sensitivity"] = BoundedParameter("sensitivity", temperature.sensitivity, (1e-4, 0.5),
                                                          "log", "1/K")

    def parameters_si(self) -> dict[str, float]:
        """The law's SI parameters and the hidden-physics parameters (alpha [1], breakdown [1], rebuild_time [s],
        relaxation_time [s], polymer_fraction [1], temperature_rate [K/s], sensitivity [1/K]) that are enabled."""
        values = dict(self.law.parameters_si()) if hasattr(self.law, "parameters_si") else {}
        values.update({k: float(p().detach()) for k, p in self.params.items()})
        return values

    def initial_material_state(self, scene) -> Tensor:
        """[t = 0, λ = λ0 on every cell, τ_p = 0 on every cell] for ``scene``'s grid, as one flat tensor."""
        cells, d = math.prod(n - 1 for n in scene.grid.shape), scene.dim
        kw = dict(dtype=scene.grid.origin.dtype, device=scene.grid.origin.device)
        parts = [torch.zeros(1, **kw)]
        if self.thixotropy is not None:
            parts.append(torch.full((cells,), float(self.thixotropy.initial_structure), **kw))
        if self.viscoelasticity is not None:
            parts.append(torch.zeros(cells * d * d, **kw))
        return torch.cat(parts)

    def viscosity_factor(self, time: Tensor) -> Tensor:
        """exp(−b rate t) [1]: the temperature drift's factor on the viscosity at ``time`` [s] since the start."""
        if self.temperature is None:
            return torch.ones_like(time)
        rate, b = self.params["temperature_rate"](), self.params["sensitivity"]()
        return torch.exp(-(b * rate).to(time.dtype) * time)

    def shear_stress(self, grad_v: Tensor, viscosity_cap: float, dt: float, *,
                     state: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Deviatoric stress [Pa] (K, d, d) of cells with velocity gradients ``grad_v`` [1/s] (K, d, d), and the
        material state after the step ``dt`` [s]; the viscosity is clamped at ``viscosity_cap`` [Pa·s]."""
        if state is None:
            raise ValueError("HiddenPhysics.shear_stress needs the material state (State.material); build the "
                             "initial state with StirringSimulator.initial_state")
        k, d = grad_v.shape[0], grad_v.shape[-1]
        dtype = grad_v.dtype
        dev_D = deviatoric_rate_of_strain(grad_v)
        g = shear_rate(dev_D)
        time = state[0]
        eta = self.law(g) * self.viscosity_factor(time)
        parts, offset = [(time + dt).reshape(1)], 1
        if self.thixotropy is not None:
            alpha, kb, tr = (self.params[n]().to(dtype) for n in ("alpha", "breakdown", "rebuild_time"))
            lam = state[offset:offset + k]
            offset += k
            lam = (lam + dt / tr) / (1.0 + dt / tr + dt * kb * g)
            eta = eta * (1.0 + alpha * lam)
            parts.append(lam)
        eta = eta.clamp(max=viscosity_cap)
        if self.viscoelasticity is None:
            return 2.0 * eta[:, None, None] * dev_D, torch.cat(parts)
        theta, beta = (self.params[n]().to(dtype) for n in ("relaxation_time", "polymer_fraction"))
        tau = state[offset:offset + k * d * d].view(k, d, d)
        a = dt / theta
        tau = (tau + a * 2.0 * beta * eta[:, None, None] * dev_D) / (1.0 + a)
        parts.append(tau.reshape(-1))
        return 2.0 * (1.0 - beta) * eta[:, None, None] * dev_D + tau, torch.cat(parts)

    def max_viscosity(self, shear_rate_max: float, dt: float | None = None) -> float:
        """Upper bound of the viscosity [Pa·s] up to ``shear_rate_max`` [1/s] within ``horizon``: the law's bound,
        times (1 + α) with thixotropy, times the temperature factor's largest value."""
        bound = float(self.law.max_viscosity(shear_rate_max))
        with torch.no_grad():
            if self.thixotropy is not None:
                bound *= 1.0 + float(self.params["alpha"]())
            if self.temperature is not None:
                drift = float(self.params["temperature_rate"]() * self.params["sensitivity"]())
                bound *= math.exp(max(0.0, -drift * self.horizon))
        return bound
