"""The 3-D finite-element reference of the stir from the command line, and its checks (docs/validation.md).

The solver is ``diffstir.lab.stokes3d`` (the method is in its docstring); here are its checks against closed forms
(Margules, the translating rod, a power-law Couette flow), against the 2-D reference (scripts/stir_reference.py,
steady and in time), mesh convergence with Richardson extrapolation, and the velocity slices' plot.

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
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from skfem import Basis, MeshTet

from diffstir.lab.stokes3d import (CupRig, Result, RigMesh, build_mesh, slab_force, slab_mesh, solve,
                                   stir_history)


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


def long_rod(rig: CupRig, cell: float, length: float | None = None) -> CupRig:
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
    paper = CupRig()
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


def stokes_2d(rig: CupRig, viscosity: float, speed: float, mesh: tuple[int, int] = (256, 48)) -> float:
    """The steady Stokes drag per length [N/m] of the rig's cross-section from the 2-D reference
    (scripts/stir_reference.py, its bipolar mesh): three steps at a negligible density with the orbit's rate held."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from stir_reference import StirReference

    reference = StirReference(rig.rod_radius, rig.cup_radius, rig.orbit, 1e-9, viscosity, n_around=mesh[0],
                              n_across=mesh[1])
    rate = speed / rig.orbit
    out = reference.run(np.linspace(0.0, 0.003, 4), lambda t: rate, lambda t: 0.0, lambda t: 0.0)
    return -float(out[-1, 1])


def convergence(rig: CupRig = CupRig(), cells=(0.0045, 0.003, 0.002), law=1.0, speed: float = 0.1,
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
    rig = CupRig(args.cup_radius, args.fill, args.rod_radius, args.gap, args.orbit)
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
        rig = CupRig(args.cup_radius, args.fill, args.rod_radius, args.gap, args.orbit)
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
        from stir_reference import cosine_ramp, stir

        rig = CupRig(cup_radius=0.0425, orbit=0.015)
        steady = slab_force(rig, args.cell, 0.2, 0.1, inertia=True, verbose=args.verbose)
        transient = stir(0.2, duration=4.0)  # the fluid's spin-up at 0.2 Pa·s lasts past 1.5 s
        late = transient["times"] > 2.5
        for label, ours, theirs in (("drag", steady.drag, -transient["tangential"][late].mean()),
                                    ("radial force", steady.radial, transient["radial"][late].mean())):
            print(f"| {label}, 2-D stir, 0.2 Pa·s, 0.1 m/s, e = 15 mm, steady slab against the transient "
                  f"scripts/stir_reference.py from 2.5 to 4 s [N/m] | {ours:.5g} | {theirs:.5g} | "
                  f"{ours / theirs:.4f} | {steady.n_velocity} + {steady.n_pressure} | {time.time() - start:.0f} | "
                  f"{steady.memory_gib:.1f} |")
        # the same start in time (stir_history on the slab), step by step against the 2-D reference's history
        step = transient["step"]
        times = np.concatenate([[0.0], transient["times"]])
        scale, rate = cosine_ramp(times, transient["ramp_time"])
        omega = transient["speed"] / transient["orbit"]
        angle = np.concatenate([[0.0], np.cumsum(0.5 * step * omega * (scale[1:] + scale[:-1]))])
        started = time.time()
        history = stir_history(slab_mesh(rig, args.cell), 0.2, times, angle, omega * scale, omega * rate)
        for t in (0.25, 0.5, 1.0, 2.0, 4.0):
            i = int(np.argmin(abs(transient["times"] - t)))
            ours, theirs = -history.frame_force[i + 1, 1], -transient["tangential"][i]
            print(f"| drag at {t:g} s, 2-D stir from rest (0.5 s ramp), 0.2 Pa·s, slab in time "
                  f"(stir_history, {step * 1e3:g} ms steps) against scripts/stir_reference.py [N/m] | {ours:.5g} | "
                  f"{theirs:.5g} | {ours / theirs:.4f} | {history.n_velocity} + {history.n_pressure} | "
                  f"{time.time() - started:.0f} | {history.memory_gib:.1f} |")
        return
    for label, computed, reference, result in check(name, args.cell, args.viscosity or 1.0, 0.01, args.verbose):
        print(f"| {label} | {computed:.6g} | {reference:.6g} | {computed / reference:.5f} | "
              f"{result.n_velocity} + {result.n_pressure} | {result.seconds:.0f} | {result.memory_gib:.1f} |")


if __name__ == "__main__":
    main()
