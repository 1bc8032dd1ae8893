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

import itertools

import torch
import torch.nn.functional as F
from torch import Tensor


def _corners(d: int):
    for corner in itertools.product((0, 1), repeat=d):
        yield corner, torch.tensor([1.0 if c else -1.0 for c in corner])


def _cell_view(nodes: Tensor, corner: tuple[int, ...]) -> Tensor:
    """The node values at one corner of every cell: nodes (n0, n1[, n2], ...) -> (n0-1, n1-1[, n2-1], ...)."""
    index = tuple(slice(c, c + n - 1) for c, n in zip(corner, nodes.shape[: len(corner)]))
    return nodes[index]


def cell_velocity_gradient(v: Tensor, shape: tuple[int, ...], dx: float) -> Tensor:
    """∂v_a/∂x_b at cell centres [1/s], (cells, d, d) in flat order, from node velocities v (num_nodes, d)."""
    d = len(shape)
    nodes = v.view(*shape, d)
    grad = 0.0
    for corner, sign in _corners(d):
        grad = grad + _cell_view(nodes, corner)[..., :, None] * sign.to(v)
    return (grad / (2 ** (d - 1) * dx)).reshape(-1, d, d)


def nodal_forces(stress: Tensor, cell_volume: Tensor, shape: tuple[int, ...], dx: float) -> Tensor:
    """Node forces f_i = −Σ_c V_c σ_c ∇N_i(x_c) [N] (2-D: per unit length), (num_nodes, d), from cell stress
    σ_c [Pa] (cells, d, d) and cell volumes V_c [m³] (cells,)."""
    d = len(shape)
    cells = tuple(n - 1 for n in shape)
    weighted = (cell_volume[:, None, None] * stress).view(*cells, d, d) / (2 ** (d - 1) * dx)
    force = 0.0
    for corner, sign in _corners(d):
        per_cell = -(weighted @ sign.to(stress))  # (cells..., d)
        # place the cell's contribution on its corner node: pad one cell of zeros on the far side
        pad = []
        for c in reversed(corner):
            pad += [c, 1 - c]
        force = force + F.pad(per_cell.movedim(-1, 0), pad).movedim(0, -1)
    return force.reshape(-1, d)


def cell_min(node_values: Tensor, shape: tuple[int, ...]) -> Tensor:
    """The smallest of each cell's corner values, (cells,)."""
    nodes = node_values.view(*shape)
    result = None
    for corner, _ in _corners(len(shape)):
        view = _cell_view(nodes, corner)
        result = view if result is None else torch.minimum(result, view)
    return result.reshape(-1)


def cell_max(node_values: Tensor, shape: tuple[int, ...]) -> Tensor:
    """The largest of each cell's corner values, (cells,)."""
    return -cell_min(-node_values, shape)
