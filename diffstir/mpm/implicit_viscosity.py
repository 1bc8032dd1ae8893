"""The shear stress's step solved implicitly (backward Euler), for fluids too thick for explicit substeps.

An explicit viscous step is stable only below Δt = ρ dx² / (2 d η): at 100 Pa·s on 2.5 mm cells that is 31 µs,
and ``step.grid_update``'s substeps then cost in proportion to η. Here the step's shear stress is taken at the
step's end velocity, with each cell's apparent viscosity η_c frozen at the step's start (lagged, as the
rheology is nonlinear):

    m_i (v_i − v*_i) / Δt = f_i(E(v)),        f_i = −Σ_c V_c 2 η_c dev(D_c) ∇N_i(x_c)     (``viscous``)

for every node i that carries fluid and is not a ghost, with E the cup's and the rod's ghost map (affine: its
wall velocities are the offset). f is linear in v for fixed η_c: f = K E_lin v + K e₀, with the cell stiffness

    K_c[(i,a),(j,b)] = −V_c η_c [δ_ab ∇N_i·∇N_j + ∂_b N_i ∂_a N_j − (2/d) ∂_a N_i ∂_b N_j],

so the step is one sparse linear solve, (M/Δt − K E_lin) v = M v*/Δt + K e₀, stable at any η. The matrix is not
symmetric (the ghosts' rows of E_lin): it is solved by BiCGSTAB preconditioned by its diagonal (float64, on the
CPU), the backward pass's transposed system alike. Gradients follow the implicit function theorem, as the pressure's do
(``projection.solve_pressure``): v = v₀ + A⁻¹ r(v₀), r the residual of the step's equation at the solution v₀
held constant, computed with the differentiable ``viscous`` operators, so that η_c's parameters, v* and the
walls' velocities all carry derivatives, in reverse and forward mode.

The nodes' inertia is the explicit update's, m_i at least the bulk node mass (``step.grid_update``), so that the
two agree where both are stable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.autograd.forward_ad as fwAD
from scipy import sparse
from scipy.sparse import linalg
from torch import Tensor

from .boundaries import GhostOperator
from .materials import deviatoric_rate_of_strain
from .projection import ImplicitSolve, extension_matrix
from .viscous import CellStencil, cell_velocity_gradient, nodal_forces


@dataclass(frozen=True)
class StiffnessPattern:
    """The grid's viscous stiffness K = Σ_c V_c η_c K_c as a sparse matrix of fixed pattern, built once per scene:
    each step fills its values from the cells' V_c η_c (``matrix``).

    Attributes:
        local: one cell's stiffness per unit V_c η_c [m⁻²], (2^d d, 2^d d), rows and columns (corner, component):
            −[δ_ab ∇N_i·∇N_j + ∂_b N_i ∂_a N_j − (2/d) ∂_a N_i ∂_b N_j] (module docstring).
        slot: where each cell's local entries add up in the CSR values, (cells · (2^d d)²,).
        indices, indptr: the CSR pattern over the nodes' velocity components (num_nodes · d).
    """

    local: np.ndarray
    slot: np.ndarray
    indices: np.ndarray
    indptr: np.ndarray

    @classmethod
    def of(cls, cells: CellStencil, num_nodes: int) -> "StiffnessPattern":
        g = cells.grad.detach().cpu().double().numpy()
        k, d = g.shape
        local = -(np.einsum("ab,ij->iajb", np.eye(d), g @ g.T) + np.einsum("ja,ib->iajb", g, g)
                  - (2.0 / d) * np.einsum("ia,jb->iajb", g, g)).reshape(k * d, k * d)
        corners = cells.corners.detach().cpu().numpy()
        dof = (corners[:, :, None] * d + np.arange(d)).reshape(len(corners), k * d)
        size = num_nodes * d
        entry = (dof[:, :, None] * size + dof[:, None, :]).ravel()
        unique, slot = np.unique(entry, return_inverse=True)
        indptr = np.concatenate([[0], np.cumsum(np.bincount(unique // size, minlength=size))])
        return cls(local, slot, unique % size, indptr)

    def matrix(self, coefficient: np.ndarray) -> sparse.csr_matrix:
        """K [N·s/m] (2-D: per unit length) of the cells' V_c η_c ``coefficient`` [m³·Pa·s], (cells,)."""
        values = (coefficient[:, None] * self.local.ravel()[None, :]).ravel()
        size = len(self.indptr) - 1
        return sparse.csr_matrix((np.bincount(self.slot, weights=values, minlength=len(self.indices)),
                                  self.indices, self.indptr), shape=(size, size))


#: The relative residual at which BiCGSTAB stops, and its most iterations (then a sparse LU solves the system).
TOLERANCE, MAX_ITERATIONS = 1e-10, 1000


class ViscousSolve:
    """The step's backward-Euler operator A = M/Δt − K E_lin on the ``unknown`` nodes (module docstring).

    Args:
        stiffness: the grid's ``StiffnessPattern``.
        coefficient: V_c η_c per cell [m³·Pa·s] (2-D: per unit length), (cells,), detached.
        inertia: the nodes' inertia m_i [kg], (num_nodes,).
        unknown: the nodes the step solves for, (num_nodes,) bool.
        cup, rod: the step's ghost operators (the cup's applied first).
        dt: the step [s].
    """

    def __init__(self, stiffness: StiffnessPattern, coefficient: Tensor, inertia: Tensor, unknown: Tensor,
                 cup: GhostOperator, rod: GhostOperator, dt: float):
        num_nodes = inertia.shape[0]
        d = (len(stiffness.indptr) - 1) // num_nodes
        stiff = stiffness.matrix(coefficient.detach().cpu().double().numpy())
        self.unknown_dof = np.flatnonzero(np.repeat(unknown.detach().cpu().numpy(), d))
        extension = extension_matrix(cup, rod, num_nodes, d)
        coupled = (stiff @ extension).tocsr()[self.unknown_dof][:, self.unknown_dof]
        mass = np.repeat(inertia.detach().cpu().double().numpy(), d)[self.unknown_dof] / dt
        self.matrix = (sparse.diags(mass) - coupled).tocsr()
        diagonal = self.matrix.diagonal()
        self.preconditioner = linalg.LinearOperator(self.matrix.shape, matvec=lambda r: r / diagonal)
        self.shape = (num_nodes, d)

    def solve(self, b: np.ndarray, transpose: bool) -> np.ndarray:
        """A⁻¹ b (A⁻ᵀ b with ``transpose``) on the unknown dofs: BiCGSTAB preconditioned by A's diagonal, which
        M/Δt dominates (a few iterations for a thin fluid, tens at 100 Pa·s on 2.5 mm cells), else a sparse LU
        where it stalls."""
        matrix = self.matrix.T.tocsr() if transpose else self.matrix
        x, info = linalg.bicgstab(matrix, b, rtol=TOLERANCE, atol=0.0, maxiter=MAX_ITERATIONS, M=self.preconditioner)
        return x if info == 0 else linalg.splu(matrix.tocsc()).solve(b)

    def __call__(self, rhs: Tensor, transpose: bool = False) -> Tensor:
        """A⁻¹ rhs (A⁻ᵀ with ``transpose``) of a node vector (num_nodes, d) on the unknown nodes, zero elsewhere."""
        b = rhs.detach().reshape(-1)[torch.as_tensor(self.unknown_dof, device=rhs.device)]
        x = self.solve(b.double().cpu().numpy(), transpose)
        out = torch.zeros(rhs.numel(), dtype=rhs.dtype, device=rhs.device)
        out[torch.as_tensor(self.unknown_dof, device=rhs.device)] = torch.as_tensor(x, dtype=rhs.dtype,
                                                                                     device=rhs.device)
        return out.view(self.shape)


def implicit_viscous_step(cells: CellStencil, stiffness: StiffnessPattern, viscosity: Tensor, cell_volume: Tensor,
                          v: Tensor, inertia: Tensor, unknown: Tensor, cup: GhostOperator, rod: GhostOperator,
                          dt: float) -> tuple[Tensor, Tensor]:
    """The node velocities [m/s] (num_nodes, d) after the step ``dt`` [s] of the shear stress from ``v`` [m/s]
    with the cells' ``viscosity`` η_c [Pa·s] (cells,) held (module docstring), zero off the ``unknown`` nodes and
    before the ghosts are applied, and the shear stress's node forces at them [N] (2-D: [N/m]), (num_nodes, d).
    ``cell_volume`` V_c [m³] (cells,), ``inertia`` m_i [kg] (num_nodes,)."""
    num_nodes = v.shape[0]
    coefficient = viscosity * cell_volume
    solve = ViscousSolve(stiffness, coefficient, inertia, unknown, cup, rod, dt)
    keep = unknown[:, None]

    def forces(u: Tensor) -> Tensor:
        dev_D = deviatoric_rate_of_strain(cell_velocity_gradient(rod(cup(u)), cells))
        return nodal_forces(2.0 * viscosity[:, None, None] * dev_D, cell_volume, cells, num_nodes)

    start = torch.where(keep, v, 0.0)
    rhs = torch.where(keep, inertia[:, None] * start / dt + forces(torch.zeros_like(v)), 0.0)
    solution = solve(rhs.detach())
    dual = any(fwAD.unpack_dual(t).tangent is not None for t in (v, viscosity, cup.offset, rod.offset))
    if torch.is_grad_enabled() or dual:
        residual = torch.where(keep, inertia[:, None] * (start - solution) / dt + forces(solution), 0.0)
        if residual.requires_grad or dual:
            solution = solution + ImplicitSolve.apply(residual, solve)
    return solution, forces(solution)
