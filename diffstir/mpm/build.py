"""Building a scene: the grid around the cup, the fluid's particles, and its settled state at rest (cached)."""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import asdict, replace
from pathlib import Path

import torch
from torch import nn

from ..errors import SimulationError
from ..rig import Rig
from .boundaries import BAND, RodPose, RodWindow, cup_sdf, ghost_band, is_solid, rod_sdf, rod_shape
from .config import SimConfig
from .grid import Grid, flat_index
from .implicit_viscosity import StiffnessPattern
from .materials import deviatoric_rate_of_strain
from .packing import FINE, cup_solid_mass, rod_fill_points
from .projection import CellMatrices
from .scene import Scene
from .state import State
from .step import step
from .transfer import use_fused
from .viscous import CellStencil
from .walls import WallParticles

PADDING = 3  # cells of grid beyond the cup on every side: the ghost band and the stencil's reach


def build_scene(rig: Rig, config: SimConfig, density: float) -> Scene:
    """The static part of a simulation of ``rig`` filled with fluid of ``density`` [kg/m³]."""
    if not 1.0 <= density <= 3.0e4:
        raise ValueError(f"density = {density!r}; expected a fluid density in kg/m³ (water is 1000)")
    dtype, device, dx, d = config.torch_dtype, config.torch_device, config.dx, config.dim
    cup = rig.cup
    if cup.radius / dx < 4:
        raise ValueError(f"sim.dx = {dx} m is too coarse for a cup of radius {cup.radius} m (need >= 4 cells)")
    lo = [-cup.radius - PADDING * dx] * 2
    hi = [cup.radius + PADDING * dx] * 2
    if d == 3:
        lo.append(-PADDING * dx)
        hi.append(cup.fill_height + config.headroom + PADDING * dx)
    shape = tuple(int(math.ceil((h - l) / dx)) + 1 for l, h in zip(lo, hi))
    grid = Grid(origin=torch.tensor(lo, dtype=dtype, device=device), shape=shape, dx=dx)
    nodes = grid.node_positions()
    cup_phi, cup_normal = cup_sdf(cup, nodes)
    # the band's inner edge lies between node layers, so that round-off decides no node's membership
    reach = is_solid(cup_phi, dx) & (cup_phi > -(BAND + 1.5) * dx)
    bulk_modulus = density * config.sound_speed**2
    gravity = torch.zeros(d, dtype=dtype, device=device)
    if d == 3:
        gravity[2] = -rig.gravity
    spacing = dx / config.particles_per_cell
    cells_volume = spacing ** d
    offsets = grid.stencil_offsets()
    cup_nodes = torch.nonzero(reach).squeeze(1)
    rod = rod_shape(rig.rod, dx)
    mass_row = torch.zeros(1, 1, d + 1, dtype=dtype, device=device)
    mass_row[..., d] = density * cells_volume
    # a particle's base node (floor(x/dx − 1/2)) and its stencil's last node (+2) must lie on the grid
    highest = grid.origin + (torch.tensor(shape, dtype=dtype, device=device) - 1.5001) * dx
    bounds = torch.stack([grid.origin + 0.5001 * dx, highest])
    offset_index = flat_index(offsets, grid.strides())
    rod_spacing = spacing / FINE
    rod_height = rig.rod.immersion_depth + config.headroom + 2 * dx  # m above its tip that its particles fill
    cells = CellStencil.of(grid)
    return Scene(
        grid=grid, offset_index=offset_index,
        stencil_points=torch.cat([offsets, torch.ones(len(offsets), 1, dtype=torch.int64, device=device)], 1).to(dtype),
        eye=torch.eye(d, dtype=dtype, device=device), mass_row=mass_row, cells=cells,
        particle_bounds=bounds,
        strides=grid.strides(), nodes=nodes, cup=cup, cup_phi=cup_phi,
        cup_band=ghost_band(grid, cup_nodes, nodes[cup_nodes], cup_phi[cup_nodes], cup_normal[cup_nodes],
                            slip=cup.wall == "slip"),
        rod=rod, rod_window=RodWindow.of(grid, rod.radius), rod_slip=rig.rod.wall == "slip",
        rod_slip_length=rig.rod.slip_length,
        particle_mass=density * cells_volume, particle_volume=cells_volume, node_mass=density * dx**d,
        bulk_modulus=bulk_modulus,
        gravity=gravity, viscosity_cap=config.viscosity_cap,
        flip=config.flip, relaxation_rate=1.0 / config.volume_relaxation if config.volume_relaxation > 0 else 0.0,
        solid_mass=cup_solid_mass(grid, cup, spacing, density, offset_index, grid.strides(), bounds),
        rod_points=rod_fill_points(rod, dx, rod_spacing, rod_height, d, dtype, device),
        rod_point_mass=density * rod_spacing ** d,
        cell_matrices=(CellMatrices.of(cells, grid.num_nodes) if config.pressure == "projection"
                       else None),
        walls=(WallParticles.of(grid, cup, rod, spacing, rod_height, offset_index, bounds) if config.wall_pressure
               else None),
        fused=use_fused(config.kernels, device),
        viscous_stiffness=(StiffnessPattern.of(cells, grid.num_nodes) if config.viscous_solver == "implicit"
                           else None),
    )


def seed_particles(scene: Scene, rig: Rig, config: SimConfig, pose: RodPose) -> State:
    """Particles on a regular lattice, ``particles_per_cell`` per axis, filling the cup to its fill height
    around the rod at ``pose``; at rest with volume ratio 1."""
    grid, d, ppc = scene.grid, scene.dim, config.particles_per_cell
    spacing = grid.dx / ppc
    lo = grid.origin + 0.5 * spacing
    counts = [int(grid.shape[a] * ppc) for a in range(d)]
    axes = [lo[a] + spacing * torch.arange(counts[a], dtype=lo.dtype, device=lo.device) for a in range(d)]
    x = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, d)
    keep = (cup_sdf(rig.cup, x)[0] > 0) & (rod_sdf(scene.rod, x, pose)[0] > 0)
    if d == 3:
        keep &= x[:, 2] < rig.cup.fill_height
    x = x[keep]
    n = x.shape[0]
    zeros = torch.zeros_like(x)
    return State(x=x, v=zeros, C=torch.zeros(n, d, d, dtype=x.dtype, device=x.device),
                 J=torch.ones(n, dtype=x.dtype, device=x.device))


class _SettlingFluid(nn.Module):
    """A Newtonian fluid of fixed viscosity used only to let the fluid settle under gravity."""

    def __init__(self, viscosity: float):
        super().__init__()
        self.viscosity = viscosity

    def shear_stress(self, grad_v, viscosity_cap, dt):
        return 2.0 * self.viscosity * deviatoric_rate_of_strain(grad_v)


def cache_root(cache_dir: str | Path | None = None) -> Path:
    """Where diffstir keeps what it computes once (settled fluids, a rig's plan calibration): ``cache_dir``, else
    ``$DIFFSTIR_CACHE_DIR``, else ``~/.cache/diffstir``."""
    return Path(cache_dir or os.environ.get("DIFFSTIR_CACHE_DIR", Path.home() / ".cache" / "diffstir"))


def settled_state(scene: Scene, rig: Rig, config: SimConfig, density: float, pose: RodPose,
                  cache_dir: str | Path | None = None) -> State:
    """The fluid at rest around a still rod: seeded, then left to settle with damping, under gravity in 3-D and, in
    both, until its packing around the rod (``packing``) is in equilibrium.

    The result depends only on the rig, the resolution, the density and the rod's starting pose, not on the
    rheology, so it is computed once and cached on disk (``cache_dir``, default ``$DIFFSTIR_CACHE_DIR`` or
    ``~/.cache/diffstir``).
    """
    state = seed_particles(scene, rig, config, pose)
    if config.settle_time <= 0:
        return state
    # a rollout may have raised the bulk modulus; a projection's fluid settles as the compressible one, with an
    # explicit shear stress whatever the rollout's
    scene = replace(scene, bulk_modulus=density * config.sound_speed**2, cell_matrices=None, viscous_stiffness=None)
    key = _settle_key(rig, config, density, pose)
    path = cache_root(cache_dir) / "settled" / f"{key}.pt"
    if path.exists():
        cached = torch.load(path, map_location=state.x.device)
        if cached["x"].shape == state.x.shape:
            return State(x=cached["x"].to(state.x), v=torch.zeros_like(state.x), C=torch.zeros_like(state.C),
                         J=cached["J"].to(state.J))
    # any viscosity that the acoustic step resolves settles the fluid; the damping does the rest
    dt = config.cfl * config.dx / config.sound_speed
    fluid = _SettlingFluid(viscosity=0.5 * config.viscous_safety * density * config.dx**2 / (2 * config.dim * dt))
    damping = math.exp(-dt / 0.02)  # velocity decays with a 20 ms time constant
    still = RodPose(axis=pose.axis, tip=pose.tip, angle=pose.angle, velocity=torch.zeros_like(pose.velocity),
                    angular_velocity=torch.zeros_like(pose.angular_velocity))
    with torch.no_grad():
        for k in range(int(math.ceil(config.settle_time / dt))):
            state, _, _ = step(scene, fluid, state, still, dt)
            state.v = state.v * damping
            state.C = state.C * damping
            if not (torch.isfinite(state.x).all() and torch.isfinite(state.J).all()):  # and nothing is cached
                raise SimulationError(f"the fluid became non-finite while settling, at step {k} of dt = {dt:.3g} "
                                         f"s (sim.dx = {config.dx} m, sim.sound_speed = {config.sound_speed} m/s, "
                                         f"sim.cfl = {config.cfl}); try a smaller sim.cfl")
    settled = State(x=state.x, v=torch.zeros_like(state.v), C=torch.zeros_like(state.C), J=state.J)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    torch.save({"x": settled.x.cpu(), "J": settled.J.cpu()}, tmp)
    os.replace(tmp, path)
    return settled


def _settle_key(rig: Rig, config: SimConfig, density: float, pose: RodPose) -> str:
    fields = {k: v for k, v in asdict(config).items() if k in ("dim", "dx", "particles_per_cell", "sound_speed", "cfl",
                                                                 "headroom", "settle_time", "dtype", "flip",
                                                                 "volume_relaxation")}
    if config.wall_pressure:  # keyed only when on, so that the caches of the states settled without it stay valid
        fields["wall_pressure"] = True
    payload = json.dumps({"rig": asdict(rig), "sim": fields, "density": density, "version": 2,
                          "pose": [round(float(v), 9) for v in (*pose.axis.tolist(), pose.tip, pose.angle)]},
                         sort_keys=True, default=str)
    return hashlib.sha256(payload.encode()).hexdigest()[:20]
