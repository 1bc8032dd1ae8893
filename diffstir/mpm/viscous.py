"""The viscous stress on the grid: velocity gradients in cells, stress by the material, forces on the nodes.

Each grid cell is a bilinear (2-D) or trilinear (3-D) finite element integrated at its centre:

    ∇v_c = Σ_i v_i ⊗ ∇N_i(x_c),        f_i = −Σ_c V_c σ_c ∇N_i(x_c),        ∇N_i(x_c) = s_i / (2^(d−1) dx)

with s_i ∈ {−1, +1}^d the corner's side. The velocity field includes the solids' ghost velocities, so a cell
that straddles a wall sees the no-slip surface where it is and the fluid next to the wall feels the wall's shear
stress in the same step. Computing the viscous stress from particle velocity gradients instead leaves the nodes
next to a wall with one-sided stress, an error that grows with the time step (a 15-25 % slip of the Couette
profile at typical steps; see docs/validation.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .grid import Grid


@dataclass(frozen=True)
class CellStencil:
    """The cells of a grid as finite elements, precomputed once per scene.

    Attributes:
        corners: flat node index of each cell's 2^d corners, (cells, 2^d) int64.
        grad: shape-function gradients at the cell centre ∇N_i(x_c) = s_i / (2^(d−1) dx) [1/m], (2^d, d).
        faces: the pairs of cells that share a face, (F, 2) int64.
    """

    corners: Tensor
    grad: Tensor
    faces: Tensor

    @classmethod
    def of(cls, grid: Grid) -> "CellStencil":
        sign = 2.0 * grid.stencil_offsets(2).to(grid.origin.dtype) - 1.0
        shape = [n - 1 for n in grid.shape]
        index = torch.arange(math.prod(shape), device=grid.origin.device).view(shape)
        faces = [torch.stack([index.narrow(a, 0, n - 1).reshape(-1), index.narrow(a, 1, n - 1).reshape(-1)], 1)
                 for a, n in enumerate(shape)]
        return cls(corners=grid.cell_corners(), grad=sign / (2 ** (grid.dim - 1) * grid.dx), faces=torch.cat(faces))


def cell_velocity_gradient(v: Tensor, cells: CellStencil) -> Tensor:
    """∂v_a/∂x_b = Σ_i v_ia ∇N_i,b(x_c) at cell centres [1/s], (cells, d, d), from node velocities v (num_nodes, d)."""
    k, d = cells.grad.shape
    corner_v = v.T.contiguous().index_select(1, cells.corners.view(-1)).view(-1, k)  # rows (a, cell)
    return (corner_v @ cells.grad).view(d, -1, d).transpose(0, 1)


def nodal_forces(stress: Tensor, cell_volume: Tensor, cells: CellStencil, num_nodes: int) -> Tensor:
    """Node forces f_i = −Σ_c V_c σ_c ∇N_i(x_c) [N] (2-D: per unit length), (num_nodes, d), from cell stress
    σ_c [Pa] (cells, d, d) and cell volumes V_c [m³] (cells,)."""
    d = stress.shape[-1]
    weighted = (cell_volume[:, None, None] * stress).transpose(0, 1).reshape(-1, d)  # rows (a, cell)
    per_corner = (weighted @ cells.grad.T).view(d, -1)  # (d, cells · 2^d): V_c (σ_c ∇N_i)_a
    index = cells.corners.view(1, -1).expand(d, -1)
    return torch.zeros(d, num_nodes, dtype=stress.dtype, device=stress.device).scatter_add(
        1, index, -per_corner).T.contiguous()


def cell_min(node_values: Tensor, cells: CellStencil) -> Tensor:
    """The smallest of each cell's corner values, (cells,)."""
    return node_values[cells.corners].amin(dim=1)


def cell_mean(node_values: Tensor, cells: CellStencil) -> Tensor:
    """The mean of each cell's corner values, (cells,)."""
    return node_values[cells.corners].mean(dim=1)


def cell_any(node_mask: Tensor, cells: CellStencil) -> Tensor:
    """Whether any of each cell's corners is set, (cells,) bool."""
    return node_mask[cells.corners].any(dim=1)
