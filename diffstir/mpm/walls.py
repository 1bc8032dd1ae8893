"""Boundary particles in the solids (``SimConfig.wall_pressure``): where they sit and which nodes they reach.

A fluid particle next to a solid face has part of its quadratic stencil in the solid, where no particle carries
pressure, so the fluid's nodes next to the face are pushed away from it and the particles there are left at a
fraction of the pressure: under the 3-D rod's tip, half the hydrostatic value (docs/validation.md). Dummy wall
particles (Adami, Hu and Adams 2012, J. Comput. Phys. 231, 7057) on the fluid's seeding lattice inside the solids
complete the stencil; each has a ghost probe a distance δ = ``PROBE_DISTANCE`` cells outside the surface along its
normal n_b, x_probe = x_b + (δ − φ_b) n_b (φ_b < 0: the particle's signed distance). The pressure they carry is
``wall_pressure``'s.
"""

from __future__ import annotations

from dataclasses import dataclass
import torch
from torch import Tensor

from ..rig import Cup
from .boundaries import PROBE_DISTANCE, RodShape, cup_sdf
from .grid import Grid, quadratic_stencil
from .packing import lattice, rod_fill_points

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
