"""How densely the particles pack, measured on the grid, and the volume ratio it implies.

A particle's volume ratio J integrates its own velocity divergence, dJ/dt = J tr C. With several particles to a cell
the particles have volume modes that the grid cannot see: divergence in those modes is never pushed back by the
pressure and accumulates, so J drifts away from the space the particles fill (next to a moving rod it adds a drag
that grows with the bulk modulus; in 3-D the fluid compacts under gravity while its J says it does not;
docs/validation.md). The grid sees the packing directly: the mass the particles put on a node, with the mass the
solids would put there if they were fluid at rest, over the mass a node holds inside the resting fluid,

    φ_i = (m_i + m_i^solid) / (ρ dx^d),        ρ̂_p = Σ_i w_ip φ_i,        J_p^ρ = 1 / ρ̂_p,

and each particle's J relaxes towards J_p^ρ over a time τ [s] (``SimConfig.volume_relaxation``):

    J ← J (1 + Δt tr C) + (Δt/τ) (J^ρ − J).

The solids' mass comes from virtual particles filling the cup's walls and bottom (on the fluid's seeding lattice, so
that the resting fluid measures φ = 1 up to the wall) and the rod (a lattice four times finer per axis, which moves
with the rod; ``rod_fill_points``). A particle whose stencil reaches a node less than half full is at the free
surface, where the grid cannot tell missing neighbours from expansion; it keeps its own J (the relaxation fades
out between a full stencil and one with a half-full node).
"""

from __future__ import annotations

import torch
from torch import Tensor

from ..rig import Cup
from .boundaries import RodPose, RodShape, cup_sdf, rod_to_cup
from .grid import Grid, Stencil, quadratic_stencil

FINE = 4  # the rod's virtual particles per fluid-particle spacing, per axis
SURFACE_FILL = 0.5  # a node whose fill is below this lies outside the fluid (a free surface)
# cells into a solid that its virtual particles fill: a particle on the surface has stencil nodes up to 1.5 cells
# (axis) or 2.1 cells (diagonal) inside, each of whose kernels reaches 1.5 cells further
DEPTH = 4.0


def lattice(grid: Grid, spacing: float) -> Tensor:
    """Points at the centres of a lattice of ``spacing`` [m] covering the grid (the fluid's seeding lattice when
    ``spacing`` is dx / particles per cell) [m], (P, d)."""
    lo = grid.origin + 0.5 * spacing
    axes = [lo[a] + spacing * torch.arange(int(round(grid.shape[a] * grid.dx / spacing)), dtype=lo.dtype,
                                           device=lo.device) for a in range(grid.dim)]
    return torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, grid.dim)


def deposit(grid: Grid, points: Tensor, mass: float, offset_index: Tensor, strides: Tensor,
            bounds: Tensor) -> Tensor:
    """The mass [kg] that particles of ``mass`` at ``points`` [m] put on each node, (num_nodes,). Points beyond
    ``bounds`` (2, d), the particles' bounds, are moved onto them (their mass then lands on the grid's edge, away
    from the fluid)."""
    st = quadratic_stencil(grid, torch.clamp(points, bounds[0], bounds[1]), offset_index, strides)
    return torch.zeros(grid.num_nodes, dtype=points.dtype, device=points.device).scatter_add(
        0, st.index.view(-1), (mass * st.weights()).view(-1))


def cup_solid_mass(grid: Grid, cup: Cup, spacing: float, density: float, offset_index: Tensor, strides: Tensor,
                   bounds: Tensor) -> Tensor:
    """The mass [kg] (2-D: per unit length) that the cup's walls and bottom would put on each node if they were
    fluid of ``density`` [kg/m³] at rest, sampled on the seeding lattice of ``spacing`` [m], (num_nodes,)."""
    points = lattice(grid, spacing)
    phi = cup_sdf(cup, points)[0]
    solid = (phi <= 0) & (phi > -DEPTH * grid.dx) & ((points >= bounds[0]) & (points <= bounds[1])).all(1)
    return deposit(grid, points[solid], density * spacing**grid.dim, offset_index, strides, bounds)


def rod_fill_points(shape: RodShape, dx: float, spacing: float, height: float, dim: int, dtype, device) -> Tensor:
    """Virtual particles filling the rod within ``DEPTH`` cells of its surface, in the rod's frame (tip on the axis at
    the origin) [m], (R, d): a lattice of ``spacing`` [m] up to ``height`` [m] above the tip (3-D)."""
    reach = shape.radius + DEPTH * dx
    count = int(round(2 * reach / spacing))
    across = (torch.arange(count, dtype=dtype, device=device) + 0.5) * spacing - 0.5 * count * spacing
    axes = [across, across]
    if dim == 3:
        axes.append((torch.arange(int(round(height / spacing)), dtype=dtype, device=device) + 0.5) * spacing)
    points = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, dim)
    phi = shape.sdf(points)[0]
    return points[(phi <= 0) & (phi > -DEPTH * dx)]


def place_rod_points(shape: RodShape, points: Tensor, pose: RodPose) -> Tensor:
    """The rod's virtual particles ``points`` (rod frame, ``rod_fill_points``) at ``pose``, in the cup frame [m],
    (R, d); an axisymmetric rod's are not turned."""
    placed = points if shape.axisymmetric else rod_to_cup(points, pose)
    origin = pose.axis if points.shape[1] == 2 else torch.cat([pose.axis, pose.tip.reshape(1)])
    return placed + origin


def packed_volume_ratio(fill: Tensor, st: Stencil, interpolated: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """The volume ratio J^ρ = 1 / Σ_i w_ip φ_i that the nodes' fill φ (num_nodes,) implies for each particle, (N,),
    and how far the particle lies inside the fluid, (N,) in [0, 1]: 0 where its emptiest stencil node is filled to
    ``SURFACE_FILL`` or less (a free surface), 1 where it is full, linear between, so that the relaxation switches
    off smoothly at a surface (a hard switch made the readings jump with the parameters). ``interpolated``:
    Σ_i w_ip φ_i where the caller has it already (g2p's gather), (N,)."""
    node_fill = fill[st.index]
    inside = ((node_fill.min(1).values - SURFACE_FILL) / (1.0 - SURFACE_FILL)).clamp(0.0, 1.0)
    if interpolated is None:
        interpolated = (node_fill * st.weights()).sum(1)
    return 1.0 / interpolated, inside
