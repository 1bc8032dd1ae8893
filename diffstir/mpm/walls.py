"""Boundary particles that carry the fluid's pressure into the solids (``SimConfig.wall_pressure``).

A fluid particle next to a solid face has part of its quadratic stencil in the solid, where no particle carries
pressure, so the fluid's nodes next to the face are pushed away from it and the particles there are left at a
fraction of the pressure: under the 3-D rod's tip, half the hydrostatic value (docs/validation.md). Dummy wall
particles with the fluid's pressure extrapolated to them (Adami, Hu and Adams 2012, J. Comput. Phys. 231, 7057)
complete the stencil. A boundary particle b at x_b takes the state of the fluid at the ghost probe a distance
δ = ``PROBE_DISTANCE`` cells outside the surface along its normal n_b, x_probe = x_b + (δ − φ_b) n_b (φ_b < 0: the
particle's signed distance): the particles' volume ratio J and pressure p = −τ_v(J) interpolated there
(mass-weighted), the pressure continued hydrostatically,

    p_b = max(0, p(x_probe) + ρ g · (x_b − x_probe)),      V_b = J(x_probe) V0,

none where the probe lies at a free surface (its stencil less than ``SURFACE_FILL`` full). It gives node i the
MLS-MPM pressure impulse of a fluid particle of volume V_b and pressure p_b at that place,

    Δq_i = (4 Δt / dx²) V_b p_b w_ib (x_i − x_b),

whose sum over the nodes is zero (Σ_i w_ib (x_i − x_b) = 0). What the rod's particles give the fluid's nodes is the
rod's push on the fluid, so it enters the rod's reaction with the opposite sign (``step.grid_update``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from ..rig import Cup
from . import transfer
from .boundaries import PROBE_DISTANCE, RodPose, RodShape, cup_sdf, rod_sdf
from .grid import Grid, Stencil, quadratic_stencil
from .materials import volumetric_stress
from .packing import SURFACE_FILL, lattice, place_rod_points, rod_fill_points
from .state import State

if TYPE_CHECKING:
    from .step import Scene

#: Cells into the cup that its boundary particles fill: a node reaches a particle within 1.5 cells along each axis,
#: so through the bottom (axis-aligned) at most 1.5 cells deep and through the vertical wall 1.5 sqrt(2) ≈ 2.12; a
#: particle deeper gives only the cup's own nodes, which take nothing.
DEPTH = 2.2


@dataclass(frozen=True)
class Stencils:
    """Where boundary particles meet the nodes: the quadratic stencils of their probes (``probe_index`` (B, 3^d)
    int64, ``probe_weight`` [1] (B, 3^d)) and of themselves (``index`` (B, 3^d) int64 with
    ``push`` = w_ib (x_i − x_b) / dx [1] (B, 3^d, d)), and x_b − x_probe, ``lever`` [m] (B, d)."""

    probe_index: Tensor
    probe_weight: Tensor
    index: Tensor
    push: Tensor
    lever: Tensor

    @classmethod
    def of(cls, grid: Grid, points: Tensor, phi: Tensor, normal: Tensor, offsets: Tensor, offset_index: Tensor,
           strides: Tensor, bounds: Tensor) -> "Stencils":
        """The stencils of boundary particles at ``points`` [m] of signed distance ``phi`` [m] and unit normal into
        the fluid ``normal``, their probes ``PROBE_DISTANCE`` cells outside the surface, on ``grid`` (its stencil's
        node ``offsets`` in cells (3^d, d), their flat ``offset_index`` and the flat ``strides``); positions are
        clamped to the particles' ``bounds`` (2, d) [m]."""
        probes = points + (PROBE_DISTANCE * grid.dx - phi)[:, None] * normal
        at_probe = quadratic_stencil(grid, torch.clamp(probes, bounds[0], bounds[1]), offset_index, strides)
        at_wall = quadratic_stencil(grid, torch.clamp(points, bounds[0], bounds[1]), offset_index, strides)
        push = at_wall.weights()[:, :, None] * (offsets[None] - at_wall.frac[:, None, :])
        return cls(at_probe.index, at_probe.weights(), at_wall.index, push, points - probes)


@dataclass(frozen=True)
class WallParticles:
    """The boundary particles of a scene, on the fluid's seeding lattice: the rod's in its own frame [m], (R, d)
    (``packing.rod_fill_points``), which move with it, and the ``Stencils`` of the cup's, which do not."""

    rod: Tensor
    cup: Stencils

    @classmethod
    def of(cls, grid: Grid, cup: Cup, rod: RodShape, spacing: float, rod_height: float, offset_index: Tensor,
           bounds: Tensor) -> "WallParticles":
        """The particles on a lattice of ``spacing`` [m]: the cup's within ``DEPTH`` cells of its surface and inside
        the particles' ``bounds`` (2, d) [m], the rod's those of ``packing.rod_fill_points`` up to ``rod_height``
        [m] above its tip."""
        points = lattice(grid, spacing)
        phi, normal = cup_sdf(cup, points)
        keep = (phi <= 0) & (phi > -DEPTH * grid.dx) & ((points >= bounds[0]) & (points <= bounds[1])).all(1)
        offsets = grid.stencil_offsets().to(points.dtype)
        return cls(rod=rod_fill_points(rod, grid.dx, spacing, rod_height, grid.dim, points.dtype, points.device),
                   cup=Stencils.of(grid, points[keep], phi[keep], normal[keep], offsets, offset_index,
                                   grid.flat_strides, bounds))


def fluid_state(scene: "Scene", state: State, st: Stencil, mass: Tensor) -> Tensor:
    """Σ_p w_ip m_p (p_p, J_p, 1) on each node: the particles' pressure p = −τ_v(J) [Pa] and volume ratio J [1]
    weighted by the mass they put there, and that mass ``mass`` [kg] (p2g's) (2-D: per unit length),
    (num_nodes, 3)."""
    values = scene.particle_mass * torch.stack([-volumetric_stress(state.J, scene.bulk_modulus), state.J])  # (2, N)
    rows = torch.cat([torch.zeros(2, values.shape[1], scene.dim, dtype=values.dtype, device=values.device),
                      values[:, :, None]], 2)  # (2, N, d + 1): rows [0, m p] and [0, m J] (``transfer.scatter``)
    weighted = transfer.scatter(rows, st, scene.grid.num_nodes, scene.stencil_points, scene.fused)
    return torch.cat([weighted, mass[:, None]], 1)


def pressure_impulse(scene: "Scene", weighted: Tensor, stencils: Stencils, dt: float) -> Tensor:
    """The impulse [N·s] (2-D: per unit length) that boundary particles of ``stencils`` give the nodes,
    (num_nodes, d) (module docstring), from the nodes' mass-weighted pressure, volume ratio and mass ``weighted``
    (``fluid_state``)."""
    grid, d = scene.grid, scene.dim
    count, k = stencils.index.shape
    at_probe = (weighted.index_select(0, stencils.probe_index.view(-1)).view(count, k, 3)
                * stencils.probe_weight[:, :, None]).sum(1)
    pressure, J = (at_probe[:, :2] / at_probe[:, 2:].clamp_min(1e-30)).unbind(1)
    in_fluid = at_probe[:, 2] > SURFACE_FILL * scene.node_mass
    density = scene.node_mass / grid.dx**d
    p_wall = torch.where(in_fluid, pressure + density * (stencils.lever @ scene.gravity), 0.0).clamp_min(0.0)
    scale = (4.0 * dt / grid.dx) * scene.particle_volume * J * p_wall  # [N·s], times w_ib (x_i − x_b) / dx
    contrib = (scale[:, None, None] * stencils.push).permute(2, 0, 1).reshape(d, -1)  # component-major
    index = stencils.index.view(1, -1).expand(d, -1)
    return torch.zeros(d, grid.num_nodes, dtype=weighted.dtype, device=weighted.device).scatter_add(
        1, index, contrib).T


def wall_impulses(scene: "Scene", state: State, st: Stencil, mass: Tensor, pose: RodPose,
                  dt: float) -> tuple[Tensor, Tensor]:
    """The pressure impulses [N·s] (2-D: per unit length) of the rod's and of the cup's boundary particles on the
    nodes, each (num_nodes, d), for particles of stencil ``st`` that put ``mass`` [kg] on the nodes (p2g's), the rod
    at ``pose`` (module docstring)."""
    weighted = fluid_state(scene, state, st, mass)
    points = place_rod_points(scene.rod, scene.walls.rod, pose)
    rod = Stencils.of(scene.grid, points, *rod_sdf(scene.rod, points, pose), scene.stencil_points[:, :scene.dim],
                      scene.offset_index, scene.strides, scene.particle_bounds)
    return pressure_impulse(scene, weighted, rod, dt), pressure_impulse(scene, weighted, scene.walls.cup, dt)
