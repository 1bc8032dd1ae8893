"""The background grid and the quadratic B-spline stencil that couples it to the particles."""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from functools import cached_property

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

    @cached_property
    def flat_strides(self) -> Tensor:
        """``strides()``, built once."""
        return self.strides()

    @cached_property
    def corner_offsets(self) -> Tensor:
        """Flat index offsets of a cell's 2^d corners from its lowest corner, (2^d,) int64, built once."""
        return flat_index(self.stencil_offsets(2), self.flat_strides)

    @cached_property
    def last_cell(self) -> Tensor:
        """Index of the last cell along each axis, shape − 2, (d,) int64, built once."""
        return torch.tensor(self.shape, device=self.origin.device) - 2

    def node_positions(self) -> Tensor:
        """Positions of all nodes in flat order [m], (num_nodes, d)."""
        axes = [torch.arange(s, dtype=self.origin.dtype, device=self.origin.device) for s in self.shape]
        mesh = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, self.dim)
        return self.origin + mesh * self.dx

    def stencil_offsets(self, width: int = 3) -> Tensor:
        """The width^d node offsets of a stencil (3: quadratic B-spline, 2: cell corners), in flat order with the
        first axis slowest, (width^d, d) int64."""
        return torch.tensor(list(itertools.product(range(width), repeat=self.dim)), dtype=torch.int64,
                            device=self.origin.device)

    def cell_corners(self) -> Tensor:
        """Flat node index of the 2^d corners of every cell, (cells, 2^d) int64; cells in flat (row-major) order."""
        axes = [torch.arange(s - 1, device=self.origin.device) for s in self.shape]
        lower = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, self.dim)
        strides = self.strides()
        return flat_index(lower, strides)[:, None] + flat_index(self.stencil_offsets(2), strides)[None, :]


@dataclass
class Stencil:
    """The quadratic B-spline stencil of N particles: their 3^d nodes and weights.

    Attributes:
        index: flat node index of each (particle, stencil node), (N, 3^d) int64.
        frac: particle position relative to its base node, in cells, in [0.5, 1.5), (N, d).
        weight: B-spline weight w_ip [1], (N, 3^d), rows summing to 1; None until ``weights()`` computes it (the
            fused transfers compute their own).
    """

    index: Tensor
    frac: Tensor
    weight: Tensor | None = None

    def weights(self) -> Tensor:
        """w_ip [1], (N, 3^d): ``weight``, computed from ``frac`` where it was not."""
        if self.weight is None:
            self.weight = outer_weights(bspline_weights(self.frac))
        return self.weight


def bspline_weights(frac: Tensor) -> Tensor:
    """Per-axis quadratic B-spline weights N(x) = 3/4 - x², (3/2 - |x|)²/2 of the three stencil nodes of points at
    ``frac`` cells from their base node, (N, d) → (N, d, 3)."""
    return torch.stack([0.5 * (1.5 - frac) ** 2, 0.75 - (frac - 1.0) ** 2, 0.5 * (frac - 0.5) ** 2], dim=-1)


def outer_weights(w1d: Tensor) -> Tensor:
    """Tensor-product weights of a stencil from per-axis weights w1d (N, d, width): (N, width^d), first axis
    slowest (the order of ``Grid.stencil_offsets``)."""
    n, d, width = w1d.shape
    weight = w1d[:, 0, :]
    for a in range(1, d):
        weight = (weight[:, :, None] * w1d[:, a, None, :]).reshape(n, -1)
    return weight


def flat_index(cells: Tensor, strides: Tensor) -> Tensor:
    """The flat (row-major) node index Σ_a c_a s_a of integer node coordinates ``cells`` (..., d) int64 with the
    grid's ``strides`` (d,) int64; a sum of products, as CUDA has no integer matrix product."""
    return (cells * strides).sum(-1)


def quadratic_stencil(grid: Grid, x: Tensor, offset_index: Tensor, strides: Tensor, weights: bool = True) -> Stencil:
    """The quadratic B-spline stencil of particles at ``x`` [m], (N, d), with its weights unless ``weights`` is
    False.

    ``offset_index`` is the flat index offset of each stencil node from the base node, (3^d,) int64
    (``flat_index(stencil_offsets(), strides)``); ``strides`` the grid's flat-index strides.
    """
    cell = (x - grid.origin) / grid.dx
    base = torch.floor(cell - 0.5).detach()
    frac = cell - base
    index = flat_index(base.long(), strides)[:, None] + offset_index[None, :]
    return Stencil(index=index, frac=frac, weight=outer_weights(bspline_weights(frac)) if weights else None)
