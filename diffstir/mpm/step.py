"""One MLS-MPM step: particle-to-grid, grid update with boundaries, grid-to-particle.

Quadratic B-splines, APIC/MLS transfers (Hu et al. 2018) blended with FLIP in the particles' velocity, explicit time
integration. The volumetric (pressure) stress lives on the particles and enters in ``p2g``; the shear stress of the
material is evaluated on the grid, from the ghost-extended velocity field, in ``grid_update`` (see ``viscous``); the
particles' volume ratio relaxes towards the packing the grid measures in ``g2p`` (see ``packing``).
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import Tensor

from . import transfer
from .boundaries import GhostOperator, RodPose, cup_sdf, ghost_band, is_solid, rod_sdf, rod_velocity
from .grid import Stencil, quadratic_stencil
from .implicit_viscosity import implicit_viscous_step
from .materials import volumetric_stress
from .packing import SURFACE_FILL, deposit, packed_volume_ratio, place_rod_points
from .projection import Projection, divergence, divergence_transpose, solve_pressure
from .scene import Scene
from .state import State
from .viscous import cell_any, cell_mean, cell_min, cell_velocity_gradient, nodal_forces
from .wall_pressure import wall_impulses

MASS_FLOOR = 1e-12  # kg: nodes lighter than this carry no fluid


def node_fill(scene: Scene, mass: Tensor, pose: RodPose) -> Tensor:
    """φ_i = (m_i + m_i^solid) / (ρ dx^d): how full each node is, with the solids counted as resting fluid [1],
    (num_nodes,), from the particles' node mass ``mass`` [kg] (``packing``)."""
    rod = deposit(scene.grid, place_rod_points(scene.rod, scene.rod_points, pose), scene.rod_point_mass,
                  scene.offset_index, scene.strides, scene.particle_bounds)
    return (mass + scene.solid_mass + rod) / scene.node_mass


def p2g(scene: Scene, state: State, dt: float) -> tuple[Tensor, Stencil]:
    """Scatter particle momentum, with the pressure impulse, and mass to the grid: buffer (num_nodes, d + 1), and
    with a FLIP share (``scene.flip`` > 0) the momentum without the impulse in d more columns, (num_nodes, 2d + 1).

    The pressure impulse is the MLS-MPM node force −Σ V σ ∇w Δt with ∇w = w (4/dx²)(x_i − x_p), V = J V0 the
    particle's current volume and σ = τ_v(J) I its volumetric stress.
    """
    grid, m, d = scene.grid, scene.particle_mass, scene.dim
    st = quadratic_stencil(grid, state.x, scene.offset_index, scene.strides, weights=not scene.fused)
    kirchhoff = scene.particle_volume * state.J * volumetric_stress(state.J, scene.bulk_modulus)
    # node k receives w_pk (m v_p + A_p (x_k − x_p)), A = m C − (4 Δt/dx²) V σ, x_k − x_p = (o_k − frac_p) dx:
    # w_pk T_p [o_k, 1] with T_p = [[dx A_p, b_p], [0, m]], b_p = m v_p − dx A_p frac_p, in the component-major
    # layout (d + 1, N, d + 1) of ``transfer.scatter``.
    affine = grid.dx * (m * state.C - (dt * 4.0 / grid.dx**2) * kirchhoff[:, None, None] * scene.eye)
    b = m * state.v - (affine @ st.frac[:, :, None]).squeeze(-1)
    n = state.x.shape[0]
    rows = [torch.cat([affine, b[:, :, None]], dim=2).transpose(0, 1), scene.mass_row.expand(1, n, d + 1)]
    if scene.flip > 0:  # the same transfer without the pressure term: the grid's velocity before any force
        plain = grid.dx * m * state.C
        rows.append(torch.cat([plain, (m * state.v - (plain @ st.frac[:, :, None]).squeeze(-1))[:, :, None]],
                              dim=2).transpose(0, 1))
    return transfer.scatter(torch.cat(rows), st, grid.num_nodes, scene.stencil_points, scene.fused), st


def boundary_operators(scene: Scene, has_mass: Tensor, pose: RodPose) -> tuple[Tensor, Tensor, Tensor,
                                                                                GhostOperator, GhostOperator]:
    """The step's solids: the node solid mask (num_nodes,) bool, the rod window's node indices (W,) and which of
    them lie inside the rod (W,) bool, and the ghost-velocity operators of the cup and of the rod
    (``boundaries.GhostOperator``; apply the cup's first). ``has_mass``: the nodes that carry mass."""
    window = scene.rod_window.nodes(scene.grid, pose.axis)
    window_nodes = scene.nodes[window]
    rod_phi, rod_normal = rod_sdf(scene.rod, window_nodes, pose)
    in_rod = is_solid(rod_phi, scene.grid.dx)
    cup_solid = is_solid(scene.cup_phi, scene.grid.dx)
    solid = cup_solid.index_copy(0, window, cup_solid[window] | in_rod)
    fluid = (has_mass & ~solid).to(window_nodes.dtype)
    rod_band = ghost_band(scene.grid, window, window_nodes, rod_phi, rod_normal, scene.rod_slip, scene.rod_slip_length)
    return (solid, window, in_rod, GhostOperator.of(scene.cup_band, fluid),
            GhostOperator.of(rod_band, fluid, lambda p: rod_velocity(p, pose), active=in_rod))


class GridUpdate(NamedTuple):
    """The grid after a step's forces and boundary conditions.

    Attributes:
        velocity: node velocities [m/s], (num_nodes, d).
        force: the fluid's force on the rod [N] (2-D: per unit length [N/m]), (d,).
        torque: the fluid's torque on the rod about its axis [N·m] (2-D: [N]), 0-d.
        material: the material's new state (``State.material``), or None.
        pressure: with ``scene.incompressible``, the step's pressure in each cell [Pa], (cells,) (``State.pressure``);
            else None.
    """

    velocity: Tensor
    force: Tensor
    torque: Tensor
    material: Tensor | None
    pressure: Tensor | None


def grid_update(scene: Scene, material, buffer: Tensor, pose: RodPose, dt: float,
                material_state: Tensor | None = None, packing: Tensor | None = None,
                wall_push: tuple[Tensor, Tensor] | None = None, substeps: int = 1,
                pressure: Tensor | None = None) -> GridUpdate:
    """Node velocities after gravity, the shear stress, the pressure (with ``scene.incompressible``, which needs the
    nodes' fill ``packing``, ``node_fill``) and the cup's and rod's boundary conditions, with the fluid's force and
    torque on the rod.

    The shear stress advances the velocity in ``substeps`` explicit steps of dt/m, each from the velocity the last
    one left (with the walls' ghost velocities): v ← v + (dt/m) f(v) / m_i. The fluid's mass, the cells' volumes
    and the pressure stay those of the whole step, so a step of dt resolves a viscosity whose explicit limit is
    dt/m; the rod's reaction takes the substeps' mean force. With ``scene.incompressible`` and m > 1, the last
    step's cell ``pressure`` [Pa] (``State.pressure``) pushes the velocity between substeps, so that they follow
    the shear stress the pressure balances rather than a velocity that drifts from divergence-free until the step's
    end; its push is then taken back and the projection solves for the whole step's pressure (solving for its
    change only would leave the checkerboard's stabilisation, ``projection``, to the change).

    With a ``material_state`` (``State.material``), the material is called as
    ``material.shear_stress(grad_v, cap, dt, state=material_state)`` and returns the stress with its new state.
    ``wall_push``: the pressure impulses [N·s] of the rod's and of the cup's boundary particles on the nodes
    (``wall_pressure.wall_impulses``). The cup's go to the fluid's nodes; the rod's to the fluid's and to the rod's own,
    where its reaction returns them, so that the rod's force counts its push on the fluid with the opposite sign.
    """
    grid, d = scene.grid, scene.dim
    mass, momentum = buffer[:, d], buffer[:, :d]
    has_mass = mass > MASS_FLOOR
    solid, window, in_rod, cup_ghosts, rod_ghosts = boundary_operators(scene, has_mass, pose)
    rod_push = None
    if wall_push is not None:
        rod_push, cup_push = wall_push
        rod_node = torch.zeros_like(solid).index_copy(0, window, in_rod)
        rod_push = torch.where((has_mass & (rod_node | ~solid))[:, None], rod_push, 0.0)
        momentum = momentum + rod_push + torch.where((has_mass & ~solid)[:, None], cup_push, 0.0)
    v = torch.where(has_mass[:, None], momentum / mass.clamp_min(MASS_FLOOR)[:, None] + dt * scene.gravity, 0.0)

    # shear stress from the ghost-extended velocity field; a cell counts where it holds fluid: its emptiest corner
    # sets its volume, solid corners count as full, and cells wholly inside solids are left out
    v_ext = rod_ghosts(cup_ghosts(v))
    fill = torch.where(solid, 1.0, (2.0 * mass / scene.node_mass).clamp(max=1.0)).to(v.dtype)
    cell_volume = grid.dx**d * cell_min(fill, scene.cells) * cell_any(~solid, scene.cells)
    inertia = mass.clamp_min(scene.node_mass)[:, None]  # lighter nodes (walls, surface) get the bulk's inertia
    implicit = scene.viscous_stiffness is not None
    kick, h = None, dt / substeps
    if scene.incompressible:
        operator, pressure_cell = pressure_operator(scene, mass, has_mass & ~solid, solid, packing, cup_ghosts,
                                                    rod_ghosts)
        if pressure is not None and (substeps > 1 or implicit):  # the last step's pressure's impulse over h
            kick = operator.impulse((h * grid.dx**d) * pressure * pressure_cell)
    if implicit:  # one backward-Euler solve (``implicit_viscosity``), the last step's pressure pushing throughout
        if material_state is not None:
            raise ValueError("sim.viscous_solver = implicit takes a material without a state of its own")
        eta = material.viscosity_of(cell_velocity_gradient(v_ext, scene.cells), scene.viscosity_cap)
        ghost = torch.zeros_like(has_mass).index_fill(0, cup_ghosts.target, True)
        ghost = ghost.index_copy(0, rod_ghosts.target, ghost[rod_ghosts.target] | in_rod)
        v_visc, f_shear = implicit_viscous_step(scene.cells, scene.viscous_stiffness, eta, cell_volume,
                                                v if kick is None else v + kick, inertia[:, 0], has_mass & ~ghost,
                                                cup_ghosts, rod_ghosts, dt)
        if kick is not None:  # the projection below solves for the whole step's pressure
            v_visc = v_visc - kick
    else:
        v_visc, f_shear = v, None
        for k in range(substeps):
            if k > 0:
                v_ext = rod_ghosts(cup_ghosts(v_visc))
            grad_v = cell_velocity_gradient(v_ext, scene.cells)
            if material_state is None:
                stress = material.shear_stress(grad_v, scene.viscosity_cap, h)
            else:
                stress, material_state = material.shear_stress(grad_v, scene.viscosity_cap, h, state=material_state)
            f = nodal_forces(stress, cell_volume, scene.cells, grid.num_nodes)
            v_visc = torch.where(has_mass[:, None], v_visc + h * f / inertia, 0.0)
            if kick is not None and k < substeps - 1:
                v_visc = v_visc + kick
            f_shear = f if f_shear is None else f_shear + f
        if kick is not None:  # the projection below solves for the whole step's pressure
            v_visc = v_visc - (substeps - 1) * kick
        if substeps > 1:
            f_shear = f_shear / substeps
    f_stress = f_shear
    if scene.incompressible:
        impulse = project(scene, operator, pressure_cell, v_visc, packing)
        v_visc = v_visc + operator.impulse(impulse)
        pressure = impulse * pressure_cell / (dt * grid.dx**d)
        # the pressure's node forces Σ_c p_c V_c ∇N_i(x_c) [N] (2-D: [N/m]); on the rod's nodes part of its reaction
        f_stress = f_shear + divergence_transpose(impulse * pressure_cell, scene.cells, grid.num_nodes) / dt
    v_new = rod_ghosts(cup_ghosts(v_visc))

    # the fluid's force on the rod is the rod's reaction on its ghost nodes: the stress's node forces on them less
    # the momentum the boundary condition gives the fluid mass they carry (with a sound speed, the pressure's
    # force and gravity are in v)
    reaction = f_stress[window] - mass[window, None] * (v_new[window] - v[window]) / dt
    on_rod = torch.where(in_rod[:, None], reaction, 0.0)
    force = on_rod.sum(0)
    arm = scene.nodes[window, :2] - pose.axis
    torque = (arm[:, 0] * on_rod[:, 1] - arm[:, 1] * on_rod[:, 0]).sum()
    if rod_push is not None:  # its boundary particles' push on the fluid's nodes is the rod's on the fluid
        push = rod_push / dt
        arm = scene.nodes[:, :2] - pose.axis
        force = force - push.sum(0)
        torque = torque - (arm[:, 0] * push[:, 1] - arm[:, 1] * push[:, 0]).sum()
    return GridUpdate(v_new, force, torque, material_state, pressure if scene.incompressible else None)


def pressure_operator(scene: Scene, mass: Tensor, fluid: Tensor, solid: Tensor, packing: Tensor,
                      cup_ghosts: GhostOperator, rod_ghosts: GhostOperator) -> tuple[Projection, Tensor]:
    """The step's projection (``projection.Projection``) and its pressure cells, 1 where a cell carries a pressure
    and 0 elsewhere, (cells,). A cell carries one where each corner is solid or at least ``SURFACE_FILL`` full
    (``packing``, the nodes' fill of ``node_fill``) and one is fluid. ``mass``: the nodes' masses [kg] (2-D:
    [kg/m]), (num_nodes,); the projection weighs the nodes by them, so that the pressure's impulse changes the
    fluid's momentum by exactly its amount (with the bulk inertia that the viscous update gives light nodes for
    stability the stir read high, docs/validation.md)."""
    full = solid | (packing >= SURFACE_FILL)
    pressure_cell = (cell_min(full.to(mass.dtype), scene.cells) * cell_any(fluid, scene.cells)).to(mass.dtype)
    mobility = torch.where(fluid, 1.0 / mass.clamp_min(MASS_FLOOR), 0.0)[:, None]
    return Projection.of(scene.cells, scene.cell_matrices, scene.grid.num_nodes, mobility, pressure_cell,
                         cup_ghosts, rod_ghosts, scene.node_mass), pressure_cell


def project(scene: Scene, operator: Projection, pressure_cell: Tensor, v: Tensor, packing: Tensor) -> Tensor:
    """The cells' pressure impulses π_c = Δt V_c p_c [N·s·m] (2-D: [N·s]), (cells,), that make the node velocities
    ``v`` [m/s] divergence-free up to the fill's relaxation (``projection``): v + ``operator.impulse(π)``."""
    source = scene.relaxation_rate * (cell_mean(packing, scene.cells) - 1.0)
    # the 2-D slice has no free surface: its volume is fixed, so only the fill's variation can relax
    source = source - (source * pressure_cell).sum() / pressure_cell.sum()
    return solve_pressure(operator, (source - divergence(operator.extend(v), scene.cells)) * pressure_cell)


def g2p(scene: Scene, st: Stencil, v_grid: Tensor, state: State, dt: float, v_before: Tensor | None = None,
        fill: Tensor | None = None) -> State:
    """Gather velocity and its MLS gradient back to the particles and advect them.

    ``v_before``: the grid's velocity before this step's forces [m/s], (num_nodes, d); with it the particle keeps
    ``scene.flip`` of the velocity the grid did not see, v_p − Σ w v_i^before (FLIP). ``fill``: the nodes' fill
    (``node_fill``); with it J relaxes towards the packing at ``scene.relaxation_rate`` (``packing``).
    """
    d = scene.dim
    # one gather of every nodal field the particles read: Σ_k w_k G_k [o_kᵀ, 1] per column (transfer.gather)
    columns = [v_grid] + ([v_before] if v_before is not None else []) + ([fill[:, None]] if fill is not None else [])
    gathered = transfer.gather(torch.cat(columns, 1), st, scene.stencil_points, scene.fused)  # (C, N, d + 1)
    # the node velocities' first moment and, in the last column, the velocity
    moments = gathered[:d].transpose(0, 1).contiguous()  # (N, d, d + 1); a new state has the layout of a seeded one
    v = moments[:, :, d].contiguous()
    # C = (4/dx²) Σ w v_i (x_i − x_p)ᵀ, with x_i − x_p = (offset − frac) dx
    C = (4.0 / scene.grid.dx) * (moments[:, :, :d] - v[:, :, None] * st.frac[:, None, :])
    J = state.J * (1.0 + dt * C.diagonal(dim1=-2, dim2=-1).sum(-1))
    if fill is not None:
        packed, inside = packed_volume_ratio(fill, st, gathered[-1, :, d])
        J = J + (dt * scene.relaxation_rate) * inside * (packed - J)
    if v_before is not None:
        v = v + scene.flip * (state.v - gathered[d:2 * d, :, d].T)
    return State(x=state.x + dt * v, v=v, C=C, J=J)


def project_out_of_solids(scene: Scene, x: Tensor, pose: RodPose) -> Tensor:
    """Move particles that ended a step inside the cup's walls or the rod back onto the surface [m]."""
    phi, normal = cup_sdf(scene.cup, x)
    x = x - phi.clamp_max(0.0)[:, None] * normal
    phi, normal = rod_sdf(scene.rod, x, pose)
    x = x - phi.clamp_max(0.0)[:, None] * normal
    return torch.clamp(x, scene.particle_bounds[0], scene.particle_bounds[1])


def step(scene: Scene, material, state: State, pose: RodPose, dt: float,
         substeps: int = 1) -> tuple[State, Tensor, Tensor]:
    """Advance the fluid by ``dt`` [s] with the rod moving rigidly as ``pose`` says (pose at mid-step), the shear
    stress in ``substeps`` explicit steps (``grid_update``).

    Returns the new state, the fluid's force on the rod [N] and its torque about the rod's axis [N·m]
    (in 2-D both per unit length of rod: [N/m], [N]).
    """
    buffer, st = p2g(scene, state, dt)
    d, mass = scene.dim, buffer[:, scene.dim]
    fill = node_fill(scene, mass, pose) if scene.relaxation_rate > 0 or scene.incompressible else None
    wall_push = None if scene.walls is None else wall_impulses(scene, state, st, mass, pose, dt)
    grid = grid_update(scene, material, buffer, pose, dt, state.material, fill, wall_push, substeps, state.pressure)
    v_before = None
    if scene.flip > 0:
        v_before = torch.where((mass > MASS_FLOOR)[:, None], buffer[:, d + 1:] / mass.clamp_min(MASS_FLOOR)[:, None],
                               0.0)
    new = g2p(scene, st, grid.velocity, state, dt, v_before, None if scene.incompressible else fill)
    new.material, new.pressure = grid.material, grid.pressure
    tip_rate = pose.velocity[2] if scene.dim == 3 else 0.0
    end_pose = RodPose(axis=pose.axis + 0.5 * dt * pose.velocity[:2], tip=pose.tip + 0.5 * dt * tip_rate,
                       angle=pose.angle + 0.5 * dt * pose.angular_velocity, velocity=pose.velocity,
                       angular_velocity=pose.angular_velocity)
    new.x = project_out_of_solids(scene, new.x, end_pose)
    return new, grid.force, grid.torque
