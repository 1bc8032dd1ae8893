"""Solid boundaries on the grid: the cup and the rod as signed distance fields, with ghost-fluid velocities.

A node inside a solid or on its surface (signed distance φ ≤ ``ON_SURFACE`` cells, φ > 0 in the fluid; ``is_solid``)
is given the solid's velocity plus the fluid's velocity relative to the solid, extrapolated linearly through the
surface from a probe point a distance ``PROBE_DISTANCE`` cells outside it:

    no-slip:  tangential u_rel(node) = −(|φ|/δ) u_rel(probe)      (odd: zero on the surface φ = 0)
              normal     u_rel(node) = +(|φ|/δ)² u_rel(probe)     (even: zero with zero normal derivative on the
                                                                  surface, as continuity demands at a no-slip wall)
    slip:     normal     u_rel(node) = −(|φ|/δ) u_rel(probe)       (odd: no penetration)
              tangential u_rel(node) = u_rel(probe)               (even: no shear stress)
    Navier:   tangential u_rel(node) = (b − |φ|)/(b + δ) u_rel(probe), normal as no-slip: the linear profile
              through the probe whose wall value is b times its normal gradient (slip length b [m]); b = 0 is
              no-slip, b → ∞ the tangential part of slip.

This puts the no-slip surface where the geometry is, to second order, instead of half a cell inside the solid as
marking the solid's nodes with its velocity does. Nodes deeper than the probe distance use their mirror point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ..rig import Cup, Rod
from .grid import Grid, flat_index, outer_weights

PROBE_DISTANCE = 2.0  # cells from the surface to the nearest probe; its linear stencil then lies in the fluid
BAND = 2.0  # cells: nodes deeper than this inside a solid carry no fluid mass and just take the solid's velocity
ON_SURFACE = 1e-4  # cells: a node this close to a surface is on it, and is a solid node with the wall's velocity


def is_solid(phi: Tensor, dx: float) -> Tensor:
    """Whether nodes with signed distance ``phi`` [m] belong to the solid: inside it or on its surface.

    A node exactly on a surface (the cup's wall, where the cup's radius is a whole number of cells) has φ = 0 in
    exact arithmetic and ±round-off in floating point; without a tolerance, float32 and float64 put it on
    different sides and the two precisions simulate different cups (2 % apart in force on 2.5 mm cells)."""
    return phi <= ON_SURFACE * dx


@dataclass
class RodPose:
    """The rod's rigid motion over one step.

    Attributes:
        axis: horizontal position of the rod's axis [m], (2,).
        tip: height of the rod's tip above the cup's bottom [m] (unused in 2-D).
        angle: rotation about its own axis [rad].
        velocity: velocity of the rod [m/s], (d,).
        angular_velocity: rate of turn about its own (vertical) axis [rad/s].
    """

    axis: Tensor
    tip: Tensor
    angle: Tensor
    velocity: Tensor
    angular_velocity: Tensor


def cup_sdf(cup: Cup, points: Tensor) -> tuple[Tensor, Tensor]:
    """Signed distance to the cup's wall and bottom [m] (positive inside the cup) and its unit gradient."""
    r_vec = points[:, :2]
    r = r_vec.norm(dim=-1).clamp_min(1e-12)
    phi = cup.radius - r
    inward = -r_vec / r[:, None]
    if points.shape[1] == 2:
        return phi, inward
    bottom = points[:, 2]
    use_bottom = (bottom < phi)[:, None]
    normal = torch.cat([torch.where(use_bottom, 0.0, inward), use_bottom.to(points.dtype)], dim=1)  # bottom: up
    return torch.where(use_bottom[:, 0], bottom, phi), normal


class RodShape:
    """The rod's geometry in its own frame: signed distance (positive in the fluid) with its unit gradient.

    ``axisymmetric``: the shape is a body of revolution about the rod's axis, so turning the rod leaves its
    distance field unchanged.
    """

    axisymmetric = False

    def sdf(self, local: Tensor) -> tuple[Tensor, Tensor]:
        raise NotImplementedError


class CylinderRod(RodShape):
    """A vertical cylinder of ``radius`` [m] whose flat tip is at local z = 0 (in 2-D, a disc)."""

    axisymmetric = True

    def __init__(self, radius: float):
        self.radius = radius

    def sdf(self, local: Tensor) -> tuple[Tensor, Tensor]:
        r_vec = local[:, :2]
        r = r_vec.norm(dim=-1).clamp_min(1e-12)
        d_r = r - self.radius
        radial = r_vec / r[:, None]
        if local.shape[1] == 2:
            return d_r, radial
        d_z = -local[:, 2]  # positive below the tip
        out_r, out_z = d_r.clamp_min(0), d_z.clamp_min(0)
        corner = torch.sqrt(out_r**2 + out_z**2).clamp_min(1e-12)
        outside_both = (d_r > 0) & (d_z > 0)
        phi = torch.where(outside_both, corner, torch.maximum(d_r, d_z))
        # normal = c_r (radial, 0) + c_z (0, 0, −1): towards the tip's rim below and beside it, else the nearer face
        c_r = torch.where(outside_both, out_r / corner, (d_r > d_z).to(local.dtype))
        c_z = torch.where(outside_both, out_z / corner, (d_r <= d_z).to(local.dtype))
        return phi, torch.cat([c_r[:, None] * radial, -c_z[:, None]], dim=1)


class MeshRod(RodShape):
    """Any closed mesh (spoon, paddle) as a rod: its signed distance sampled once on a fine grid, interpolated.

    The mesh is in the rod's frame, metres, with the tip at z = 0 and the axis along z; 3-D only.
    """

    def __init__(self, path: str, spacing: float):
        import trimesh

        mesh = trimesh.load(path, force="mesh")
        if not mesh.is_watertight:
            raise ValueError(f"rod.mesh {path!r} is not a closed (watertight) mesh; its inside is undefined")
        if mesh.extents.max() > 2.0:
            raise ValueError(f"rod.mesh {path!r} is {mesh.extents.max():.3g} long: it looks like millimetres, "
                             "expected metres")
        lo, hi = mesh.bounds[0] - 3 * spacing, mesh.bounds[1] + 3 * spacing
        axes = [np.arange(lo[a], hi[a] + spacing, spacing) for a in range(3)]
        pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        phi = -trimesh.proximity.signed_distance(mesh, pts).reshape([a.size for a in axes])  # trimesh: + inside
        self.origin = torch.tensor(lo)
        self.spacing = spacing
        self.phi = torch.tensor(phi)
        self.gradient = torch.tensor(np.stack(np.gradient(phi, spacing), axis=-1))
        self.radius = float(np.max(np.linalg.norm(mesh.vertices[:, :2], axis=-1)))
        self._fields: dict[tuple, tuple[Grid, Tensor, Tensor]] = {}

    def _field(self, like: Tensor) -> tuple[Grid, Tensor, Tensor]:
        """The sampled φ and ∇φ as (nodes, 4) on ``like``'s device and dtype, their grid and the value outside it,
        converted once per device and dtype."""
        key = (like.device, like.dtype)
        if key not in self._fields:
            field = torch.cat([self.phi[..., None], self.gradient], -1).to(like).reshape(-1, 4)
            samples = Grid(origin=self.origin.to(like), shape=tuple(self.phi.shape), dx=self.spacing)
            outside = torch.tensor([4 * self.spacing, 0, 0, 0], dtype=like.dtype, device=like.device)
            self._fields[key] = samples, field, outside
        return self._fields[key]

    def sdf(self, local: Tensor) -> tuple[Tensor, Tensor]:
        if local.shape[1] != 3:
            raise ValueError("a mesh rod needs sim.dim = 3")
        samples, field, outside = self._field(local)
        sample = interpolate_linear(samples, field, local, outside=outside)
        normal = sample[:, 1:] / sample[:, 1:].norm(dim=-1, keepdim=True).clamp_min(1e-12)
        return sample[:, 0], normal


def rod_shape(rod: Rod, dx: float) -> RodShape:
    return MeshRod(rod.mesh, spacing=dx / 4) if rod.mesh else CylinderRod(rod.radius)


def rod_offset(points: Tensor, pose: RodPose) -> Tensor:
    """Points relative to the rod's tip on its axis [m], in cup-frame axes, (Q, d)."""
    if points.shape[1] == 2:
        return points - pose.axis
    return points - torch.cat([pose.axis, pose.tip.reshape(1)])


def _turn(vectors: Tensor, c: Tensor, s: Tensor) -> Tensor:
    """Vectors (Q, d) turned about the vertical axis by the angle whose cosine and sine are c, s."""
    x, y = vectors[:, 0], vectors[:, 1]
    return torch.cat([torch.stack([c * x - s * y, s * x + c * y], dim=-1), vectors[:, 2:]], dim=1)


def rod_local(points: Tensor, pose: RodPose) -> Tensor:
    """Points in the rod's frame: origin at the tip on the axis, turned by −angle."""
    return _turn(rod_offset(points, pose), torch.cos(pose.angle), -torch.sin(pose.angle))


def rod_sdf(shape: RodShape, points: Tensor, pose: RodPose) -> tuple[Tensor, Tensor]:
    """Signed distance to the rod [m] (positive in the fluid) and its unit gradient, in the cup frame.

    An axisymmetric shape's distance field does not turn with the rod, so its frame is only shifted."""
    if shape.axisymmetric:
        return shape.sdf(rod_offset(points, pose))
    phi, n_local = shape.sdf(rod_local(points, pose))
    return phi, rod_to_cup(n_local, pose)


def rod_to_cup(local: Tensor, pose: RodPose) -> Tensor:
    """Rod-frame vectors turned by the rod's angle into the cup frame (directions; add the axis for points)."""
    return _turn(local, torch.cos(pose.angle), torch.sin(pose.angle))


def rod_velocity(points: Tensor, pose: RodPose) -> Tensor:
    """Rigid-body velocity of the rod at ``points`` [m/s]: V + Ω ẑ × (x − axis)."""
    rel = points[:, :2] - pose.axis
    spin = pose.angular_velocity * torch.stack([-rel[:, 1], rel[:, 0]], dim=-1)
    return pose.velocity + (spin if points.shape[1] == 2 else F.pad(spin, (0, 1)))


def linear_stencil(grid: Grid, points: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Multilinear interpolation stencil of ``points`` [m], (Q, d), on ``grid``.

    Returns the flat indices of the 2^d corner nodes of each point's cell (Q, 2^d), their weights [1] (Q, 2^d)
    (rows sum to 1) and whether the point lies inside the grid (Q,); outside points use the nearest cell, clamped.
    """
    cell = (points - grid.origin) / grid.dx
    base = torch.floor(cell).detach().long()
    inside = ((base >= 0) & (base <= grid.last_cell)).all(dim=1)
    base = torch.minimum(base.clamp_min(0), grid.last_cell)
    frac = (cell - base).clamp(0.0, 1.0)
    index = flat_index(base, grid.flat_strides)[:, None] + grid.corner_offsets[None, :]
    return index, outer_weights(torch.stack([1.0 - frac, frac], dim=-1)), inside


def interpolate_linear(grid: Grid, field: Tensor, points: Tensor, outside: Tensor | None = None) -> Tensor:
    """Multilinear interpolation of a node ``field`` (num_nodes, c) at ``points`` [m], (Q, d) -> (Q, c).

    Points outside the grid take the value ``outside`` (default: clamped to the nearest cell).
    """
    index, weight, inside = linear_stencil(grid, points)
    corners = field.index_select(0, index.reshape(-1)).view(*index.shape, field.shape[1])
    result = (weight[:, None, :] @ corners).squeeze(1)
    if outside is not None:
        result = torch.where(inside[:, None], result, outside.to(result))
    return result


def ghost_matrix(depth: Tensor, delta: Tensor, normal: Tensor, slip: bool,
                 slip_length: float | Tensor = 0.0) -> Tensor:
    """G, the ghost node's velocity relative to the wall per unit relative velocity at its probe [1], (Q, d, d):
    G = a_n n nᵀ + a_t (I − n nᵀ), with (module docstring, r = |φ|/δ, ``depth`` |φ| [m], ``delta`` δ [m])

        no-slip: a_n = r², a_t = −r;     slip: a_n = −r, a_t = 1;     Navier (slip length b [m]): a_n = r²,
        a_t = (b − |φ|)/(b + δ).

    ``slip_length`` (float or differentiable 0-d tensor, ignored when ``slip``) selects Navier partial slip.
    """
    ratio = depth / delta
    if slip:
        a_n, a_t = -ratio, torch.ones_like(ratio)
    elif isinstance(slip_length, Tensor) or slip_length > 0:
        a_n, a_t = ratio**2, (slip_length - depth) / (slip_length + delta)
    else:
        a_n, a_t = ratio**2, -ratio
    nn_t = normal[:, :, None] * normal[:, None, :]
    eye = torch.eye(normal.shape[1], dtype=normal.dtype, device=normal.device)
    return (a_n - a_t)[:, None, None] * nn_t + a_t[:, None, None] * eye


@dataclass
class GhostBand:
    """Solid nodes with their probes: the geometry of the ghost-fluid extension, which does not depend on the flow.

    Attributes:
        target: flat indices of the solid nodes, (Q,) int64.
        nodes: their positions [m], (Q, d).
        probes: the probe points, a distance δ = max(|φ|, ``PROBE_DISTANCE`` dx) outside the surface [m], (Q, d).
        source: flat indices of the probes' 2^d interpolation nodes, (Q, 2^d) int64.
        weight: their multilinear weights [1], (Q, 2^d).
        matrix: ``ghost_matrix`` of each node [1], (Q, d, d).
    """

    target: Tensor
    nodes: Tensor
    probes: Tensor
    source: Tensor
    weight: Tensor
    matrix: Tensor


def ghost_band(grid: Grid, target: Tensor, nodes: Tensor, phi: Tensor, normal: Tensor, slip: bool,
               slip_length: float | Tensor = 0.0) -> GhostBand:
    """The ``GhostBand`` of solid ``nodes`` (positions [m], (Q, d), flat indices ``target``) with signed distances
    ``phi`` <= 0 [m] and outward unit normals ``normal`` (into the fluid)."""
    depth = (-phi).clamp_min(0.0)
    delta = depth.clamp_min(PROBE_DISTANCE * grid.dx)
    probes = nodes + (depth + delta)[:, None] * normal
    source, weight, _ = linear_stencil(grid, probes)
    return GhostBand(target=target, nodes=nodes, probes=probes, source=source, weight=weight,
                     matrix=ghost_matrix(depth, delta, normal, slip, slip_length))


@dataclass
class GhostOperator:
    """Ghost-fluid velocities of solid nodes as an affine map of the fluid's node velocities v [m/s]:

        v(target_q) = offset_q + G_q Σ_c W_qc v(source_qc)        for the targets that are ``active``

    where W interpolates the fluid's velocity at the probe from the nodes that carry fluid only (its weights are
    renormalised over them), and offset_q = u_wall(node_q) − G_q u_wall(probe_q) (zero where the probe sees no
    fluid). The fluid mask is fixed within a step, so one operator serves every boundary pass of the step.
    Inactive targets (``active`` False; None: all active) keep their velocity.
    """

    target: Tensor
    source: Tensor
    weight: Tensor
    matrix: Tensor
    offset: Tensor
    active: Tensor | None = None

    @classmethod
    def of(cls, band: GhostBand, fluid: Tensor, wall_velocity=None, active: Tensor | None = None) -> "GhostOperator":
        """The operator of ``band`` for node fluid mask ``fluid`` (num_nodes,) float, 1 on nodes that carry fluid
        outside every solid; ``wall_velocity(points)`` [m/s] is the solid's velocity (None: at rest); ``active``
        (Q,) bool marks the band's nodes that are inside the solid (None: all)."""
        w = band.weight * fluid[band.source]
        total = w.sum(1, keepdim=True)
        seen = total > 1e-6
        w = torch.where(seen, w / total.clamp_min(1e-6), 0.0)
        if wall_velocity is None:
            offset = torch.zeros_like(band.nodes)
        else:
            wall_node, wall_probe = wall_velocity(torch.cat([band.nodes, band.probes])).chunk(2)
            offset = wall_node - seen * (band.matrix @ wall_probe[:, :, None]).squeeze(-1)
        return cls(target=band.target, source=band.source, weight=w, matrix=band.matrix, offset=offset,
                   active=active)

    def without_offset(self) -> "GhostOperator":
        """The linear part: the ghost velocities with the wall at rest."""
        return GhostOperator(self.target, self.source, self.weight, self.matrix, torch.zeros_like(self.offset),
                             self.active)

    def __call__(self, v: Tensor) -> Tensor:
        """``v`` (num_nodes, d) with the ghost velocities of the targets in place [m/s]."""
        q, k = self.source.shape
        corners = v.index_select(0, self.source.reshape(-1)).view(q, k, v.shape[1])
        probe = (self.weight[:, None, :] @ corners).transpose(1, 2)  # (Q, d, 1)
        ghost = self.offset + (self.matrix @ probe).squeeze(-1)
        if self.active is not None:
            ghost = torch.where(self.active[:, None], ghost, v.index_select(0, self.target))
        return v.index_copy(0, self.target, ghost)


@dataclass(frozen=True)
class RodWindow:
    """A fixed block of grid nodes that holds every node inside the rod wherever its axis is: the grid's full
    height, and ceil(2 R / dx) + 2 nodes along each horizontal axis, R the rod's bounding radius [m]. A fixed node
    count keeps a step's tensor shapes constant (one compiled graph, no data-dependent sizes) and confines the rod's
    distance field and ghost nodes to the nodes near it.

    Attributes:
        offsets: flat index of each window node relative to the window's first node, (W,) int64.
        reach: R [m].
        last_start: the largest index of the window's first node along each horizontal axis that keeps it on the
            grid, (2,) int64.
    """

    offsets: Tensor
    reach: float
    last_start: Tensor

    @classmethod
    def of(cls, grid: Grid, reach: float) -> "RodWindow":
        width = min(int(np.ceil(2 * reach / grid.dx)) + 2, *grid.shape[:2])
        sizes = [width, width, *grid.shape[2:]]
        block = torch.stack(torch.meshgrid(*[torch.arange(n, device=grid.origin.device) for n in sizes],
                                           indexing="ij"), dim=-1).reshape(-1, grid.dim)
        last = torch.tensor(grid.shape[:2], device=grid.origin.device) - width
        return cls(offsets=flat_index(block, grid.flat_strides), reach=reach, last_start=last)

    def nodes(self, grid: Grid, axis: Tensor) -> Tensor:
        """Flat indices of the window's nodes for the rod's axis at ``axis`` [m], (W,) int64."""
        start = torch.floor((axis - self.reach - grid.origin[:2]) / grid.dx).detach().long()
        start = torch.minimum(start.clamp_min(0), self.last_start)
        return flat_index(start, grid.flat_strides[:2]) + self.offsets
