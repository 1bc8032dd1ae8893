"""The pressure of an incompressible fluid, solved on the grid each step (a projection), instead of a sound speed.

The weakly compressible fluid's pressure comes from its compression, κ/2 (J − 1/J); a viscous stir's pressure then
compresses it by δ = p/κ and the drag reads low unless κ is raised, which shortens the step and adds noise
(docs/validation.md). Here the pressure is the Lagrange multiplier that keeps the grid's velocity divergence-free.
With the bilinear (trilinear) cells of ``viscous`` and one pressure per cell (the Q1-P0 element), the discrete
divergence of cell c is

    D_c(v) = Σ_i ∇N_i(x_c) · v_i^ext,        v^ext = E(v) = R(C(v))   (the cup's and the rod's ghost velocities),

and the step's velocity v* is projected, with the node masses M, onto D(v) = s:

    v = v* + M⁻¹ Lᵀ π,        A π = (L M⁻¹ Lᵀ) π = s − D(E(v*)),        L = D E_lin,

with π_c = Δt V_c p_c the cell's pressure impulse [N·s·m] (2-D: per unit length, [N·s]), V_c = dx^d, p_c [Pa],
and E_lin the ghost map without its wall velocities. The source s = (φ_c − 1)/τ [1/s] lets the cell's fill φ_c
(``packing``) relax to one over τ (``SimConfig.volume_relaxation``), undoing the slow drift in the particles'
spacing that a divergence-free grid velocity cannot see. Cells with a corner less than half full (a free
surface) carry no pressure. The pressure's node forces Σ_c π_c ∇N_i(x_c) / Δt act on the rod's nodes as the
shear stress's do, so that the rod's reaction (``step.grid_update``) counts both alike.

Q1-P0 has a spurious pressure mode, the checkerboard (−1)^(i+j), that D Dᵀ does not see inside the fluid: left
alone it grows from the particles' noise to a large part of the pressure. The operator
is therefore stabilised, A + ε G², with G the cells' face graph Laplacian: G² weighs the checkerboard by (4d)²
and a smooth pressure of wavenumber k by (k dx)⁴, so ε = β diag(A)/(4d)² gives the checkerboard β times the
weight of a cell inside the fluid and leaves a divergence of relative order β (k dx)²/(4d)² unremoved. β = 0.1
removes a smooth divergence to under 2 % (tests/test_projection.py); the sharp one the moving rod causes beside
it is removed less well the larger β (docs/validation.md).

A is symmetric positive definite (the ghost velocities pin the constant pressure). It is assembled each step as a
sparse matrix and factorised (``PressureSolver``). Gradients: the solve is differentiated implicitly,
dπ = A⁻¹ (ds − dA π), by one more solve in the backward pass (``ImplicitSolve``), not through a solver's
iterations.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
import qdldl
import torch
import torch.autograd.forward_ad as fwAD
from scipy import sparse
from torch import Tensor

from .boundaries import GhostOperator
from .viscous import CellStencil, cell_velocity_gradient, nodal_forces

STABILISATION = 0.1  # β: the checkerboard's weight in the stabilised operator, over A's diagonal (module docstring)
TOLERANCE = 1e-10  # relative residual at which conjugate gradients stop (devices other than the CPU)
MAX_ITERATIONS = 2000
RESTRICTIONS = 8  # pressure-cell sets whose restricted operators a scene keeps (CellMatrices.on)


def divergence(v: Tensor, cells: CellStencil) -> Tensor:
    """D_c(v) = Σ_i ∇N_i(x_c) · v_i [1/s] at every cell centre, (cells,), from node velocities v (num_nodes, d): the
    trace of ``viscous.cell_velocity_gradient``."""
    return cell_velocity_gradient(v, cells).diagonal(dim1=-2, dim2=-1).sum(-1)


def divergence_transpose(p: Tensor, cells: CellStencil, num_nodes: int) -> Tensor:
    """Dᵀ p: Σ_c p_c ∇N_i(x_c) on every node, (num_nodes, d), from cell values p (cells,): the node forces
    (``viscous.nodal_forces``) of the isotropic stress −p I on unit cell volumes."""
    d = cells.grad.shape[1]
    stress = -p[:, None, None] * torch.eye(d, dtype=p.dtype, device=p.device)
    return nodal_forces(stress, torch.ones_like(p), cells, num_nodes)


def ghost_transpose(op: GhostOperator, u: Tensor) -> Tensor:
    """The transpose of ``op``'s linear part, applied to node vectors u (num_nodes, d): what a cotangent on the ghost
    nodes puts on the fluid nodes their velocities were extrapolated from."""
    q, k = op.source.shape
    on_target = u.index_select(0, op.target)
    active = torch.ones(q, dtype=torch.bool, device=u.device) if op.active is None else op.active
    back = torch.where(active[:, None], (op.matrix.transpose(1, 2) @ on_target[:, :, None]).squeeze(-1), 0.0)
    kept = u.index_copy(0, op.target, torch.where(active[:, None], 0.0, on_target))
    return kept.index_add(0, op.source.view(-1), (op.weight[:, :, None] * back[:, None, :]).view(q * k, -1))


@dataclass(frozen=True)
class CellMatrices:
    """A grid's cell operators as sparse matrices, built once per scene (float64, for the CPU-side assembly): the
    divergence D (cells, nodes·d) of ``divergence`` and the cells' face pairs, with ``on`` restricting both to a set
    of pressure cells."""

    divergence: sparse.csr_matrix
    faces: np.ndarray
    _restricted: OrderedDict = field(default_factory=OrderedDict, compare=False, repr=False)

    @classmethod
    def of(cls, cells: CellStencil, num_nodes: int) -> "CellMatrices":
        n_cells, k = cells.corners.shape
        d = cells.grad.shape[1]
        corners = _np(cells.corners)
        rows = np.repeat(np.arange(n_cells), k * d)
        cols = (corners[:, :, None] * d + np.arange(d)).ravel()
        values = np.tile(_np(cells.grad).ravel(), n_cells)
        return cls(sparse.csr_matrix((values, (rows, cols)), shape=(n_cells, num_nodes * d)), _np(cells.faces))

    def on(self, kept: np.ndarray) -> tuple[sparse.csr_matrix, sparse.csr_matrix]:
        """D's rows of the pressure cells ``kept`` (indices, ascending) and G² among them, G p = Σ over faces shared
        with another pressure cell of (p_c − p_c') (``Projection.face_laplacian``); the last ``RESTRICTIONS``
        sets are kept, as the pressure cells change only every few steps."""
        key = kept.tobytes()
        if key in self._restricted:
            self._restricted.move_to_end(key)
            return self._restricted[key]
        index = np.full(self.divergence.shape[0], -1)
        index[kept] = np.arange(len(kept))
        first, second = index[self.faces].T
        both = (first >= 0) & (second >= 0)
        first, second, n = first[both], second[both], len(kept)
        degree = np.bincount(first, minlength=n) + np.bincount(second, minlength=n)
        laplacian = sparse.csr_matrix((np.r_[degree, -np.ones(2 * len(first))],
                                       (np.r_[np.arange(n), first, second], np.r_[np.arange(n), second, first])),
                                      shape=(n, n))
        self._restricted[key] = restricted = (self.divergence[kept], (laplacian @ laplacian).tocsr())
        if len(self._restricted) > RESTRICTIONS:
            self._restricted.popitem(last=False)
        return restricted


@dataclass
class Projection:
    """The step's stabilised projection operator A = L M⁻¹ Lᵀ + ε G² over the pressure cells (module docstring);
    calling it applies A matrix-free, differentiably.

    Attributes:
        cells: the grid's cells.
        num_nodes: node count.
        mobility: 1/m_i on the fluid's nodes and 0 elsewhere [1/kg], (num_nodes, 1).
        pressure_cell: which cells carry a pressure, (cells,) float 0/1.
        cup, rod: the ghost operators (the cup's is applied first).
        stabilisation: ε of the checkerboard penalty ε G² (module docstring) [units of A].
        matrices: the grid's ``CellMatrices``.
    """

    cells: CellStencil
    num_nodes: int
    mobility: Tensor
    pressure_cell: Tensor
    cup: GhostOperator
    rod: GhostOperator
    stabilisation: float
    matrices: CellMatrices

    @classmethod
    def of(cls, cells: CellStencil, matrices: CellMatrices, num_nodes: int, mobility: Tensor, pressure_cell: Tensor,
           cup: GhostOperator, rod: GhostOperator, node_mass: float) -> "Projection":
        """The projection with ε = β diag(A)/(4d)², diag(A) = 2^d d / (4^(d−1) dx² m) that of a cell inside the
        fluid, ``node_mass`` m [kg] (2-D: [kg/m]), β = ``STABILISATION``."""
        d = cells.grad.shape[1]
        diagonal = float((cells.grad**2).sum()) / node_mass
        return cls(cells, num_nodes, mobility, pressure_cell, cup, rod, STABILISATION * diagonal / (4 * d) ** 2,
                   matrices)

    def extend(self, v: Tensor) -> Tensor:
        """E(v): the node velocities with the ghosts' in place, wall terms included."""
        return self.rod(self.cup(v))

    def impulse(self, p: Tensor) -> Tensor:
        """M⁻¹ Lᵀ p: the velocity change [m/s] of the fluid's nodes under pressure impulses p, (num_nodes, d)."""
        cotangent = divergence_transpose(p * self.pressure_cell, self.cells, self.num_nodes)
        return self.mobility * ghost_transpose(self.cup, ghost_transpose(self.rod, cotangent))

    def constrained_divergence(self, v: Tensor) -> Tensor:
        """L v without wall terms, on the pressure cells only."""
        linear = self.rod.without_offset()(self.cup.without_offset()(v))
        return divergence(linear, self.cells) * self.pressure_cell

    def face_laplacian(self, p: Tensor) -> Tensor:
        """G p = Σ over faces shared with another pressure cell of (p_c − p_c'), (cells,)."""
        first, second = self.cells.faces.unbind(1)
        jump = (p[first] - p[second]) * self.pressure_cell[first] * self.pressure_cell[second]
        return torch.zeros_like(p).index_add(0, first, jump).index_add(0, second, -jump)

    def __call__(self, p: Tensor) -> Tensor:
        return (self.constrained_divergence(self.impulse(p))
                + self.stabilisation * self.face_laplacian(self.face_laplacian(p)))

    def matrix(self) -> sparse.csr_matrix:
        """A on the pressure cells only, in their order (detached, float64, CPU): L = D E_lin, with E_lin the
        identity but on the ghosts' active targets, whose rows hold W_qc G_q."""
        d = self.cells.grad.shape[1]
        kept = np.flatnonzero(_np(self.pressure_cell) > 0)
        extension = extension_matrix(self.cup, self.rod, self.num_nodes, d)
        divergence, laplacian_squared = self.matrices.on(kept)
        constraint = divergence @ extension
        weighted = constraint.copy()
        weighted.data *= np.repeat(_np(self.mobility[:, 0]), d)[weighted.indices]
        return (weighted @ constraint.T + self.stabilisation * laplacian_squared).tocsr()


def extension_matrix(cup: GhostOperator, rod: GhostOperator, num_nodes: int, d: int) -> sparse.csr_matrix:
    """E_lin, the ghosts' linear map of node velocities (num_nodes·d, num_nodes·d), detached, float64: the identity
    but on the active targets of ``cup`` and ``rod``, whose rows hold W_qc G_q (their sources carry fluid, never a
    ghost, so the two maps compose as one)."""
    n_dof = num_nodes * d
    rows, cols, values = [], [], []
    ghost = np.zeros(n_dof, dtype=bool)
    for op in (cup, rod):
        target, source, weight, matrix = (_np(t) for t in (op.target, op.source, op.weight, op.matrix))
        if op.active is not None:
            active = _np(op.active).astype(bool)
            target, source, weight, matrix = target[active], source[active], weight[active], matrix[active]
        entries = weight[:, None, :, None] * matrix[:, :, None, :]  # (Q, a, K, b): W_qc G_q,ab
        target_dof = target[:, None] * d + np.arange(d)
        rows.append(np.broadcast_to(target_dof[:, :, None, None], entries.shape).ravel())
        cols.append(np.broadcast_to((source[:, :, None] * d + np.arange(d))[:, None], entries.shape).ravel())
        values.append(entries.ravel())
        ghost[target_dof.ravel()] = True
    fluid_dof = np.flatnonzero(~ghost)
    return sparse.csr_matrix((np.concatenate([*values, np.ones(len(fluid_dof))]),
                              (np.concatenate([*rows, fluid_dof]), np.concatenate([*cols, fluid_dof]))),
                             shape=(n_dof, n_dof))


def _np(t: Tensor) -> np.ndarray:
    return t.detach().cpu().numpy().astype(np.float64 if t.is_floating_point() else np.int64)


class PressureSolver:
    """x = A⁻¹ b for the step's assembled A (``Projection.matrix``, on the pressure cells ``pressure_cell``), zero
    on the other cells.

    ``method`` ``"ldl"``: a sparse LDLᵀ factorisation (QDLDL after an approximate minimum degree ordering, float64,
    on the CPU), which the backward pass's solve reuses. ``"cg"``: Jacobi-preconditioned conjugate gradients with A
    as a sparse tensor on the pressure's device. None: LDLᵀ on the CPU, CG elsewhere.
    """

    def __init__(self, matrix: sparse.csr_matrix, pressure_cell: Tensor, method: str | None = None):
        self.keep = pressure_cell.detach().bool()
        self.device = pressure_cell.device
        self.method = method or ("ldl" if self.device.type == "cpu" else "cg")
        if self.method == "ldl":
            self.ldl = qdldl.Solver(upper_triangle(matrix), upper=True)
        elif self.method == "cg":
            coo = matrix.tocoo()
            self.sparse = torch.sparse_coo_tensor(np.stack([coo.row, coo.col]), coo.data, coo.shape,
                                                  device=self.device, check_invariants=False).coalesce()
            self.inverse_diagonal = torch.as_tensor(1.0 / coo.diagonal(), device=self.device)
        else:
            raise ValueError(f"method = {method!r}; expected 'ldl', 'cg' or None")

    def __call__(self, rhs: Tensor, transpose: bool = False) -> Tensor:
        """A⁻¹ ``rhs`` on the pressure cells; A is symmetric, so ``transpose`` changes nothing."""
        b = rhs.detach()[self.keep]
        if self.method == "ldl":
            x = torch.from_numpy(self.ldl.solve(b.double().cpu().numpy())).to(rhs.device)
        else:
            x = conjugate_gradient(lambda y: torch.mv(self.sparse, y), b.double(), self.inverse_diagonal)
        return torch.zeros_like(rhs).index_put((self.keep,), x.to(rhs.dtype))


def upper_triangle(symmetric: sparse.csr_matrix) -> sparse.csc_matrix:
    """The upper triangle of a symmetric matrix in compressed columns, read off its compressed rows (whose indices
    it sorts in place): row i's entries at columns j ≤ i are column i's at rows j ≤ i of the transpose, which is
    the matrix itself."""
    symmetric.sort_indices()
    n = symmetric.shape[0]
    row = np.repeat(np.arange(n), np.diff(symmetric.indptr))
    lower = symmetric.indices <= row
    indptr = np.concatenate([[0], np.cumsum(np.bincount(row[lower], minlength=n))])
    return sparse.csc_matrix((symmetric.data[lower], symmetric.indices[lower], indptr), shape=symmetric.shape)


def conjugate_gradient(operator, rhs: Tensor, inverse_diagonal: Tensor, tolerance: float = TOLERANCE,
                       max_iterations: int = MAX_ITERATIONS) -> Tensor:
    """Solve operator(x) = rhs for a symmetric positive definite ``operator`` by conjugate gradients, preconditioned
    by ``inverse_diagonal``; stops at the relative residual ``tolerance``."""
    x = torch.zeros_like(rhs)
    r = rhs.clone()
    stop = tolerance * rhs.norm()
    z = inverse_diagonal * r
    direction, rz = z, torch.dot(r, z)
    for _ in range(max_iterations):
        if r.norm() <= stop:
            break
        a_d = operator(direction)
        alpha = rz / torch.dot(direction, a_d)
        x, r = x + alpha * direction, r - alpha * a_d
        z = inverse_diagonal * r
        rz, previous = torch.dot(r, z), rz
        direction = z + (rz / previous) * direction
    return x


class ImplicitSolve(torch.autograd.Function):
    """x = A⁻¹ r for a residual r that is zero at the solution: its value is taken as zero (the solve's round-off
    would only make a rollout with derivatives differ from one without), its derivatives are the reverse-mode
    g ↦ A⁻ᵀ g and the forward-mode ṙ ↦ A⁻¹ ṙ, by a ``solver`` called as ``solver(rhs, transpose=...)``
    (``PressureSolver``, ``implicit_viscosity.ViscousSolve``)."""

    @staticmethod
    def forward(ctx, residual: Tensor, solver) -> Tensor:
        ctx.solver = solver
        return torch.zeros_like(residual)

    @staticmethod
    def backward(ctx, grad: Tensor):
        return ctx.solver(grad, transpose=True), None

    @staticmethod
    def jvp(ctx, rhs_tangent: Tensor, _):
        return ctx.solver(rhs_tangent)


def solve_pressure(projection: Projection, rhs: Tensor) -> Tensor:
    """π with A π = rhs on the pressure cells (module docstring); differentiable, in reverse and forward mode, in
    ``rhs`` and in A's tensors by the implicit function theorem: π = π₀ + A⁻¹ (rhs − A π₀), with π₀ the solution
    held constant (``ImplicitSolve``)."""
    solver = PressureSolver(projection.matrix(), projection.pressure_cell)
    p = solver(rhs)
    dual = any(fwAD.unpack_dual(t).tangent is not None for t in (rhs, projection.mobility))
    if not (torch.is_grad_enabled() or dual):
        return p
    residual = rhs - projection(p)  # zero, but differentiable
    if residual.requires_grad or dual:
        return p + ImplicitSolve.apply(residual, solver)
    return p
