"""A 3-D reference for the steady stir: Stokes or Navier-Stokes by finite elements in a real cup (docs/validation.md).

The rig: a cup of radius R [m] with a flat bottom, fluid to depth H [m] under a flat free surface, a rod of radius
a [m] immersed to depth h = H − g (its flat tip a gap g above the bottom), its axis on a circle of radius e about the
cup's axis, moving along that circle at speed U [m/s] without spinning in the lab.

Method. In the frame that turns with the rod at Ω = U / e (the rod's centre c = (e, 0, ·), moving along +y), steady
stirring is a steady problem in a fixed domain. The relative velocity u and the pressure p [Pa] solve

    ρ (u·∇u + 2 Ω ẑ × u) = −∇p + ∇·(2 η(γ̇) D(u)) + ρ Ω² (x, y, 0),    ∇·u = 0,    γ̇ = sqrt(2 D:D),

with u = −Ω ẑ × x on the cup's wall and bottom (at rest in the lab), u = −Ω ẑ × (x − c) on the rod's side and tip
(translating in the lab without spin), and on the free surface u_z = 0 with zero shear traction (a rigid rotation
has no shear, so the condition is the same in both frames). Without ``inertia`` the left side is dropped (Stokes,
for Re = ρ U 2a / η ≪ 1); with it the convection and the Coriolis term are linearised about the last iterate
(Picard / Oseen), and the centrifugal term is a body force. A generalized-Newtonian law η(γ̇) (any
``diffstir.rheology`` law, evaluated in float64) is updated at the quadrature points by the same fixed-point
iteration. Taylor-Hood elements (P2 velocity, P1 pressure, scikit-fem) on an unstructured tetrahedral mesh from
gmsh (OCC: cup cylinder minus rod cylinder, cells of ``cell`` [m] at the rod growing to ``growth`` times that 2a away).

The force on the rod is the consistent reaction: the residual of the discrete momentum equation at the rod's
velocity degrees of freedom, with the pressure's mean on the free surface set to zero (no gravity: the hydrostatic
part is not in it). Forces are reported in the lab at the instant the rod passes (e, 0): x outward along the
circle's radius, y along the motion, z up; the drag is −F_y. The torque is about the rod's own axis [N m], the
dissipation ∫ 2 η D:D dV [W] (which equals the drag times U in Stokes flow).

Linear solver: SuperLU on the condensed saddle-point system up to ``DIRECT_LIMIT`` unknowns; above, MINRES (GMRES
with inertia) preconditioned by a smoothed-aggregation AMG V-cycle on the viscous block (pyamg, the six rigid
modes as near null space) and the pressure mass matrix weighted by 1/η (diagonal). Costs on a 2-core x86-64 VM,
24 GiB, are in docs/validation.md ("3-D reference (finite elements)").

    python scripts/stir_reference_3d.py --viscosity 1 --speed 0.1 --cell 0.003 --out ref3d/  # the paper's rig
    python scripts/stir_reference_3d.py --law power_law --param k=1 --param n=0.6 --out ref3d/
    python scripts/stir_reference_3d.py --check margules         # margules, translate, eccentric, power_law,
                                                                 # convergence, transient2d
Needs scikit-fem, gmsh and pyamg (``pip install -e ".[validation]"``).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import resource
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, gmres, minres, splu
from skfem import (Basis, BilinearForm, ElementTetP1, ElementTetP2, ElementVector, Functional, LinearForm, MeshTet,
                   asm, bmat)
from skfem.helpers import ddot, div, dot, grad, sym_grad

DIRECT_LIMIT = 40_000
"""Unknowns (velocity and pressure, after the boundary conditions) up to which the sparse direct solver is used."""

BOUNDARIES = ("wall", "bottom", "surface", "rod_side", "rod_tip")


@dataclasses.dataclass(frozen=True)
class Rig:
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


@dataclasses.dataclass
class RigMesh:
    """A tetrahedral mesh of the fluid, its boundary facets by name (``BOUNDARIES``), the rig and the cell [m]."""

    mesh: MeshTet
    rig: Rig
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


def _gmsh_mesh(build, cell: float, growth: float, rig: Rig, classify) -> tuple[np.ndarray, np.ndarray, dict]:
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


def _tag(points: np.ndarray, tets: np.ndarray, faces: dict, rig: Rig, cell: float, thickness=None) -> RigMesh:
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


def _classifier(rig: Rig, top: float):
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


def build_mesh(rig: Rig = Rig(), cell: float = 0.003, *, growth: float = 3.0) -> RigMesh:
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


def slab_mesh(rig: Rig = Rig(), cell: float = 0.003, *, growth: float = 3.0) -> RigMesh:
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

    velocity = Basis(mesh, ElementVector(ElementTetP2()), intorder=4)
    pressure = Basis(mesh, ElementTetP1(), intorder=4)
    n_u, n_p = velocity.N, pressure.N
    x = velocity.doflocs
    rod_facets = np.concatenate([mesh.boundaries["rod_side"], mesh.boundaries["rod_tip"]])
    rod = velocity.get_dofs(rod_facets)
    rod_dofs = [rod.all(f"u^{k}") for k in (1, 2, 3)]
    cup_facets = [mesh.boundaries["wall"]] + ([] if rig.slip_bottom else [mesh.boundaries["bottom"]])
    cup = velocity.get_dofs(np.concatenate(cup_facets))
    slip_facets = [mesh.boundaries["surface"]] + ([mesh.boundaries["bottom"]] if rig.slip_bottom else [])
    slip = velocity.get_dofs(np.concatenate(slip_facets)).all("u^3")
    fixed_u = np.unique(np.concatenate([rod.all(), cup.all(), slip]))
    # the wall velocities relative to the turning frame, at every dof (only the fixed ones are used)
    wall = np.zeros(n_u)
    wall[0::3], wall[1::3] = frame_rate * x[1, 0::3], -frame_rate * x[0, 1::3]
    rx, ry, rz = rod_dofs  # V + ω ẑ × (x − c) − Ω ẑ × x
    wall[rx] = rod_velocity[0] - spin * x[1, rx] + frame_rate * x[1, rx]
    wall[ry] = rod_velocity[1] + spin * (x[0, ry] - e) - frame_rate * x[0, ry]
    wall[rz] = 0.0
    wall[slip] = 0.0
    pin = n_u + int(np.argmin(np.linalg.norm(pressure.doflocs - pressure.doflocs[:, :1], axis=0)))
    fixed = np.concatenate([fixed_u, [pin]])
    free = np.setdiff1d(np.arange(n_u + n_p), fixed)

    divergence = asm(BilinearForm(lambda u, q, w: div(u) * q), velocity, pressure)

    @BilinearForm
    def viscous(u, v, w):
        return 2.0 * w["eta"] * ddot(sym_grad(u), sym_grad(v))

    @BilinearForm
    def oseen(u, v, w):  # ρ ((w·∇) u + 2 Ω ẑ × u) · v
        advection = np.einsum("ij...,j...->i...", grad(u), w["w"])
        coriolis = 2 * frame_rate * np.stack([-u[1], u[0], 0 * u[2]])
        return density * dot(advection + coriolis, v)

    @BilinearForm
    def weighted_mass(p, q, w):
        return p * q / w["eta"]

    centrifugal = np.zeros(n_u)
    if inertia:
        centrifugal = asm(LinearForm(lambda v, w: density * frame_rate**2 * (w.x[0] * v[0] + w.x[1] * v[1])),
                          velocity)
    rhs = np.concatenate([centrifugal, np.zeros(n_p)])

    def shear_rate(u):
        d = sym_grad(velocity.interpolate(u))
        return np.sqrt(2.0 * ddot(d, d))

    u = wall.copy()
    eta = np.full((mesh.t.shape[1], velocity.X.shape[-1]), float(viscosity(np.array([speed / a]))[0]))
    newtonian = isinstance(law, (int, float))
    solution = np.zeros(n_u + n_p)
    drag_old, used, iterations = np.inf, "", 0
    peak = 0.0
    for iterations in range(1, max_iterations + 1):
        if not newtonian and iterations > 1:
            eta = eta ** (1 - relaxation) * viscosity(shear_rate(u)) ** relaxation
        stiffness = asm(viscous, velocity, eta=eta)
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
            mass = asm(weighted_mass, pressure, eta=eta)
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
    top = pressure.get_dofs(mesh.boundaries["surface"]).all()
    solution[n_u:] -= solution[n_u + top].mean()
    residual = matrix @ solution - rhs  # the rod's force on the fluid at its dofs
    force = -np.array([residual[d].sum() for d in rod_dofs])
    torque = -float(((x[0, ry] - e) * residual[ry]).sum() - (x[1, rx] * residual[rx]).sum())
    gamma = shear_rate(u)
    dissipation = float(Functional(lambda w: w["eta"] * w["g"] ** 2).assemble(velocity, eta=eta, g=gamma))
    scale = 1.0 / rig_mesh.thickness if rig_mesh.thickness else 1.0
    return Result(force * scale, torque * scale, dissipation * scale, iterations, n_u, n_p, time.time() - start,
                  peak, used, u, velocity, frame_rate)


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


def slab_force(rig: Rig = Rig(), cell: float = 0.003, law=1.0, speed: float = 0.1, *, growth: float = 3.0,
               **options) -> Result:
    """The 2-D stir of the rig's cross-section per unit length (N/m, N, W/m) with the same elements and solver: a
    one-layer slab with slip top and bottom (``slab_mesh``); ``options`` as for ``solve``. F_3D / (F'_2D h) is the
    slice's geometric error."""
    return solve(slab_mesh(rig, cell, growth=growth), law, speed, **options)


def couette_torque(viscosity: float, spin: float, a: float, b: float) -> float:
    """Margules: torque per length [N] on a rod of radius a [m] spinning at ω [rad/s] centred in a still cup of
    radius b [m], 4π η ω a² b² / (b² − a²)."""
    return 4 * math.pi * viscosity * spin * a**2 * b**2 / (b**2 - a**2)


def power_law_couette_torque(k: float, n: float, spin: float, a: float, b: float) -> float:
    """The same for η = k γ̇^(n−1) [k in Pa sⁿ]: 2π k a² [2ω / (n (1 − (a/b)^(2/n)))]ⁿ [N]."""
    return 2 * math.pi * k * a**2 * (2 * spin / (n * (1 - (a / b) ** (2 / n)))) ** n


def translating_rod_drag(viscosity: float, speed: float, a: float, b: float) -> float:
    """Exact 2-D Stokes drag per length [N/m] on a rod translating at U [m/s] at the centre of a still cup:
    4π η U / [ln(b/a) − (b² − a²)/(b² + a²)]."""
    return 4 * math.pi * viscosity * speed / (math.log(b / a) - (b**2 - a**2) / (b**2 + a**2))


def long_rod(rig: Rig, cell: float, length: float | None = None) -> Rig:
    """The rig's cross-section as a rod through the whole depth ``length`` [m] (4 cells by default) with slip ends:
    its flow is the 2-D one."""
    return dataclasses.replace(rig, fill=length or 4 * cell, gap=0.0, slip_bottom=True)


def richardson(values, ratio: float) -> tuple[float, float]:
    """The extrapolated value and observed order p from three values on cells shrinking by ``ratio`` each."""
    f1, f2, f3 = values
    order = math.log(abs((f1 - f2) / (f3 - f2 if f3 != f2 else 1e-300))) / math.log(ratio)
    return f3 + (f3 - f2) / (ratio**order - 1), order


def check(name: str, cell: float = 0.003, viscosity: float = 1.0, speed: float = 0.01, verbose: bool = False) -> list:
    """Rows (check, computed, closed form or reference, ratio) of one named check; per length for the long rods."""
    paper = Rig()
    a, b = paper.rod_radius, paper.cup_radius
    if name == "margules":
        rig = long_rod(dataclasses.replace(paper, orbit=0.0), cell)
        result = solve(build_mesh(rig, cell), viscosity, speed, motion="spin", verbose=verbose)
        exact = couette_torque(viscosity, speed / a, a, b)
        return [(f"Margules torque per length, cell {cell * 1e3:g} mm [N]", -result.torque / rig.fill, exact,
                 result)]
    if name == "power_law":
        from diffstir.rheology import PowerLaw

        rig = long_rod(dataclasses.replace(paper, orbit=0.0), cell)
        law = PowerLaw(k=viscosity, n=0.6, shear_rate_reg=1e-6)
        result = solve(build_mesh(rig, cell), law, speed, motion="spin", tol=1e-7, verbose=verbose)
        exact = power_law_couette_torque(viscosity, 0.6, speed / a, a, b)
        return [(f"power-law (n = 0.6) Couette torque per length, cell {cell * 1e3:g} mm [N]",
                 -result.torque / rig.fill, exact, result)]
    if name == "translate":
        rig = long_rod(dataclasses.replace(paper, orbit=0.0), cell)
        result = solve(build_mesh(rig, cell), viscosity, speed, motion="translate", verbose=verbose)
        exact = translating_rod_drag(viscosity, speed, a, b)
        return [(f"centred translating rod drag per length, cell {cell * 1e3:g} mm [N/m]", result.drag / rig.fill,
                 exact, result)]
    if name == "eccentric":
        rig = long_rod(paper, cell)
        result = solve(build_mesh(rig, cell), viscosity, speed, verbose=verbose)
        reference = stokes_2d(paper, viscosity, speed)
        slab = slab_force(paper, cell, viscosity, speed)
        return [(f"eccentric (e = 30 mm) rod drag per length, Stokes, cell {cell * 1e3:g} mm, against "
                 f"scripts/stir_reference.py [N/m]", result.drag / rig.fill, reference, result),
                ("the same, slab (slab_force) against scripts/stir_reference.py [N/m]", slab.drag, reference, slab)]
    raise ValueError(f"unknown check {name!r}")


def stokes_2d(rig: Rig, viscosity: float, speed: float, mesh: tuple[int, int] = (256, 48)) -> float:
    """The steady Stokes drag per length [N/m] of the rig's cross-section from the 2-D reference
    (scripts/stir_reference.py, its bipolar mesh): three steps at a negligible density with the orbit's rate held."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from stir_reference import StirReference

    reference = StirReference(rig.rod_radius, rig.cup_radius, rig.orbit, 1e-9, viscosity, n_around=mesh[0],
                              n_across=mesh[1])
    rate = speed / rig.orbit
    out = reference.run(np.linspace(0.0, 0.003, 4), lambda t: rate, lambda t: 0.0, lambda t: 0.0)
    return -float(out[-1, 1])


def convergence(rig: Rig = Rig(), cells=(0.0045, 0.003, 0.002), law=1.0, speed: float = 0.1,
                verbose: bool = False) -> list:
    """The steady stir on meshes whose cells shrink by a constant ratio: rows (cell, result), then the Richardson
    extrapolation of the drag and its observed order."""
    rows = [(cell, solve(build_mesh(rig, cell), law, speed, verbose=verbose)) for cell in cells]
    ratio = cells[0] / cells[1]
    extrapolated, order = richardson([r.drag for _, r in rows], ratio)
    return rows, extrapolated, order


def _locate(mesh: MeshTet, points: np.ndarray, candidates: int = 100) -> tuple[np.ndarray, np.ndarray]:
    """The tet holding each of the (3, m) points among the ``candidates`` nearest by centroid, and whether one
    does."""
    from scipy.spatial import cKDTree

    corner = mesh.p[:, mesh.t]  # (3, 4, n)
    edges = np.transpose(corner[:, 1:] - corner[:, :1], (2, 0, 1))  # (n, 3, 3): columns v_k − v_0
    inverse = np.linalg.inv(edges)
    near = cKDTree(corner.mean(axis=1).T).query(points.T, min(candidates, mesh.t.shape[1]))[1]  # (m, k)
    local = np.einsum("mkij,jmk->imk", inverse[near], points[:, :, None] - corner[:, 0][:, near])
    inside = (local >= -1e-9).all(axis=0) & (local.sum(axis=0) <= 1 + 1e-9)
    return near[np.arange(len(near)), inside.argmax(axis=1)], inside.any(axis=1)


def _probe(basis: Basis, points: np.ndarray, cells: np.ndarray) -> sp.coo_matrix:
    """The matrix that evaluates a scalar ``basis``'s function at the (3, m) ``points`` in ``cells``."""
    local = basis.mapping.invF(points[:, :, np.newaxis], tind=cells)
    phis = np.array([basis.elem.gbasis(basis.mapping, local, k, tind=cells)[0] for k in range(basis.Nbfun)])
    rows = np.tile(np.arange(points.shape[1]), basis.Nbfun)
    return sp.coo_matrix((phis.ravel(), (rows, basis.element_dofs[:, cells].ravel())),
                         shape=(points.shape[1], basis.N)).tocsr()


def slices(result: Result, rig_mesh: RigMesh, path: str | Path, n: int = 120) -> None:
    """Plot the lab-frame speed |u + Ω ẑ × x| [m/s] on the horizontal slice at mid-immersion and on the vertical
    plane through the cup's axis and the rod's axis, into ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rig = rig_mesh.rig
    R, a, e, H = rig.cup_radius, rig.rod_radius, rig.orbit, rig.fill
    parts = result.basis.split(result.u)
    shrink = 1 - 1e-3

    def sample(points, inside):  # the lab-frame speed at (3, m) points, NaN outside the fluid
        out = np.full(points.shape[1], np.nan)
        good = np.flatnonzero(inside)
        cells, found = _locate(rig_mesh.mesh, points[:, good])
        good, cells = good[found], cells[found]
        values = [_probe(b, points[:, good], cells) @ u for u, b in parts]
        values[0] = values[0] - result.frame_rate * points[1, good]
        values[1] = values[1] + result.frame_rate * points[0, good]
        out[good] = np.sqrt(sum(v**2 for v in values))
        return out

    fig, axes = plt.subplots(1, 2, figsize=(11, 5), gridspec_kw={"width_ratios": [1, 1.3]})
    s = np.linspace(-R * shrink, R * shrink, n)
    X, Y = np.meshgrid(s, s)
    z_mid = H - 0.5 * rig.immersion
    points = np.stack([X.ravel(), Y.ravel(), np.full(X.size, z_mid)])
    inside = (np.hypot(X, Y).ravel() < R * shrink) & (np.hypot(X - e, Y).ravel() > a / shrink)
    image = axes[0].pcolormesh(X * 1e3, Y * 1e3, sample(points, inside).reshape(X.shape), shading="auto")
    axes[0].set(aspect="equal", xlabel="x [mm]", ylabel="y [mm] (rod moving +y)",
                title=f"|u| at z = {z_mid * 1e3:.0f} mm (mid-immersion)")
    fig.colorbar(image, ax=axes[0], label="speed in the lab [m/s]")
    zs = np.linspace(H * 1e-3, H * shrink, n)
    X, Z = np.meshgrid(s, zs)
    points = np.stack([X.ravel(), np.zeros(X.size), Z.ravel()])
    in_rod = (np.abs(X - e) < a / shrink) & (Z > rig.gap * shrink)
    image = axes[1].pcolormesh(X * 1e3, Z * 1e3, sample(points, ~in_rod.ravel()).reshape(X.shape), shading="auto")
    axes[1].set(aspect="equal", xlabel="x [mm]", ylabel="z [mm]", title="|u| on the plane y = 0 (cup and rod axes)")
    fig.colorbar(image, ax=axes[1], label="speed in the lab [m/s]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _parse_law(name: str, params: list[str], viscosity: float | None):
    if name == "newtonian":
        if viscosity is None:
            raise SystemExit("--viscosity [Pa·s] is needed for the Newtonian law")
        return viscosity
    from diffstir.rheology import make_law

    values = {}
    for item in params:
        key, _, value = item.partition("=")
        values[key] = float(value)
    return make_law(name, **values)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--viscosity", type=float, help="η [Pa·s] (Newtonian)")
    parser.add_argument("--law", default="newtonian", help="a diffstir.rheology law name (power_law, carreau, cross, "
                        "herschel_bulkley, ...)")
    parser.add_argument("--param", action="append", default=[], help="a law's parameter, NAME=VALUE in SI")
    parser.add_argument("--speed", type=float, default=0.1, help="the rod's speed on its circle U [m/s]")
    parser.add_argument("--density", type=float, default=1000.0, help="ρ [kg/m³]")
    parser.add_argument("--inertia", action="store_true", help="Navier-Stokes in the turning frame (Picard)")
    for name, default, unit in (("cup-radius", 0.0475, "m"), ("fill", 0.125, "m"), ("rod-radius", 0.0125, "m"),
                                ("gap", 0.020, "m"), ("orbit", 0.030, "m")):
        parser.add_argument(f"--{name}", type=float, default=default, help=f"[{unit}] (default: the paper's rig)")
    parser.add_argument("--cell", type=float, default=0.003, help="the cells' size at the rod [m]")
    parser.add_argument("--growth", type=float, default=3.0, help="far cells / cells at the rod")
    parser.add_argument("--solver", choices=("auto", "direct", "krylov"), default="auto")
    parser.add_argument("--slab", action="store_true", help="the 2-D cross-section per length (slab_force)")
    parser.add_argument("--check", choices=("margules", "translate", "eccentric", "power_law", "convergence",
                                            "transient2d"), action="append", help="a closed-form or reference check")
    parser.add_argument("--out", help="a folder for result.npz and slices.png (made if missing; existing files "
                        "there are not overwritten without --overwrite)")
    parser.add_argument("--overwrite", action="store_true")
    parser.add_argument("--verbose", action="store_true")
    args = parser.parse_args()
    started = time.time()
    if args.check:
        for name in args.check:
            run_check(name, args)
        return
    rig = Rig(args.cup_radius, args.fill, args.rod_radius, args.gap, args.orbit)
    law = _parse_law(args.law, args.param, args.viscosity)
    out = Path(args.out) if args.out else None
    if out is not None:
        clash = [p for p in (out / "result.npz", out / "slices.png") if p.exists()]
        if clash and not args.overwrite:
            raise SystemExit(f"{clash[0]} exists; pass --overwrite to replace it")
        out.mkdir(parents=True, exist_ok=True)
    rig_mesh = (slab_mesh if args.slab else build_mesh)(rig, args.cell, growth=args.growth)
    result = solve(rig_mesh, law, args.speed, density=args.density, inertia=args.inertia, solver=args.solver,
                   verbose=args.verbose)
    unit = "/m" if args.slab else ""
    print(f"drag {result.drag:.6g} N{unit}, radial {result.radial:+.6g} N{unit}, vertical {result.force[2]:+.6g} "
          f"N{unit}, torque {result.torque:+.6g} N m{unit}, dissipation {result.dissipation:.6g} W{unit}; "
          f"{result.iterations} iterations, {result.n_velocity} + {result.n_pressure} dofs, {result.solver}, "
          f"{result.seconds:.0f} s, peak memory {result.memory_gib:.1f} GiB (total {time.time() - started:.0f} s)")
    if out is not None:
        np.savez(out / "result.npz", force=result.force, torque=result.torque, dissipation=result.dissipation,
                 iterations=result.iterations, dofs=(result.n_velocity, result.n_pressure), cell=args.cell,
                 rig=np.array(dataclasses.astuple(rig)[:5]), speed=args.speed, density=args.density,
                 inertia=args.inertia, law=repr(law))
        if not args.slab:
            slices(result, rig_mesh, out / "slices.png")
        print(f"-> {out}")


def run_check(name: str, args) -> None:
    """Print one check's table rows (``--check``)."""
    start = time.time()
    print("| check | computed | reference | ratio | dofs (u + p) | time [s] | peak memory [GiB] |")
    print("|---|---|---|---|---|---|---|")
    if name == "convergence":
        rig = Rig(args.cup_radius, args.fill, args.rod_radius, args.gap, args.orbit)
        viscosity = args.viscosity or 1.0
        rows, extrapolated, order = convergence(rig, law=viscosity, speed=args.speed, verbose=args.verbose)
        for cell, r in rows:
            print(f"| drag, paper's rig, {viscosity:g} Pa·s, {args.speed:g} m/s, cell {cell * 1e3:g} mm [N] | "
                  f"{r.drag:.6g} | {extrapolated:.6g} (extrapolated) | {r.drag / extrapolated:.5f} | "
                  f"{r.n_velocity} + {r.n_pressure} | {r.seconds:.0f} | {r.memory_gib:.1f} |")
        second = rows[-1][1].drag + (rows[-1][1].drag - rows[-2][1].drag) / ((rows[0][0] / rows[1][0]) ** 2 - 1)
        print(f"observed order {order:.2f}; finest mesh's error {abs(rows[-1][1].drag / extrapolated - 1):.3%} "
              f"(against the order-2 extrapolation {second:.6g}: {abs(rows[-1][1].drag / second - 1):.3%})")
        return
    if name == "transient2d":
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from stir_reference import stir

        rig = Rig(cup_radius=0.0425, orbit=0.015)
        steady = slab_force(rig, args.cell, 0.2, 0.1, inertia=True, verbose=args.verbose)
        transient = stir(0.2, duration=4.0)  # the fluid's spin-up at 0.2 Pa·s lasts past 1.5 s
        late = transient["times"] > 2.5
        for label, ours, theirs in (("drag", steady.drag, -transient["tangential"][late].mean()),
                                    ("radial force", steady.radial, transient["radial"][late].mean())):
            print(f"| {label}, 2-D stir, 0.2 Pa·s, 0.1 m/s, e = 15 mm, steady slab against the transient "
                  f"scripts/stir_reference.py from 2.5 to 4 s [N/m] | {ours:.5g} | {theirs:.5g} | "
                  f"{ours / theirs:.4f} | {steady.n_velocity} + {steady.n_pressure} | {time.time() - start:.0f} | "
                  f"{steady.memory_gib:.1f} |")
        return
    for label, computed, reference, result in check(name, args.cell, args.viscosity or 1.0, 0.01, args.verbose):
        print(f"| {label} | {computed:.6g} | {reference:.6g} | {computed / reference:.5f} | "
              f"{result.n_velocity} + {result.n_pressure} | {result.seconds:.0f} | {result.memory_gib:.1f} |")


if __name__ == "__main__":
    main()
