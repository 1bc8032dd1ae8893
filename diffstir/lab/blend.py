"""Two fluids stirred together: the virtual lab's mixing mode, with a known time course of the viscosity.

Every particle carries the volume fraction c ∈ [0, 1] of fluid 1. Fluid 1 starts in one region (``layout``:
``core``, the central disc; ``annulus``, along the wall; ``half``, the side x < x_φ), chosen by particle count so
that its volume fraction is exactly φ. The cell viscosity follows the Lederer-Roegiers rule
(``diffstir.rheology.blending``) of the two laws at the cell's shear rate and concentration.

Macro-mixing is the flow itself: particles carry c along as the rod stretches and folds the fluid. What the grid
cannot resolve (striations thinner than a cell, then molecular diffusion across them) is the IEM micro-mixing
model (interaction by exchange with the mean; Villermaux and Devillon 1972, Fox 2003): c relaxes towards its local
mean at the rate

    r = D / Δx² + β γ̇      [1/s],

with D the molecular diffusivity [m²/s] and β [1] the mixing per unit shear strain. Every ``interval`` [s] the
local mean is taken on the grid's nodes with the simulator's quadratic B-spline weights w_pk, c_k = Σ_p w_pk c_p
/ Σ_p w_pk (likewise the rate, from the particles' shear rates), and each particle moves towards it,

    c_p ← c_p + Σ_k w_pk (1 − exp(−r_k Δt)) (c_k − c_p),

which conserves Σ_p c_p exactly (equal particle masses) and keeps c in [0, 1] (a convex combination) at any Δt.

Truth time courses, sampled every ``interval``: the intensity of segregation I = var(c) / (c̄ (1 − c̄)) (1 unmixed,
0 homogeneous; Danckwerts 1952); the coefficient of variation of c, whose fall below 5 % is the usual 95 %
mixing time; and the dissipation-weighted viscosity η_D = Σ_p η_p γ̇_p² / Σ_p γ̇_p², the viscosity of the
Newtonian fluid that would dissipate the same power in the same flow.

Simplifications: one density for both fluids (their volume-weighted mean; the simulator's particles share one
mass, and a horizontal 2-D slice has no buoyancy anyway); no interfacial tension.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace

import numpy as np
import torch
from torch import Tensor, nn

from diffstir.errors import is_number
from diffstir.lab.fluid import Fluid
from diffstir.lab.sensor import SensorModel
from diffstir.lab.synth import HiddenPhysicsSpec, LabRecording, TruthSimulation, check_programme, read_truth
from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.mpm.grid import quadratic_stencil
from diffstir.mpm.materials import deviatoric_rate_of_strain, shear_rate
from diffstir.rheology.blending import lederer_roegiers
from diffstir.rig import Rig
from diffstir.slice_correction import trajectory_correction
from diffstir.trajectory import Trajectory

LAYOUTS = ("core", "annulus", "half")
HOMOGENEITY_COV = 0.05  # coefficient of variation of c at the 95 % mixing time


@dataclass(frozen=True)
class Blend:
    """Fluid ``first`` (volume fraction ``fraction`` φ [1], starting in ``layout``) stirred into ``second``;
    Lederer-Roegiers ``alpha`` [1]; IEM ``strain_mixing`` β [1] and ``diffusivity`` D [m²/s]; concentrations
    updated every ``interval`` [s]."""

    first: Fluid
    second: Fluid
    fraction: float
    alpha: float = 1.0
    layout: str = "core"
    strain_mixing: float = 0.05
    diffusivity: float = 1e-9
    interval: float = 0.02

    def __post_init__(self) -> None:
        checks = (("fraction", self.fraction, 0.0, 1.0, "1"), ("alpha", self.alpha, 0.0, 1.0, "1"),
                  ("strain_mixing", self.strain_mixing, 0.0, 10.0, "1"),
                  ("diffusivity", self.diffusivity, 0.0, 1e-3, "m^2/s"), ("interval", self.interval, 0.0, 1.0, "s"))
        for name, value, lo, hi, unit in checks:
            if not (is_number(value) and lo <= value <= hi) or (name in ("fraction", "interval")
                                                                             and value in (lo, hi)):
                raise ValueError(f"blend.{name} = {value!r}; expected a number in [{lo}, {hi}] {unit}")
        if self.layout not in LAYOUTS:
            raise ValueError(f"blend.layout = {self.layout!r}; expected one of {LAYOUTS}")

    @classmethod
    def from_mapping(cls, cfg: Mapping) -> "Blend":
        """From ``{first: <fluid>, second: <fluid>, fraction, alpha, layout, strain_mixing, diffusivity,
        interval}`` (fluids as in ``Fluid.from_mapping``)."""
        cfg = dict(cfg)
        unknown = sorted(set(cfg) - {f for f in cls.__dataclass_fields__})
        if unknown:
            raise ValueError(f"blend: unknown field(s) {unknown}; expected {sorted(cls.__dataclass_fields__)}")
        return cls(**{**cfg, "first": Fluid.from_mapping(cfg["first"]), "second": Fluid.from_mapping(cfg["second"])})

    @property
    def density(self) -> float:
        """φ ρ1 + (1 − φ) ρ2 [kg/m³]."""
        return self.fraction * self.first.density + (1.0 - self.fraction) * self.second.density

    def as_dict(self) -> dict:
        return {**{k: v for k, v in asdict(self).items() if k not in ("first", "second")},
                "first": {"name": self.first.name, "density": self.first.density, "law": dict(self.first.law)},
                "second": {"name": self.second.name, "density": self.second.density, "law": dict(self.second.law)},
                "density": self.density}


class BlendMaterial(nn.Module):
    """The paper's Kelvin-Voigt fluid whose cells hold a concentration c of fluid 1 (``State.material`` =
    [t, c per cell]) and whose viscosity is the Lederer-Roegiers blend of ``first`` and ``second`` at the cell's
    shear rate."""

    def __init__(self, first: nn.Module, second: nn.Module, alpha: float):
        super().__init__()
        self.first, self.second, self.alpha = first, second, float(alpha)

    def initial_material_state(self, scene) -> Tensor:
        cells = math.prod(n - 1 for n in scene.grid.shape)
        return torch.zeros(1 + cells, dtype=scene.grid.origin.dtype, device=scene.grid.origin.device)

    def viscosity(self, rate: Tensor, c: Tensor) -> Tensor:
        """η [Pa·s] at shear rates ``rate`` [1/s] and concentrations ``c`` [1]."""
        return lederer_roegiers(self.first(rate), self.second(rate), c.clamp(1e-9, 1.0), self.alpha)

    def shear_stress(self, grad_v: Tensor, viscosity_cap: float, dt: float, *,
                     state: Tensor) -> tuple[Tensor, Tensor]:
        """2 η dev D [Pa] (K, d, d) with η clamped at ``viscosity_cap`` [Pa·s]; the state advances its clock."""
        dev_D = deviatoric_rate_of_strain(grad_v)
        eta = self.viscosity(shear_rate(dev_D), state[1:]).clamp(max=viscosity_cap)
        return 2.0 * eta[:, None, None] * dev_D, torch.cat([(state[0] + dt).reshape(1), state[1:]])

    def max_viscosity(self, shear_rate_max: float) -> float:
        return max(self.first.max_viscosity(shear_rate_max), self.second.max_viscosity(shear_rate_max))


def initial_concentration(x: Tensor, layout: str, fraction: float) -> Tensor:
    """c [1] of particles at ``x`` [m] (N, d): 1 on the share ``fraction`` of them nearest the cup's axis
    (``core``), nearest its wall (``annulus``) or with the smallest x (``half``), else 0."""
    key = {"core": x[:, :2].norm(dim=1), "annulus": -x[:, :2].norm(dim=1), "half": x[:, 0]}[layout]
    c = torch.zeros(x.shape[0], dtype=x.dtype, device=x.device)
    c[torch.argsort(key)[: int(round(fraction * x.shape[0]))]] = 1.0
    return c


def mix(scene, x: Tensor, rate: Tensor, c: Tensor, dt: float, diffusivity: float, strain_mixing: float) -> Tensor:
    """One IEM exchange over ``dt`` [s] (module docstring) of particle concentrations ``c`` at ``x`` [m] with shear
    rates ``rate`` [1/s]."""
    st = quadratic_stencil(scene.grid, x, scene.offset_index, scene.strides)
    node = _node_mean(scene, st, torch.stack([c, rate]))
    relax = 1.0 - torch.exp(-dt * (diffusivity / scene.grid.dx**2 + strain_mixing * node[1]))
    pull = (st.weight * relax[st.index]).sum(1)
    return c + (st.weight * (relax * node[0])[st.index]).sum(1) - pull * c


def cell_concentration(scene, x: Tensor, c: Tensor) -> Tensor:
    """c [1] of each grid cell: the mean of its corners' B-spline-weighted node concentrations (corners without
    fluid left out; 0 in empty cells)."""
    st = quadratic_stencil(scene.grid, x, scene.offset_index, scene.strides)
    weight = torch.zeros(scene.grid.num_nodes, dtype=c.dtype, device=c.device).index_add_(
        0, st.index.reshape(-1), st.weight.reshape(-1))
    node = _node_mean(scene, st, c[None])[0]
    has = (weight > 0).to(c.dtype)[scene.cells.corners]
    return (node[scene.cells.corners] * has).sum(1) / has.sum(1).clamp(min=1.0)


def _node_mean(scene, st, values: Tensor) -> Tensor:
    """Σ_p w_pk v_p / Σ_p w_pk on the nodes for each row of ``values`` (R, N); 0 where no particle reaches."""
    n = scene.grid.num_nodes
    w = st.weight.reshape(-1)
    total = torch.zeros(n, dtype=values.dtype, device=values.device).index_add_(0, st.index.reshape(-1), w)
    sums = torch.stack([torch.zeros(n, dtype=values.dtype, device=values.device).index_add_(
        0, st.index.reshape(-1), (st.weight * v[:, None]).reshape(-1)) for v in values])
    return sums / total.clamp(min=1e-30)


@dataclass
class BlendHistory:
    """Truth time courses at ``times`` [s]: ``intensity`` of segregation [1], coefficient of variation ``cov`` of
    c [1], dissipation-weighted viscosity ``viscosity`` [Pa·s], and ``mixing_time`` t_95 [s] (None when c never
    came within 5 % of homogeneous)."""

    times: np.ndarray
    intensity: np.ndarray
    cov: np.ndarray
    viscosity: np.ndarray
    mixing_time: float | None

    def as_dict(self) -> dict:
        return {"times": self.times.tolist(), "intensity_of_segregation": self.intensity.tolist(),
                "coefficient_of_variation": self.cov.tolist(), "dissipation_viscosity": self.viscosity.tolist(),
                "mixing_time_95": self.mixing_time, "homogeneity_cov": HOMOGENEITY_COV,
                "units": {"times": "s", "dissipation_viscosity": "Pa s", "mixing_time_95": "s"}}


def simulate_blend(blend: Blend, trajectory: Trajectory, *, rig: Rig | None = None,
                   sim_config: SimConfig | None = None, seed: int = 0,
                   cache_dir=None) -> tuple[TruthSimulation, BlendHistory]:
    """Stir ``blend`` along ``trajectory``: the truth force on the rod and the mixing's time courses."""
    rig, sim_config = rig or Rig(), sim_config or SimConfig(dim=2)
    torch.manual_seed(seed)
    material = BlendMaterial(blend.first.make_law(), blend.second.make_law(), blend.alpha)
    sim = StirringSimulator(material, rig, sim_config, density=blend.density, cache_dir=cache_dir)
    # one step and one sound speed for every chunk: the sensor model needs uniform times
    dt = sim.time_step(trajectory)
    sim.config = replace(sim.config, dt=dt, rollout_sound_speed=sim.sound_speed(trajectory))
    scene = sim.scene
    state = sim.initial_state(trajectory)
    c = initial_concentration(state.x, blend.layout, blend.fraction)
    steps = int(round(trajectory.duration / dt))
    edges = trajectory.t[0] + dt * np.append(np.arange(0, steps, max(1, int(round(blend.interval / dt)))), steps)
    times, forces, history = [], [], []
    with torch.no_grad():
        for t0, t1 in zip(edges[:-1], edges[1:]):
            history.append(_snapshot(material, state, c, t0))
            state.material = torch.cat([state.material[:1], cell_concentration(scene, state.x, c)])
            t = np.linspace(t0, t1, max(2, math.ceil((t1 - t0) * 1000.0)) + 1)
            xy, z, angle = trajectory.poses(t)
            result = sim(Trajectory(t, xy, z, angle), initial=state)
            state = result.state
            times.append(t0 + dt * (np.arange(result.times.numel()) + 0.5))  # mid-step, float64
            forces.append(result.force.double().cpu().numpy()[:, :2])
            rate = shear_rate(deviatoric_rate_of_strain(state.C))
            c = mix(scene, state.x, rate, c, t1 - t0, blend.diffusivity, blend.strain_mixing)
        history.append(_snapshot(material, state, c, float(edges[-1])))
    factor, length = 1.0, 1.0  # 3-D: newtons
    if sim_config.dim == 2:  # F = F' h C
        factor = trajectory_correction(rig, material, blend.density, trajectory, np.concatenate(times)).factor
        length = rig.rod.immersion_depth * factor
    stats = np.array(history)
    cov = stats[:, 2]
    settled = np.flatnonzero(cov > HOMOGENEITY_COV)
    mixing_time = None if cov[-1] > HOMOGENEITY_COV else float(stats[settled[-1] + 1, 0] if settled.size else
                                                                   stats[0, 0])
    fluid = Fluid(name=f"blend of {blend.first.name} and {blend.second.name}", density=blend.density,
                  law=blend.first.law)
    truth = TruthSimulation(fluid, trajectory, rig, sim_config, HiddenPhysicsSpec(), np.concatenate(times),
                            np.concatenate(forces) * length, dt,
                            {"method": f"MLS-MPM, {sim_config.dim}-D, two fluids (diffstir.lab.blend)",
                             "particles": int(state.num_particles), "grid": list(scene.grid.shape)},
                            sim_config.dim == 2, factor)
    return truth, BlendHistory(stats[:, 0], stats[:, 1], cov, stats[:, 3], mixing_time)


def _snapshot(material: BlendMaterial, state, c: Tensor, t: float) -> tuple[float, ...]:
    """(t [s], intensity of segregation, coefficient of variation, dissipation-weighted viscosity [Pa·s])."""
    rate = shear_rate(deviatoric_rate_of_strain(state.C))
    eta = material.viscosity(rate, c)
    weight = rate**2
    eta_d = float((eta * weight).sum() / weight.sum()) if float(weight.sum()) > 0 else float(eta.mean())
    var, mean = float(c.var(unbiased=False)), float(c.mean())
    return t, var / (mean * (1.0 - mean)), math.sqrt(var) / mean, eta_d


def synthesise_blend(blend: Blend, trajectory: Trajectory, *, rig: Rig | None = None,
                     sim_config: SimConfig | None = None, sensor: SensorModel | None = None, seed: int = 0,
                     name: str | None = None, label: str | None = None, programme: Mapping | None = None,
                     cache_dir=None) -> LabRecording:
    """A recording of ``blend`` stirred along ``trajectory`` read through ``sensor``; its truth holds the blend and
    the mixing's time courses (``truth["blend"]``); a programme whose recording would be invalid is refused first
    (``check_programme``)."""
    check_programme(blend.first, trajectory, rig, sensor)
    truth_sim, history = simulate_blend(blend, trajectory, rig=rig, sim_config=sim_config, seed=seed,
                                        cache_dir=cache_dir)
    lab = read_truth(truth_sim, sensor, seed=seed, name=name, label=label, programme=programme)
    lab.truth["fluid"] = {"name": truth_sim.fluid.name, "density": blend.density, "blend": blend.as_dict()}
    lab.truth["mixing"] = history.as_dict()
    return lab
