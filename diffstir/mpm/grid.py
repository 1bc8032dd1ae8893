"""The background grid and the quadratic B-spline stencil that couples it to the particles."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass(frozen=True)
class Grid:
    """A regular grid of nodes: node (i, j[, k]) sits at ``origin + (i, j[, k]) * dx``.

    Attributes:
        origin: position of node 0 [m], (d,).
        shape: number of nodes along each axis.
        dx: node spacing [m].
    """

    origin: Tensor
    shape: tuple[int, ...]
    dx: float

    @property
    def dim(self) -> int:
        return len(self.shape)

    @property
    def num_nodes(self) -> int:
        n = 1
        for s in self.shape:
            n *= s
        return n

    def strides(self) -> Tensor:
        """Flat-index strides of each axis (row-major), (d,) int64."""
        strides = [1] * self.dim
        for a in range(self.dim - 2, -1, -1):
            strides[a] = strides[a + 1] * self.shape[a + 1]
        return torch.tensor(strides, dtype=torch.int64, device=self.origin.device)

    def node_positions(self) -> Tensor:
        """Positions of all nodes in flat order [m], (num_nodes, d)."""
        axes = [torch.arange(s, dtype=self.origin.dtype, device=self.origin.device) for s in self.shape]
        mesh = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, self.dim)
        return self.origin + mesh * self.dx

    def stencil_offsets(self) -> Tensor:
        """The 3^d node offsets of the quadratic stencil, (3^d, d) int64."""
        return torch.tensor(list(itertools.product(range(3), repeat=self.dim)), dtype=torch.int64,
                            device=self.origin.device)


@dataclass
class Stencil:
    """The quadratic B-spline stencil of N particles: their 3^d nodes and weights.

    Attributes:
        index: flat node index of each (particle, stencil node), (N, 3^d) int64.
        weight: B-spline weight w_ip [1], (N, 3^d); rows sum to 1.
        frac: particle position relative to its base node, in cells, in [0.5, 1.5), (N, d).
    """

    index: Tensor
    weight: Tensor
    frac: Tensor


def quadratic_stencil(grid: Grid, x: Tensor, offsets: Tensor, strides: Tensor) -> Stencil:
    """Quadratic B-spline weights N(x) = 3/4 - x², (3/2 - |x|)²/2 of particles at ``x`` [m], (N, d)."""
    cell = (x - grid.origin) / grid.dx
    base = torch.floor(cell - 0.5).detach()
    frac = cell - base
    w1d = torch.stack([0.5 * (1.5 - frac) ** 2, 0.75 - (frac - 1.0) ** 2, 0.5 * (frac - 0.5) ** 2], dim=-1)  # (N,d,3)
    # product over axes of the 1-D weight picked by each stencil offset
    weight = torch.ones(x.shape[0], offsets.shape[0], dtype=x.dtype, device=x.device)
    for a in range(grid.dim):
        weight = weight * w1d[:, a, :].index_select(1, offsets[:, a])
    index = (base.long() @ strides)[:, None] + (offsets @ strides)[None, :]
    return Stencil(index=index, weight=weight, frac=frac)
