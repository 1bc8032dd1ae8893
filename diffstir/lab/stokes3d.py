"""The 3-D finite-element stir: Stokes or Navier-Stokes in a real cup, steady or in time (docs/validation.md).

The rig (``CupRig``): a cup of radius R [m] with a flat bottom, fluid to depth H [m] under a flat free surface, a rod
of radius a [m] immersed to depth h = H − g (its flat tip a gap g above the bottom), its axis on a circle of radius e
about the cup's axis, moving along that circle at speed U [m/s] without spinning in the lab.

Method. In the frame that turns with the rod (angle θ(t), rate Ω = θ', the rod's centre c = (e, 0, ·), moving along
+y for Ω > 0), the domain is fixed. The relative velocity u and the pressure p [Pa] solve

    ρ (∂u/∂t + u·∇u + 2 Ω ẑ × u + Ω' ẑ × x − Ω² (x, y, 0)) = −∇p + ∇·(2 η(γ̇) D(u)),    ∇·u = 0,

γ̇ = sqrt(2 D:D), with u = −Ω ẑ × x on the cup's wall and bottom (at rest in the lab), u = −Ω ẑ × (x − c) on the
rod's side and tip (translating in the lab without spin), and on the free surface u_z = 0 with zero shear traction
(a rigid rotation has no shear, so the condition is the same in both frames). Taylor-Hood elements (P2 velocity,
P1 pressure, scikit-fem) on an unstructured tetrahedral mesh from gmsh (OCC: cup cylinder minus rod cylinder,
cells of ``cell`` [m] at the rod growing to ``growth`` times that 2a away).

* ``solve``: the steady stir (Ω constant, ∂u/∂t = 0). Without ``inertia`` the left side is dropped (Stokes, for
  Re = ρ U 2a / η ≪ 1); with it the convection and the Coriolis term are linearised about the last iterate
  (Picard / Oseen) and the centrifugal term is a body force. A generalized-Newtonian law η(γ̇) (any
  ``diffstir.rheology`` law, in float64) is updated at the quadrature points by the same fixed-point iteration.
* ``stir_history``: the stir in time along any programme on the circle (speed steps, pauses, reversals), from rest:
  second-order backward differences (SBDF2) with the convection and Coriolis terms extrapolated from the two last
  steps and the frame's Euler and centrifugal terms evaluated at the new time; the viscous term is implicit with a
  frozen viscosity field η_f and explicit in η(γ̇*) − η_f (γ̇* of the extrapolated velocity), the matrix factorised
  once for a Newtonian fluid and again whenever η(γ̇*) exceeds η_f anywhere or falls below half of it on most of
  the fluid.

The force on the rod is the consistent reaction: the residual of the discrete momentum equation at the rod's
velocity degrees of freedom, with the pressure's mean on the free surface set to zero (no gravity: the hydrostatic
part is not in it). It is the traction of the fluid on the rod in the lab (the frame's terms are part of the
fluid's acceleration). ``solve`` reports it at the instant the rod passes (e, 0): x outward along the circle's
radius, y along the motion, z up (the drag is −F_y); ``stir_history`` in the lab's axes. The torque is about the
rod's own axis [N m], the dissipation ∫ 2 η D:D dV [W] (which equals the drag times U in Stokes flow).

Linear solver: SuperLU on the condensed saddle-point system up to ``DIRECT_LIMIT`` unknowns; above (``solve``
only), MINRES (GMRES with inertia) preconditioned by a smoothed-aggregation AMG V-cycle on the viscous block
(pyamg, the six rigid modes as near null space) and the pressure mass matrix weighted by 1/η (diagonal).

The virtual lab's 3-D truth (``diffstir.lab.synth``, ``lab/sim=fe3d``) is ``stir_history``; the checks against
closed forms and the 2-D reference, and the command line, are ``scripts/stir_reference_3d.py``. Needs scikit-fem,
gmsh and pyamg (``pip install -e ".[validation]"``); nothing else in the package imports this module.
"""

from __future__ import annotations

import dataclasses
import logging
import resource
import time

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, gmres, minres, splu
from skfem import (Basis, BilinearForm, ElementTetP1, ElementTetP2, ElementVector, Functional, LinearForm, MeshTet,
                   asm, bmat)
from skfem.helpers import ddot, div, dot, grad, sym_grad

logging.getLogger("skfem").setLevel(logging.WARNING)  # it logs every assembly at INFO

DIRECT_LIMIT = 40_000
"""Unknowns (velocity and pressure, after the boundary conditions) up to which the sparse direct solver is used."""

BOUNDARIES = ("wall", "bottom", "surface", "rod_side", "rod_tip")


@dataclasses.dataclass(frozen=True)
class CupRig:
    """The cup and the rod [m]. Defaults: the paper's rig (cup Ø 95 mm, fill 125 mm, rod Ø 25 mm, tip 20 mm above
    the bottom, circle radius 30 mm). ``gap`` 0 puts the rod through the whole depth (no tip); ``slip_bottom`` makes
    the bottom a slip wall like the free surface (u_z = 0, no shear), for the 2-D checks."""

    cup_radius: float = 0.0475
    fill: float = 0.125
    rod_radius: float = 0.0125
    gap: float = 0.020
    orbit: float = 0.030
    slip_bottom: bool = False

    @property
    def immersion(self) -> float:
        """h = H − g [m]."""
        return self.fill - self.gap

    @classmethod
    def of(cls, rig, orbit: float) -> "CupRig":
        """The cup and rod of a ``diffstir.rig.Rig`` with the rod's axis on a circle of radius ``orbit`` [m]."""
        return cls(cup_radius=rig.cup.radius, fill=rig.cup.fill_height, rod_radius=rig.rod.radius,
                   gap=rig.cup.fill_height - rig.rod.immersion_depth, orbit=orbit)


@dataclasses.dataclass
class RigMesh:
    """A tetrahedral mesh of the fluid, its boundary facets by name (``BOUNDARIES``), the rig and the cell [m]."""

    mesh: MeshTet
    rig: CupRig
    cell: float
    thickness: float | None = None  # a slab's thickness [m] (``slab_mesh``), None for the cup


@dataclasses.dataclass
class Result:
    """The steady solution's integrals. force: on the rod [N], (3,), x outward along the circle's radius, y along
    the motion, z up; torque about the rod's axis [N m] (+z); dissipation [W]; per length for a slab (N/m, N,
    W/m)."""

    force: np.ndarray
    torque: float
    dissipation: float
    iterations: int
    n_velocity: int
    n_pressure: int
    seconds: float
    memory_gib: float
    solver: str
    u: np.ndarray = dataclasses.field(repr=False, default=None)
    basis: Basis = dataclasses.field(repr=False, default=None)
    frame_rate: float = 0.0

    @property
    def drag(self) -> float:
        """The force against the rod's motion [N] (N/m for a slab)."""
        return -float(self.force[1])

    @property
    def radial(self) -> float:
        """The force along the circle's radius, outwards [N] (N/m for a slab)."""
        return float(self.force[0])


def _gmsh_mesh(build, cell: float, growth: float, rig: CupRig, classify) -> tuple[np.ndarray, np.ndarray, dict]:
    """Run gmsh on the OCC model ``build`` makes; nodes (3, N), tets (4, M) and {name: triangles (3, K)}."""
    import gmsh

    gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.add("stir")
        build(gmsh.model.occ)
        gmsh.model.occ.synchronize()
        names = {tag: classify(gmsh.model.getBoundingBox(2, tag)) for _, tag in gmsh.model.getEntities(2)}
        rod = [tag for tag, name in names.items() if name.startswith("rod")]
        field = gmsh.model.mesh.field
        distance = field.add("Distance")
        field.setNumbers(distance, "SurfacesList", rod)
        field.setNumber(distance, "Sampling", 40)
        threshold = field.add("Threshold")
        field.setNumber(threshold, "InField", distance)
        field.setNumber(threshold, "SizeMin", cell)
        field.setNumber(threshold, "SizeMax", growth * cell)
        field.setNumber(threshold, "DistMin", 0.5 * rig.rod_radius)
        field.setNumber(threshold, "DistMax", 2.0 * rig.rod_radius)
        field.setAsBackgroundMesh(threshold)
        for option in ("MeshSizeExtendFromBoundary", "MeshSizeFromPoints", "MeshSizeFromCurvature"):
            gmsh.option.setNumber(f"Mesh.{option}", 0)
        gmsh.option.setNumber("Mesh.Algorithm3D", 10)  # HXT
        gmsh.model.mesh.generate(3)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        index = np.zeros(int(tags.max()) + 1, dtype=np.int64)
        index[tags.astype(np.int64)] = np.arange(len(tags))
        points = coords.reshape(-1, 3).T
        tets = index[gmsh.model.mesh.getElementsByType(4)[1].astype(np.int64)].reshape(-1, 4).T
        triangles: dict[str, list] = {name: [] for name in BOUNDARIES}
        for tag, name in names.items():
            nodes = gmsh.model.mesh.getElementsByType(2, tag)[1].astype(np.int64)
            triangles[name].append(index[nodes].reshape(-1, 3).T)
    finally:
        gmsh.finalize()
    used, tets = np.unique(tets, return_inverse=True)
    tets = tets.reshape(4, -1)
    renumber = np.full(points.shape[1], -1)
    renumber[used] = np.arange(len(used))
    faces = {name: renumber[np.concatenate(parts, axis=1)] if parts else np.zeros((3, 0), dtype=np.int64)
             for name, parts in triangles.items()}
    return np.ascontiguousarray(points[:, used]), np.ascontiguousarray(tets), faces


def _tag(points: np.ndarray, tets: np.ndarray, faces: dict, rig: CupRig, cell: float, thickness=None) -> RigMesh:
    """A MeshTet with the gmsh triangles matched to its facets as named boundaries."""
    corner = points[:, tets]
    volume = np.einsum("ij,ij->j", np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0], axis=0),
                       corner[:, 3] - corner[:, 0])
    tets[[1, 2]] = np.where(volume < 0, tets[[2, 1]], tets[[1, 2]])
    mesh = MeshTet(points, tets)
    key = {tuple(f): i for i, f in enumerate(np.sort(mesh.facets, axis=0).T)}
    boundaries = {name: np.array([key[tuple(f)] for f in np.sort(tri, axis=0).T], dtype=np.int64)
                  for name, tri in faces.items()}
    return RigMesh(mesh.with_boundaries(boundaries), rig, cell, thickness)


def _classifier(rig: CupRig, top: float):
    """Names a gmsh surface by its bounding box (xmin, ymin, zmin, xmax, ymax, zmax)."""
    tol = 1e-3 * rig.cup_radius

    def classify(box) -> str:
        x0, y0, z0, x1, y1, z1 = box
        if abs(z1 - z0) < tol:  # a plane
            if abs(z0) < tol:
                return "bottom"
            if abs(z0 - top) < tol:
                return "surface"
            return "rod_tip"
        return "wall" if x1 - x0 > 2 * rig.rod_radius + 2 * tol else "rod_side"

    return classify


def build_mesh(rig: CupRig = CupRig(), cell: float = 0.003, *, growth: float = 3.0) -> RigMesh:
    """The fluid in the cup, ``cell`` [m] at the rod's side and tip growing to ``growth`` × cell 2a away."""
    a, e, H, g = rig.rod_radius, rig.orbit, rig.fill, rig.gap
    if e + a >= rig.cup_radius or g < 0 or g >= H:
        raise ValueError(f"the rod (radius {a} m on a circle of {e} m, tip {g} m above the bottom) must lie inside "
                         f"the cup (radius {rig.cup_radius} m, fill {H} m)")

    def build(occ):
        cup = occ.addCylinder(0, 0, 0, 0, 0, H, rig.cup_radius)
        start = g if g > 0 else -0.1 * H
        rod = occ.addCylinder(e, 0, start, 0, 0, 1.2 * H - start, a)
        occ.cut([(3, cup)], [(3, rod)])

    return _tag(*_gmsh_mesh(build, cell, growth, rig, _classifier(rig, H)), rig, cell)


def slab_mesh(rig: CupRig = CupRig(), cell: float = 0.003, *, growth: float = 3.0) -> RigMesh:
    """The cup's cross-section extruded by one layer of thickness ``cell`` [m] (tets), for the 2-D force per length
    with the same elements (``slab_force``); the cross-section's cells as in ``build_mesh``."""
    a, e = rig.rod_radius, rig.orbit
    slab = dataclasses.replace(rig, fill=cell, gap=0.0, slip_bottom=True)

    def build(occ):
        disc = occ.addDisk(0, 0, 0, rig.cup_radius, rig.cup_radius)
        hole = occ.addDisk(e, 0, 0, a, a)
        (face, *_), _ = occ.cut([(2, disc)], [(2, hole)])
        occ.extrude([face], 0, 0, cell, numElements=[1])

    return _tag(*_gmsh_mesh(build, cell, growth, slab, _classifier(slab, cell)), slab, cell, thickness=cell)


def _law(law):
    """η(γ̇) [Pa·s] as a numpy function of the shear rate [1/s]: a float is Newtonian, else a diffstir law."""
    if isinstance(law, (int, float)):
        return lambda rate: np.full_like(rate, float(law))
    import torch

    law = law.double()
    return lambda rate: law(torch.from_numpy(np.ascontiguousarray(rate))).detach().numpy()


def _rigid_modes(x: np.ndarray) -> np.ndarray:
    """The six rigid motions at interleaved vector dofs located at ``x`` (3, N): (N, 6)."""
    n = x.shape[1]
    modes = np.zeros((n, 6))
    for k in range(3):
        modes[k::3, k] = 1.0
    for k, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
        modes[i::3, 3 + k] = -x[j, i::3]
        modes[j::3, 3 + k] = x[i, j::3]
    return modes


@dataclasses.dataclass
class _Spaces:
    """Taylor-Hood bases on a rig's mesh, the boundary's velocity dofs and the condensed system's free dofs."""

    velocity: Basis
    pressure: Basis
    rod_dofs: tuple  # the rod's x, y, z velocity dofs
    fixed_u: np.ndarray  # velocity dofs with a Dirichlet value: rod, cup, the slip planes' normal component
    slip: np.ndarray  # the slip planes' u_z dofs
    fixed: np.ndarray  # fixed_u and one pinned pressure dof, in the unknowns (u, p)
    free: np.ndarray
    divergence: sp.spmatrix  # ∫ div(u) q
    surface: np.ndarray  # the pressure dofs on the free surface

    @classmethod
    def of(cls, rig_mesh: RigMesh) -> "_Spaces":
        rig, mesh = rig_mesh.rig, rig_mesh.mesh
        velocity = Basis(mesh, ElementVector(ElementTetP2()), intorder=4)
        pressure = Basis(mesh, ElementTetP1(), intorder=4)
        n_u, n_p = velocity.N, pressure.N
        rod = velocity.get_dofs(np.concatenate([mesh.boundaries["rod_side"], mesh.boundaries["rod_tip"]]))
        rod_dofs = tuple(rod.all(f"u^{k}") for k in (1, 2, 3))
        cup_facets = [mesh.boundaries["wall"]] + ([] if rig.slip_bottom else [mesh.boundaries["bottom"]])
        cup = velocity.get_dofs(np.concatenate(cup_facets))
        slip_facets = [mesh.boundaries["surface"]] + ([mesh.boundaries["bottom"]] if rig.slip_bottom else [])
        slip = velocity.get_dofs(np.concatenate(slip_facets)).all("u^3")
        fixed_u = np.unique(np.concatenate([rod.all(), cup.all(), slip]))
        pin = n_u + int(np.argmin(np.linalg.norm(pressure.doflocs - pressure.doflocs[:, :1], axis=0)))
        fixed = np.concatenate([fixed_u, [pin]])
        free = np.setdiff1d(np.arange(n_u + n_p), fixed)
        divergence = asm(BilinearForm(lambda u, q, w: div(u) * q), velocity, pressure)
        surface = pressure.get_dofs(mesh.boundaries["surface"]).all()
        return cls(velocity, pressure, rod_dofs, fixed_u, slip, fixed, free, divergence, surface)

    @property
    def n_u(self) -> int:
        return self.velocity.N

    def wall(self, frame_rate: float, rod_velocity=(0.0, 0.0), spin: float = 0.0, orbit: float = 0.0) -> np.ndarray:
        """The boundary's velocity relative to the frame turning at ``frame_rate`` Ω [rad/s] at every velocity dof
        (only the fixed ones are used): −Ω ẑ × x on the cup, V + ω ẑ × (x − c) − Ω ẑ × x on the rod (V
        ``rod_velocity`` [m/s] in the frame's axes, ω ``spin`` [rad/s], c = (``orbit``, 0)), 0 normal to the slip
        planes."""
        x = self.velocity.doflocs
        wall = np.zeros(self.n_u)
        wall[0::3], wall[1::3] = frame_rate * x[1, 0::3], -frame_rate * x[0, 1::3]
        rx, ry, rz = self.rod_dofs
        wall[rx] = rod_velocity[0] - spin * x[1, rx] + frame_rate * x[1, rx]
        wall[ry] = rod_velocity[1] + spin * (x[0, ry] - orbit) - frame_rate * x[0, ry]
        wall[rz] = 0.0
        wall[self.slip] = 0.0
        return wall

    def shear_rate(self, u: np.ndarray) -> np.ndarray:
        """γ̇ = sqrt(2 D:D) [1/s] of the velocity ``u`` at the quadrature points (cells, points)."""
        d = sym_grad(self.velocity.interpolate(u))
        return np.sqrt(2.0 * ddot(d, d))

    def surface_pressure_to_zero(self, solution: np.ndarray) -> None:
        """Shift the pressure in ``solution`` so that its mean over the free surface's dofs is zero."""
        solution[self.n_u:] -= solution[self.n_u + self.surface].mean()


@BilinearForm
def _viscous(u, v, w):
    return 2.0 * w["eta"] * ddot(sym_grad(u), sym_grad(v))


@BilinearForm
def _weighted_mass(p, q, w):
    return p * q / w["eta"]


@BilinearForm
def _mass(u, v, w):
    return w["rho"] * dot(u, v)


def solve(rig_mesh: RigMesh, law=1.0, speed: float = 0.1, *, motion: str = "stir", density: float = 1000.0,
          inertia: bool = False, tol: float = 1e-4, max_iterations: int = 60, solver: str = "auto",
          relaxation: float = 1.0, verbose: bool = False) -> Result:
    """The steady flow and the rod's force, torque and dissipation.

    Args:
        rig_mesh: ``build_mesh`` or ``slab_mesh`` (then per length: divided by the slab's thickness).
        law: η [Pa·s] (Newtonian) or a ``diffstir.rheology`` law.
        speed: U [m/s]: the rod's speed on its circle ("stir"), its speed along +y ("translate", Stokes only, the
            cup still), or its surface speed ω a ("spin": the rod turns about its own axis at ω, Stokes only).
        density: ρ [kg/m³], used with ``inertia``.
        inertia: convection, Coriolis and centrifugal terms (Picard); else Stokes.
        tol: the fixed point's relative change in the velocity and the drag that ends the iteration.
        solver: "direct", "krylov" or "auto" (direct up to ``DIRECT_LIMIT`` unknowns).
        relaxation: θ of η ← η_old^(1−θ) η(γ̇)^θ (1: plain Picard).
    """
    start = time.time()
    rig, mesh = rig_mesh.rig, rig_mesh.mesh
    a, e = rig.rod_radius, rig.orbit
    if motion == "stir":
        if e <= 0:
            raise ValueError("a stir needs the rod off the cup's axis (rig.orbit > 0 m)")
        frame_rate, rod_velocity, spin = speed / e, np.array([0.0, speed]), 0.0
    elif motion == "translate":
        frame_rate, rod_velocity, spin = 0.0, np.array([0.0, speed]), 0.0
    elif motion == "spin":
        frame_rate, rod_velocity, spin = 0.0, np.zeros(2), speed / a
    else:
        raise ValueError(f"motion must be 'stir', 'translate' or 'spin', got {motion!r}")
    if inertia and motion != "stir":
        raise ValueError("inertia needs a steady stir (motion='stir')")
    viscosity = _law(law)
    spaces = _Spaces.of(rig_mesh)
    velocity, pressure, n_u, free, fixed, fixed_u = (spaces.velocity, spaces.pressure, spaces.n_u, spaces.free,
                                                     spaces.fixed, spaces.fixed_u)
    n_p = pressure.N
    x = velocity.doflocs
    rx, ry, rz = rod_dofs = spaces.rod_dofs
    wall = spaces.wall(frame_rate, rod_velocity, spin, e)
    divergence = spaces.divergence

    @BilinearForm
    def oseen(u, v, w):  # ρ ((w·∇) u + 2 Ω ẑ × u) · v
        advection = np.einsum("ij...,j...->i...", grad(u), w["w"])
        coriolis = 2 * frame_rate * np.stack([-u[1], u[0], 0 * u[2]])
        return density * dot(advection + coriolis, v)

    centrifugal = np.zeros(n_u)
    if inertia:
        centrifugal = asm(LinearForm(lambda v, w: density * frame_rate**2 * (w.x[0] * v[0] + w.x[1] * v[1])),
                          velocity)
    rhs = np.concatenate([centrifugal, np.zeros(n_p)])

    shear_rate = spaces.shear_rate
    u = wall.copy()
    eta = np.full((mesh.t.shape[1], velocity.X.shape[-1]), float(viscosity(np.array([speed / a]))[0]))
    newtonian = isinstance(law, (int, float))
    solution = np.zeros(n_u + n_p)
    drag_old, used, iterations = np.inf, "", 0
    peak = 0.0
    for iterations in range(1, max_iterations + 1):
        if not newtonian and iterations > 1:
            eta = eta ** (1 - relaxation) * viscosity(shear_rate(u)) ** relaxation
        stiffness = asm(_viscous, velocity, eta=eta)
        momentum = stiffness
        if inertia:
            momentum = stiffness + asm(oseen, velocity, w=velocity.interpolate(u))
        matrix = bmat([[momentum, -divergence.T], [-divergence, None]], "csr")
        previous = solution.copy()
        solution[fixed] = np.concatenate([wall[fixed_u], [0.0]])
        system = matrix[free][:, free]
        b = rhs[free] - matrix[free][:, fixed] @ solution[fixed]
        method = solver if solver != "auto" else ("direct" if len(free) <= DIRECT_LIMIT else "krylov")
        if method == "direct":
            solution[free] = splu(system.tocsc(), permc_spec="COLAMD").solve(b)
            used = "SuperLU"
        else:
            mass = asm(_weighted_mass, pressure, eta=eta)
            guess = None if iterations == 1 else previous[free]
            solution[free], used = _krylov(system, b, momentum, mass, free, fixed_u, n_u, velocity, inertia, guess,
                                           verbose)
        peak = max(peak, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20)
        change = np.linalg.norm(solution[:n_u] - u) / max(np.linalg.norm(solution[:n_u]), 1e-300)
        u = solution[:n_u].copy()
        drag = float((matrix[ry] @ solution - rhs[ry]).sum())  # the rod's force on the fluid along y: −F_y
        if verbose:
            print(f"  iteration {iterations}: drag {drag:.6g}, change {change:.2e} ({used}, "
                  f"{time.time() - start:.0f} s)", flush=True)
        if (newtonian and not inertia) or (change < tol and abs(drag - drag_old) <= tol * abs(drag)):
            break
        drag_old = drag
    else:
        raise RuntimeError(f"the fixed point did not converge in {max_iterations} iterations (last relative change "
                           f"{change:.1e} > tol {tol:g}); try relaxation < 1 or more iterations")
    # the pressure's mean on the free surface is the zero of pressure (the lid's normal stress)
    spaces.surface_pressure_to_zero(solution)
    residual = matrix @ solution - rhs  # the rod's force on the fluid at its dofs
    force = -np.array([residual[d].sum() for d in rod_dofs])
    torque = -float(((x[0, ry] - e) * residual[ry]).sum() - (x[1, rx] * residual[rx]).sum())
    gamma = shear_rate(u)
    dissipation = float(Functional(lambda w: w["eta"] * w["g"] ** 2).assemble(velocity, eta=eta, g=gamma))
    scale = 1.0 / rig_mesh.thickness if rig_mesh.thickness else 1.0
    return Result(force * scale, torque * scale, dissipation * scale, iterations, n_u, n_p, time.time() - start,
                  peak, used, u, velocity, frame_rate)


@dataclasses.dataclass
class History:
    """The stir in time. times [s] (S,); force on the rod [N] (S, 3) in the lab (x, y horizontal, z up) and
    frame_force [N] (S, 3) in the turning frame (x outward along the circle's radius, y along +θ, z up); angle θ
    [rad] (S,) of the rod's axis about the cup's axis; the run's unknowns, LU factorisations, seconds and peak
    memory [GiB]."""

    times: np.ndarray
    force: np.ndarray
    frame_force: np.ndarray
    angle: np.ndarray
    n_velocity: int
    n_pressure: int
    factorisations: int
    seconds: float
    memory_gib: float


REFACTOR_BELOW = 0.5
"""A frozen viscosity is refactorised when η(γ̇*) falls below this share of it on most (the median) of the
quadrature points (accuracy), or exceeds it anywhere (stability: SBDF2 with the excess explicit is stable only up
to η(γ̇*) < 4/3 η_f)."""
REFACTOR_MARGIN = 1.5
"""η_f = this × η(γ̇*) at a factorisation, so that a slowly thickening region does not force one every step."""


def stir_history(rig_mesh: RigMesh, law, times: np.ndarray, angle: np.ndarray, rate: np.ndarray,
                 acceleration: np.ndarray, *, density: float = 1000.0, verbose: bool = False) -> History:
    """The stir in time from rest: the rod on its circle (radius ``rig_mesh.rig.orbit``) at angle θ(t), SBDF2 steps
    in the turning frame (see the module docstring).

    Args:
        rig_mesh: ``build_mesh`` (a cup) or ``slab_mesh`` (per length: N/m).
        law: η [Pa·s] (Newtonian) or a ``diffstir.rheology`` law.
        times: t_n [s] (S,), uniformly spaced, from the rest at t_0.
        angle, rate, acceleration: θ [rad], Ω = θ' [rad/s] and Ω' [rad/s²] at ``times``; Ω = 0 at t_0.
        density: ρ [kg/m³].
    """
    start = time.time()
    rig, mesh = rig_mesh.rig, rig_mesh.mesh
    times, angle, rate, acceleration = (np.asarray(v, dtype=np.float64) for v in (times, angle, rate, acceleration))
    if times.ndim != 1 or times.size < 3 or not (angle.shape == rate.shape == acceleration.shape == times.shape):
        raise ValueError("times, angle, rate and acceleration must be 1-D arrays of one length >= 3")
    dt = float(times[1] - times[0])
    if not (dt > 0 and np.allclose(np.diff(times), dt, rtol=1e-6, atol=0.0)):
        raise ValueError("times must be uniformly spaced and increasing")
    if rig.orbit <= 0:
        raise ValueError("a stir needs the rod off the cup's axis (rig.orbit > 0 m)")
    viscosity = _law(law)
    newtonian = isinstance(law, (int, float))
    spaces = _Spaces.of(rig_mesh)
    velocity, n_u, free, fixed, fixed_u = spaces.velocity, spaces.n_u, spaces.free, spaces.fixed, spaces.fixed_u
    n_p = spaces.pressure.N
    e = rig.orbit

    mass = asm(_mass, velocity, rho=density)
    centrifugal = asm(LinearForm(lambda v, w: density * (w.x[0] * v[0] + w.x[1] * v[1])), velocity)  # × Ω²
    euler = asm(LinearForm(lambda v, w: density * (-w.x[1] * v[0] + w.x[0] * v[1])), velocity)  # × Ω'

    @LinearForm
    def convection(v, w):  # ρ ((u·∇) u + 2 Ω ẑ × u) · v
        u, g = w["u"], grad(w["u"])
        advection = np.einsum("ij...,j...->i...", g, u)
        coriolis = 2 * w["rate"] * np.stack([-u[1], u[0], 0 * u[2]])
        return density * dot(advection + coriolis, v)

    @LinearForm
    def viscous_excess(v, w):  # 2 (η(γ̇*) − η_f) D(u*) : D(v)
        return 2.0 * w["excess"] * ddot(sym_grad(w["u"]), sym_grad(v))

    def lu(eta):
        momentum = 1.5 / dt * mass + asm(_viscous, velocity, eta=eta)
        matrix = bmat([[momentum, -spaces.divergence.T], [-spaces.divergence, None]], "csr")
        return matrix, splu(matrix[free][:, free].tocsc(), permc_spec="COLAMD"), matrix[free][:, fixed]

    cells_points = (mesh.t.shape[1], velocity.X.shape[-1])
    eta_frozen = np.broadcast_to(viscosity(np.zeros(1)), cells_points).copy()
    matrix, factor, coupling = lu(eta_frozen)
    factorisations = 1
    rod_rows = [matrix[d] for d in spaces.rod_dofs]
    u_prev = np.zeros(n_u)
    u_now = np.zeros(n_u)
    n_prev = np.zeros(n_u)
    n_now = np.zeros(n_u)
    solution = np.zeros(n_u + n_p)
    frame_force = np.zeros((times.size, 3))
    peak = 0.0
    for step in range(1, times.size):
        extrapolated = 2.0 * u_now - u_prev
        excess = np.zeros(n_u)
        if not newtonian:
            eta_star = viscosity(spaces.shear_rate(extrapolated))
            share = eta_star / eta_frozen
            if share.max() > 1.0 or np.median(share) < REFACTOR_BELOW:
                eta_frozen = REFACTOR_MARGIN * eta_star
                matrix, factor, coupling = lu(eta_frozen)
                rod_rows = [matrix[d] for d in spaces.rod_dofs]
                factorisations += 1
            excess = asm(viscous_excess, velocity, excess=eta_star - eta_frozen,
                         u=velocity.interpolate(extrapolated))
        omega, omega_dot = rate[step], acceleration[step]
        rhs = np.zeros(n_u + n_p)
        rhs[:n_u] = (mass @ (4.0 * u_now - u_prev) / (2.0 * dt) - (2.0 * n_now - n_prev)
                     + omega**2 * centrifugal - omega_dot * euler - excess)
        wall = spaces.wall(omega, (0.0, omega * e), 0.0, e)
        solution[fixed] = np.concatenate([wall[fixed_u], [0.0]])
        solution[free] = factor.solve(rhs[free] - coupling @ solution[fixed])
        spaces.surface_pressure_to_zero(solution)
        frame_force[step] = [-float((row @ solution - rhs[d]).sum()) for row, d in zip(rod_rows, spaces.rod_dofs)]
        u_prev, u_now = u_now, solution[:n_u].copy()
        n_prev, n_now = n_now, asm(convection, velocity, u=velocity.interpolate(u_now), rate=omega)
        if verbose and (step % 100 == 0 or step == times.size - 1):
            peak = max(peak, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20)
            print(f"  t = {times[step]:.3f} s: frame force ({frame_force[step, 0]:+.5g}, {frame_force[step, 1]:+.5g})"
                  f" N, {factorisations} factorisations, {time.time() - start:.0f} s", flush=True)
    peak = max(peak, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20)
    scale = 1.0 / rig_mesh.thickness if rig_mesh.thickness else 1.0
    frame_force *= scale
    cos, sin = np.cos(angle), np.sin(angle)
    force = np.stack([cos * frame_force[:, 0] - sin * frame_force[:, 1],
                      sin * frame_force[:, 0] + cos * frame_force[:, 1], frame_force[:, 2]], axis=1)
    return History(times, force, frame_force, angle, n_u, n_p, factorisations, time.time() - start, peak)


def _krylov(system, b, stiffness, mass, free, fixed_u, n_u, velocity, nonsymmetric, guess, verbose):
    """Solve the condensed saddle-point ``system`` (velocity dofs first) by preconditioned MINRES, or GMRES with a
    block upper-triangular preconditioner when ``nonsymmetric``: a smoothed-aggregation V-cycle on the viscous
    block ``stiffness`` (its fixed rows and columns replaced by the identity, 3×3 blocks, rigid modes) and the
    diagonal of the 1/η-weighted pressure ``mass``."""
    import pyamg

    keep = np.ones(n_u)
    keep[fixed_u] = 0.0
    mask = sp.diags(keep)
    viscous = (mask @ stiffness @ mask + sp.diags(1.0 - keep)).tobsr(blocksize=(3, 3))
    hierarchy = pyamg.smoothed_aggregation_solver(viscous, B=_rigid_modes(velocity.doflocs), max_coarse=2000,
                                                  symmetry="nonsymmetric" if nonsymmetric else "hermitian",
                                                  strength=("symmetric", {"theta": 0.0}), smooth="jacobi")
    cycle = hierarchy.aspreconditioner(cycle="V")
    free_u = free[free < n_u]
    n_fu = len(free_u)
    scale = 1.0 / mass.diagonal()[free[n_fu:] - n_u]
    full = np.zeros(n_u)
    coupling = system[:n_fu, n_fu:]

    def velocity_block(r):
        full[free_u] = r
        return (cycle @ full)[free_u]

    def apply(r):
        z_p = -scale * r[n_fu:] if nonsymmetric else scale * r[n_fu:]
        z_u = velocity_block(r[:n_fu] - coupling @ z_p) if nonsymmetric else velocity_block(r[:n_fu])
        return np.concatenate([z_u, z_p])

    preconditioner = LinearOperator(system.shape, apply)
    count = [0]

    def tick(*_):
        count[0] += 1

    if nonsymmetric:
        out, info = gmres(system, b, x0=guess, rtol=1e-10, restart=200, maxiter=20, M=preconditioner,
                          callback=tick, callback_type="pr_norm")
        name = "GMRES"
    else:
        out, info = minres(system, b, x0=guess, rtol=1e-10, maxiter=3000, M=preconditioner, callback=tick)
        name = "MINRES"
    if info != 0:
        raise RuntimeError(f"{name} did not converge in {count[0]} iterations (info {info})")
    if verbose:
        print(f"    {name}: {count[0]} iterations, AMG {len(hierarchy.levels)} levels", flush=True)
    return out, f"{name}+AMG ({count[0]} it.)"


def slab_force(rig: CupRig = CupRig(), cell: float = 0.003, law=1.0, speed: float = 0.1, *, growth: float = 3.0,
               **options) -> Result:
    """The 2-D stir of the rig's cross-section per unit length (N/m, N, W/m) with the same elements and solver: a
    one-layer slab with slip top and bottom (``slab_mesh``); ``options`` as for ``solve``. F_3D / (F'_2D h) is the
    slice's geometric error."""
    return solve(slab_mesh(rig, cell, growth=growth), law, speed, **options)


