"""One MLS-MPM step: particle-to-grid, grid update with boundaries, grid-to-particle.

Quadratic B-splines, APIC/MLS transfers (Hu et al. 2018), explicit time integration. The volumetric (pressure)
stress lives on the particles and enters in ``p2g``; the shear stress of the material is evaluated on the grid, from
the ghost-extended velocity field, in ``grid_update`` (see ``viscous``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from ..rig import Cup
from .boundaries import RodPose, RodShape, cup_sdf, ghost_velocity, rod_sdf, rod_velocity
from .grid import Grid, Stencil, quadratic_stencil
from .materials import volumetric_stress
from .state import State
from .viscous import cell_max, cell_min, cell_velocity_gradient, nodal_forces

MASS_FLOOR = 1e-12  # kg: nodes lighter than this carry no fluid


@dataclass
class Scene:
    """What stays fixed over a rollout: grid, solids, particle mass and volume, bulk modulus, gravity.

    Attributes:
        grid: the background grid.
        cup: the cup; ``cup_phi``/``cup_normal`` its signed distance [m] and normal at every node.
        cup_nodes: flat indices of nodes inside the cup's solid within reach of the fluid.
        rod: the rod's shape; ``rod_slip`` whether its surface is a slip wall.
        particle_mass: mass of one particle [kg] (2-D: per unit length [kg/m]).
        particle_volume: rest volume of one particle [m³] (2-D: area [m²]).
        node_mass: the mass a grid node carries inside the fluid at rest, density · dx^d [kg] (2-D: [kg/m]).
        bulk_modulus: κ of the weakly compressible fluid [Pa].
        gravity: acceleration of gravity [m/s²], (d,).
        viscosity_cap: the largest viscosity the explicit step resolves [Pa·s]; above it the fluid is rigid-like.
    """

    grid: Grid
    offsets: Tensor
    strides: Tensor
    nodes: Tensor
    cup: Cup
    cup_phi: Tensor
    cup_normal: Tensor
    cup_nodes: Tensor
    rod: RodShape
    rod_slip: bool
    particle_mass: float
    particle_volume: float
    node_mass: float
    bulk_modulus: float
    gravity: Tensor
    viscosity_cap: float

    @property
    def dim(self) -> int:
        return self.grid.dim


def p2g(scene: Scene, state: State, dt: float) -> tuple[Tensor, Stencil]:
    """Scatter particle momentum, with the pressure impulse, and mass to the grid: buffer (num_nodes, d + 1).

    The pressure impulse is the MLS-MPM node force −Σ V σ ∇w Δt with ∇w = w (4/dx²)(x_i − x_p), V = J V0 the
    particle's current volume and σ = τ_v(J) I its volumetric stress.
    """
    grid, m, d = scene.grid, scene.particle_mass, scene.dim
    st = quadratic_stencil(grid, state.x, scene.offsets, scene.strides)
    kirchhoff = scene.particle_volume * state.J * volumetric_stress(state.J, scene.bulk_modulus)
    eye = torch.eye(d, dtype=state.x.dtype, device=state.x.device)
    affine = m * state.C - (dt * 4.0 / grid.dx**2) * kirchhoff[:, None, None] * eye
    to_node = grid.dx * (scene.offsets.to(state.x.dtype)[None, :, :] - st.frac[:, None, :])  # x_i − x_p [m]
    momentum = st.weight[..., None] * (m * state.v[:, None, :] + torch.einsum("nab,nkb->nka", affine, to_node))
    contrib = torch.cat([momentum, (m * st.weight)[..., None]], dim=-1).reshape(-1, d + 1)
    index = st.index.reshape(-1, 1).expand(-1, d + 1)
    buffer = torch.zeros(grid.num_nodes, d + 1, dtype=state.x.dtype, device=state.x.device)
    return buffer.scatter_add(0, index, contrib), st


def enforce_boundaries(scene: Scene, v: Tensor, fluid: Tensor, rod: Tensor, rod_phi: Tensor, rod_normal: Tensor,
                       pose: RodPose) -> Tensor:
    """Node velocities with the cup's and the rod's ghost velocities in place [m/s], (num_nodes, d)."""
    mask = fluid.to(v.dtype)[:, None]
    field = torch.cat([v * mask, mask], dim=-1)
    cup = scene.cup_nodes
    cup_ghost = ghost_velocity(scene.grid, field, scene.nodes[cup], scene.cup_phi[cup], scene.cup_normal[cup],
                               torch.zeros_like, slip=scene.cup.wall == "slip")
    rod_ghost = ghost_velocity(scene.grid, field, scene.nodes[rod], rod_phi[rod], rod_normal[rod],
                               lambda p: rod_velocity(p, pose), slip=scene.rod_slip)
    return v.index_copy(0, cup, cup_ghost).index_copy(0, rod, rod_ghost)


def grid_update(scene: Scene, material, buffer: Tensor, pose: RodPose, dt: float) -> tuple[Tensor, Tensor, Tensor]:
    """Node velocities after gravity, the shear stress and the cup's and rod's boundary conditions [m/s],
    (num_nodes, d), with the fluid's force on the rod [N] (d,) and its torque about the rod's axis [N·m]
    (2-D: per unit length)."""
    grid, d = scene.grid, scene.dim
    mass, momentum = buffer[:, d], buffer[:, :d]
    has_mass = mass > MASS_FLOOR
    v = torch.where(has_mass[:, None], momentum / mass.clamp_min(MASS_FLOOR)[:, None] + dt * scene.gravity, 0.0)
    rod_phi, rod_normal = rod_sdf(scene.rod, scene.nodes, pose)
    solid = (scene.cup_phi <= 0) | (rod_phi <= 0)
    fluid = has_mass & ~solid
    rod = torch.nonzero(rod_phi <= 0).squeeze(1)

    # shear stress from the ghost-extended velocity field; a cell counts where it holds fluid: its emptiest corner
    # sets its volume, solid corners count as full, and cells wholly inside solids are left out
    v_ext = enforce_boundaries(scene, v, fluid, rod, rod_phi, rod_normal, pose)
    fill = torch.where(solid, 1.0, (2.0 * mass / scene.node_mass).clamp(max=1.0)).to(v.dtype)
    cell_volume = grid.dx**d * cell_min(fill, grid.shape) * cell_max((~solid).to(v.dtype), grid.shape)
    stress = material.shear_stress(cell_velocity_gradient(v_ext, grid.shape, grid.dx), scene.viscosity_cap, dt)
    f_shear = nodal_forces(stress, cell_volume, grid.shape, grid.dx)
    inertia = mass.clamp_min(scene.node_mass)[:, None]  # lighter nodes (walls, surface) get the bulk's inertia
    v_visc = torch.where(has_mass[:, None], v + dt * f_shear / inertia, 0.0)
    v_new = enforce_boundaries(scene, v_visc, fluid, rod, rod_phi, rod_normal, pose)

    # the fluid's force on the rod is the rod's reaction on its ghost nodes: the shear stress on them less the
    # momentum the boundary condition gives the fluid mass they carry (pressure and gravity are in v)
    on_rod = f_shear[rod] - mass[rod, None] * (v_new[rod] - v[rod]) / dt
    force = on_rod.sum(0)
    arm = scene.nodes[rod, :2] - pose.axis
    torque = (arm[:, 0] * on_rod[:, 1] - arm[:, 1] * on_rod[:, 0]).sum()
    return v_new, force, torque


def g2p(scene: Scene, st: Stencil, v_grid: Tensor, state: State, dt: float) -> State:
    """Gather velocity and its MLS gradient back to the particles and advect them."""
    n, k, d = st.weight.shape[0], st.weight.shape[1], scene.dim
    v_nodes = v_grid.index_select(0, st.index.reshape(-1)).view(n, k, d)
    wv = st.weight[..., None] * v_nodes
    v = wv.sum(1)
    # C = (4/dx²) Σ w v_i (x_i − x_p)ᵀ, with x_i − x_p = (offset − frac) dx
    C = (4.0 / scene.grid.dx) * (torch.einsum("nka,kb->nab", wv, scene.offsets.to(v.dtype))
                                 - v[:, :, None] * st.frac[:, None, :])
    J = state.J * (1.0 + dt * C.diagonal(dim1=-2, dim2=-1).sum(-1))
    return State(x=state.x + dt * v, v=v, C=C, J=J)


def project_out_of_solids(scene: Scene, x: Tensor, pose: RodPose) -> Tensor:
    """Move particles that ended a step inside the cup's walls or the rod back onto the surface [m]."""
    phi, normal = cup_sdf(scene.cup, x)
    x = x - phi.clamp_max(0.0)[:, None] * normal
    phi, normal = rod_sdf(scene.rod, x, pose)
    x = x - phi.clamp_max(0.0)[:, None] * normal
    lo = scene.grid.origin + 0.5 * scene.grid.dx
    hi = scene.grid.origin + (torch.tensor(scene.grid.shape, dtype=x.dtype, device=x.device) - 1.5001) * scene.grid.dx
    return torch.maximum(torch.minimum(x, hi), lo)


def step(scene: Scene, material, state: State, pose: RodPose, dt: float) -> tuple[State, Tensor, Tensor]:
    """Advance the fluid by ``dt`` [s] with the rod moving rigidly as ``pose`` says (pose at mid-step).

    Returns the new state, the fluid's force on the rod [N] and its torque about the rod's axis [N·m]
    (in 2-D both per unit length of rod: [N/m], [N]).
    """
    buffer, st = p2g(scene, state, dt)
    v_grid, force, torque = grid_update(scene, material, buffer, pose, dt)
    new = g2p(scene, st, v_grid, state, dt)
    tip_rate = pose.velocity[2] if scene.dim == 3 else 0.0
    end_pose = RodPose(axis=pose.axis + 0.5 * dt * pose.velocity[:2], tip=pose.tip + 0.5 * dt * tip_rate,
                       angle=pose.angle + 0.5 * dt * pose.angular_velocity, velocity=pose.velocity,
                       angular_velocity=pose.angular_velocity)
    new.x = project_out_of_solids(scene, new.x, end_pose)
    return new, force, torque
