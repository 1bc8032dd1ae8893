"""The fluid's pressure on the boundary particles of the solids (``walls``) and their impulse on the nodes.

A boundary particle b at x_b takes the state of the fluid at its ghost probe x_probe (``walls``): the particles'
volume ratio J and pressure p = −τ_v(J) interpolated there (mass-weighted), the pressure continued hydrostatically,

    p_b = max(0, p(x_probe) + ρ g · (x_b − x_probe)),      V_b = J(x_probe) V0,

none where the probe lies at a free surface (its stencil less than ``SURFACE_FILL`` full). It gives node i the
MLS-MPM pressure impulse of a fluid particle of volume V_b and pressure p_b at that place,

    Δq_i = (4 Δt / dx²) V_b p_b w_ib (x_i − x_b),

whose sum over the nodes is zero (Σ_i w_ib (x_i − x_b) = 0). What the rod's particles give the fluid's nodes is the
rod's push on the fluid, so it enters the rod's reaction with the opposite sign (``step.grid_update``).
"""

from __future__ import annotations

import torch
from torch import Tensor

from . import transfer
from .boundaries import RodPose, rod_sdf
from .grid import Stencil
from .materials import volumetric_stress
from .packing import SURFACE_FILL, place_rod_points
from .scene import Scene
from .state import State
from .walls import Stencils


def fluid_state(scene: Scene, state: State, st: Stencil, mass: Tensor) -> Tensor:
    """Σ_p w_ip m_p (p_p, J_p, 1) on each node: the particles' pressure p = −τ_v(J) [Pa] and volume ratio J [1]
    weighted by the mass they put there, and that mass ``mass`` [kg] (p2g's) (2-D: per unit length),
    (num_nodes, 3)."""
    values = scene.particle_mass * torch.stack([-volumetric_stress(state.J, scene.bulk_modulus), state.J])  # (2, N)
    rows = torch.cat([torch.zeros(2, values.shape[1], scene.dim, dtype=values.dtype, device=values.device),
                      values[:, :, None]], 2)  # (2, N, d + 1): rows [0, m p] and [0, m J] (``transfer.scatter``)
    weighted = transfer.scatter(rows, st, scene.grid.num_nodes, scene.stencil_points, scene.fused)
    return torch.cat([weighted, mass[:, None]], 1)


def pressure_impulse(scene: Scene, weighted: Tensor, stencils: Stencils, dt: float) -> Tensor:
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


def wall_impulses(scene: Scene, state: State, st: Stencil, mass: Tensor, pose: RodPose,
                  dt: float) -> tuple[Tensor, Tensor]:
    """The pressure impulses [N·s] (2-D: per unit length) of the rod's and of the cup's boundary particles on the
    nodes, each (num_nodes, d), for particles of stencil ``st`` that put ``mass`` [kg] on the nodes (p2g's), the rod
    at ``pose`` (module docstring)."""
    weighted = fluid_state(scene, state, st, mass)
    points = place_rod_points(scene.rod, scene.walls.rod, pose)
    rod = Stencils.of(scene.grid, points, *rod_sdf(scene.rod, points, pose), scene.stencil_points[:, :scene.dim],
                      scene.offset_index, scene.strides, scene.particle_bounds)
    return pressure_impulse(scene, weighted, rod, dt), pressure_impulse(scene, weighted, scene.walls.cup, dt)
