"""Solid boundaries on the grid: the cup and the rod as signed distance fields, with ghost-fluid velocities.

A node inside a solid (signed distance φ < 0, φ > 0 in the fluid) is given the solid's velocity plus the fluid's
velocity relative to the solid, extrapolated linearly through the surface from a probe point a distance
``PROBE_DISTANCE`` cells outside it:

    no-slip:  tangential u_rel(node) = −(|φ|/δ) u_rel(probe)      (odd: zero on the surface φ = 0)
              normal     u_rel(node) = +(|φ|/δ)² u_rel(probe)     (even: zero with zero normal derivative on the
                                                                  surface, as continuity demands at a no-slip wall)
    slip:     normal     u_rel(node) = −(|φ|/δ) u_rel(probe)       (odd: no penetration)
              tangential u_rel(node) = u_rel(probe)               (even: no shear stress)

This puts the no-slip surface where the geometry is, to second order, instead of half a cell inside the solid as
marking the solid's nodes with its velocity does. Nodes deeper than the probe distance use their mirror point.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..rig import Cup, Rod
from .grid import Grid

PROBE_DISTANCE = 2.0  # cells from the surface to the nearest probe; its linear stencil then lies in the fluid
BAND = 2.0  # cells: nodes deeper than this inside a solid carry no fluid mass and just take the solid's velocity


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
    normal = torch.zeros_like(points)
    normal[:, :2] = -r_vec / r[:, None]
    if points.shape[1] == 3:
        bottom = points[:, 2]
        use_bottom = bottom < phi
        phi = torch.where(use_bottom, bottom, phi)
        up = torch.zeros_like(points)
        up[:, 2] = 1.0
        normal = torch.where(use_bottom[:, None], up, normal)
    return phi, normal


class RodShape:
    """The rod's geometry in its own frame: signed distance (positive in the fluid) with its unit gradient."""

    def sdf(self, local: Tensor) -> tuple[Tensor, Tensor]:
        raise NotImplementedError


class CylinderRod(RodShape):
    """A vertical cylinder of ``radius`` [m] whose flat tip is at local z = 0 (in 2-D, a disc)."""

    def __init__(self, radius: float):
        self.radius = radius

    def sdf(self, local: Tensor) -> tuple[Tensor, Tensor]:
        r_vec = local[:, :2]
        r = r_vec.norm(dim=-1).clamp_min(1e-12)
        d_r = r - self.radius
        radial = torch.zeros_like(local)
        radial[:, :2] = r_vec / r[:, None]
        if local.shape[1] == 2:
            return d_r, radial
        d_z = -local[:, 2]  # positive below the tip
        down = torch.zeros_like(local)
        down[:, 2] = -1.0
        corner = torch.sqrt(d_r.clamp_min(0) ** 2 + d_z.clamp_min(0) ** 2).clamp_min(1e-12)
        outside_both = (d_r > 0) & (d_z > 0)
        phi = torch.where(outside_both, corner, torch.maximum(d_r, d_z))
        corner_normal = (d_r.clamp_min(0)[:, None] * radial + d_z.clamp_min(0)[:, None] * down) / corner[:, None]
        normal = torch.where(outside_both[:, None], corner_normal, torch.where((d_r > d_z)[:, None], radial, down))
        return phi, normal


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

    def sdf(self, local: Tensor) -> tuple[Tensor, Tensor]:
        if local.shape[1] != 3:
            raise ValueError("a mesh rod needs sim.dim = 3")
        field = torch.cat([self.phi[..., None], self.gradient], -1).to(local)
        shape = tuple(self.phi.shape)
        sample = interpolate_linear(self.origin.to(local), self.spacing, shape, field.reshape(-1, 4), local,
                                    outside=torch.tensor([4 * self.spacing, 0, 0, 0], dtype=local.dtype))
        normal = sample[:, 1:] / sample[:, 1:].norm(dim=-1, keepdim=True).clamp_min(1e-12)
        return sample[:, 0], normal


def rod_shape(rod: Rod, dx: float) -> RodShape:
    return MeshRod(rod.mesh, spacing=dx / 4) if rod.mesh else CylinderRod(rod.radius)


def rod_local(points: Tensor, pose: RodPose) -> Tensor:
    """Points in the rod's frame: origin at the tip on the axis, turned by −angle."""
    rel = points.clone()
    rel[:, :2] = points[:, :2] - pose.axis
    if points.shape[1] == 3:
        rel[:, 2] = points[:, 2] - pose.tip
    c, s = torch.cos(pose.angle), torch.sin(pose.angle)
    x, y = rel[:, 0].clone(), rel[:, 1].clone()
    rel[:, 0], rel[:, 1] = c * x + s * y, -s * x + c * y
    return rel


def rod_sdf(shape: RodShape, points: Tensor, pose: RodPose) -> tuple[Tensor, Tensor]:
    """Signed distance to the rod [m] (positive in the fluid) and its unit gradient, in the cup frame."""
    phi, n_local = shape.sdf(rod_local(points, pose))
    return phi, rod_to_cup(n_local, pose)


def rod_to_cup(local: Tensor, pose: RodPose) -> Tensor:
    """Rod-frame vectors turned by the rod's angle into the cup frame (directions; add the axis for points)."""
    c, s = torch.cos(pose.angle), torch.sin(pose.angle)
    out = local.clone()
    out[:, 0], out[:, 1] = c * local[:, 0] - s * local[:, 1], s * local[:, 0] + c * local[:, 1]
    return out


def rod_velocity(points: Tensor, pose: RodPose) -> Tensor:
    """Rigid-body velocity of the rod at ``points`` [m/s]: V + Ω ẑ × (x − axis)."""
    rel = points[:, :2] - pose.axis
    v = pose.velocity.expand(points.shape[0], -1).clone()
    v[:, 0] = v[:, 0] - pose.angular_velocity * rel[:, 1]
    v[:, 1] = v[:, 1] + pose.angular_velocity * rel[:, 0]
    return v


def interpolate_linear(origin: Tensor, dx: float, shape: tuple[int, ...], field: Tensor, points: Tensor,
                       outside: Tensor | None = None) -> Tensor:
    """Multilinear interpolation of a node ``field`` (num_nodes, c) at ``points`` [m], (Q, d) -> (Q, c).

    Points outside the grid take the value ``outside`` (default: clamped to the nearest cell).
    """
    d = points.shape[1]
    size = torch.tensor(shape, device=points.device)
    cell = (points - origin) / dx
    base = torch.floor(cell).detach().long()
    inside = ((base >= 0) & (base <= size - 2)).all(dim=1)
    base = torch.minimum(base.clamp_min(0), size - 2)
    frac = (cell - base).clamp(0.0, 1.0)
    strides = [1] * d
    for a in range(d - 2, -1, -1):
        strides[a] = strides[a + 1] * shape[a + 1]
    strides_t = torch.tensor(strides, device=points.device)
    result = 0.0
    for corner in itertools.product((0, 1), repeat=d):
        c = torch.tensor(corner, device=points.device)
        w = torch.where(c.bool(), frac, 1.0 - frac).prod(dim=1)
        idx = (base + c) @ strides_t
        result = result + w[:, None] * field.index_select(0, idx)
    if outside is not None:
        result = torch.where(inside[:, None], result, outside.to(result))
    return result


def ghost_velocity(
    grid: Grid, fluid_field: Tensor, nodes: Tensor, phi: Tensor, normal: Tensor, wall_velocity, slip: bool
) -> Tensor:
    """Ghost-fluid velocities [m/s] of solid ``nodes`` (positions, (Q, d)) with signed distances ``phi`` < 0.

    ``fluid_field`` holds [mask·v, mask] on every node, mask = 1 on nodes that carry fluid and lie outside every
    solid, so the probe interpolates the fluid's velocity only. ``wall_velocity(points)`` is the solid's velocity.
    """
    depth = (-phi).clamp_min(0.0)
    delta = depth.clamp_min(PROBE_DISTANCE * grid.dx)
    probes = nodes + (depth + delta)[:, None] * normal
    sample = interpolate_linear(grid.origin, grid.dx, grid.shape, fluid_field, probes)
    weight = sample[:, -1:]
    u_probe = torch.where(weight > 1e-6, sample[:, :-1] / weight.clamp_min(1e-6), 0.0)
    u_rel = torch.where(weight > 1e-6, u_probe - wall_velocity(probes), 0.0)
    ratio = (depth / delta)[:, None]
    u_n = (u_rel * normal).sum(-1, keepdim=True) * normal
    u_t = u_rel - u_n
    if slip:
        ghost_rel = -ratio * u_n + u_t
    else:
        ghost_rel = ratio**2 * u_n - ratio * u_t
    return wall_velocity(nodes) + ghost_rel
