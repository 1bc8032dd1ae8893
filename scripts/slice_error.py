"""The slice's error: F_3D / (F'_2D h) from the 3-D finite-element reference across rigs, laws and Reynolds numbers.

The 3-D force on the rod F_3D [N] (``stir_reference_3d.solve`` on ``build_mesh``) and the force per length of the
same cross-section F'_2D [N/m] (``stir_reference_3d.slab_force``) come from one method, so their ratio over the
immersed length h = H − g [m] is the slice's geometric error alone (docs/accuracy-slice.md, The slice's error).

Meshes. A Newtonian Stokes row solves the cup on ``FINE_CELL`` and the slab on ``SLAB_CELL`` (the slab's error is
about first order in its cell and ten times cheaper, the cup's is below 0.1 % at 3 mm on the paper's rig,
docs/validation.md), and both again on ``COARSE_CELL``; the rig's mesh factor κ = ratio(fine) / ratio(coarse). A
power-law or inertial row solves both on ``COARSE_CELL`` (a Picard step per iteration) and reports
ratio = κ · ratio(coarse), with the raw ratio beside it.

Physics that cuts the sweep: a Newtonian Stokes ratio does not depend on η or U; a power law's depends on the rig
and n only (not k or U); only inertia brings in Re = ρ U 2a / η.

    python scripts/slice_error.py                       # the full sweep (about 40 minutes on 2 loaded cores)
    python scripts/slice_error.py --only stokes --rigs paper shallow --out /tmp/se.json
    python scripts/slice_error.py --fit docs/data/slice_error.json --out diffstir/data/slice_correction.json
    python scripts/slice_error.py --mpm paper3d --duration 3   # the 3-D MPM's steady drag (paper_e25 rig)
    python scripts/slice_error.py --mpm fine3d --set dx=0.0025 device=cuda --duration 2
Writes one JSON row per case to ``--out`` (default docs/data/slice_error.json) after each case; an existing file
is refused without ``--overwrite``. Needs scikit-fem, gmsh and pyamg (``pip install -e ".[validation]"``).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time
from pathlib import Path

from diffstir.lab import stokes3d

FINE_CELL = 0.003  # m, the cup's cell for the Stokes rows
SLAB_CELL = 0.0015  # m, the slab's cell for the Stokes rows
COARSE_CELL = 0.0045  # m, both meshes for the power-law and inertial rows and the mesh factor
DENSITY = 1000.0  # kg/m³

RIGS = {  # cup radius R, fill H, rod radius a, gap g (tip above the bottom), circle radius e [m]
    "paper": stokes3d.CupRig(cup_radius=0.0475, fill=0.125, rod_radius=0.0125, gap=0.020, orbit=0.030),
    "shallow": stokes3d.CupRig(cup_radius=0.0475, fill=0.090, rod_radius=0.0125, gap=0.050, orbit=0.020),
    "deep_centred": stokes3d.CupRig(cup_radius=0.0475, fill=0.120, rod_radius=0.0125, gap=0.010, orbit=0.010),
    "thin_rod": stokes3d.CupRig(cup_radius=0.050, fill=0.100, rod_radius=0.010, gap=0.030, orbit=0.025),
    "mid": stokes3d.CupRig(cup_radius=0.0475, fill=0.080, rod_radius=0.0125, gap=0.020, orbit=0.015),
    "small_cup": stokes3d.CupRig(cup_radius=0.040, fill=0.050, rod_radius=0.010, gap=0.010, orbit=0.020),
    "paper_e25": stokes3d.CupRig(cup_radius=0.0475, fill=0.125, rod_radius=0.0125, gap=0.020, orbit=0.025),
    # the project's default rig (conf/rig/paper.yaml) on a 15 mm circle
    "project": stokes3d.CupRig(cup_radius=0.0425, fill=0.13005, rod_radius=0.0125, gap=0.05005, orbit=0.015),
}

POWER_LAW_RIGS = ("paper", "shallow", "project")
FLOW_INDICES = (0.4, 0.7, 1.4)
INERTIA = {  # rig: [(η [Pa s], U [m/s])], Re = ρ U 2a / η from 0.1 to 30
    "paper": [(10.0, 0.04), (1.0, 0.1), (0.3, 0.1), (0.1, 0.12)],
    "shallow": [(1.0, 0.1), (0.1, 0.12)],
    "paper_e25": [(1.0, 0.1)],
}


def geometry(rig: stokes3d.CupRig) -> dict:
    """The rig's lengths [m] and dimensionless groups."""
    a = rig.rod_radius
    return {"cup_radius_m": rig.cup_radius, "fill_m": rig.fill, "rod_radius_m": a, "gap_m": rig.gap,
            "orbit_m": rig.orbit, "immersion_m": rig.immersion, "h_over_a": rig.immersion / a,
            "g_over_a": rig.gap / a, "e_over_R": rig.orbit / rig.cup_radius, "R_over_a": rig.cup_radius / a,
            "wall_gap_over_a": (rig.cup_radius - rig.orbit - a) / a}


def forces(rig: stokes3d.CupRig, law, speed: float, cell: float, slab_cell: float, inertia: bool) -> dict:
    """F_3D [N], F'_2D [N/m], their ratio over h, and the solves' costs."""
    start = time.time()
    options = {"inertia": inertia, "density": DENSITY}
    cup = stokes3d.solve(stokes3d.build_mesh(rig, cell), law, speed, **options)
    slab = stokes3d.slab_force(rig, slab_cell, law, speed, **options)
    return {"F_3D_N": cup.drag, "F_2D_N_per_m": slab.drag, "ratio": cup.drag / (slab.drag * rig.immersion),
            "cells_m": {"cup": cell, "slab": slab_cell}, "iterations": {"cup": cup.iterations, "slab": slab.iterations},
            "unknowns": cup.n_velocity + cup.n_pressure, "solver": cup.solver, "seconds": time.time() - start,
            "peak_memory_gib": cup.memory_gib}


def row(name: str, rig: stokes3d.CupRig, law: dict, speed: float, reynolds: float, result: dict, factor: float | None) -> dict:
    """One table row; ``factor`` the rig's mesh factor κ for a coarse row (None for a Stokes row)."""
    out = {"rig": name, **geometry(rig), "law": law, "speed_m_per_s": speed, "reynolds": reynolds,
           "h_m": rig.immersion, **result}
    out["ratio_raw"] = result["ratio"]
    out["mesh_factor"] = factor
    if factor is not None:
        out["ratio"] = result["ratio"] * factor
    return out


def write(path: Path, rows: list, command: str) -> None:
    """The table as JSON, written atomically."""
    data = {"description": "F_3D / (F'_2D h) from scripts/stir_reference_3d.py (docs/accuracy-slice.md, The slice's "
                           "error); forces are the drag against the rod's motion, N and N/m",
            "command": command, "date": datetime.date.today().isoformat(),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.python_version()}",
            "cells_m": {"fine_cup": FINE_CELL, "fine_slab": SLAB_CELL, "coarse": COARSE_CELL},
            "density_kg_per_m3": DENSITY, "rows": rows}
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1, default=lambda value: value.item()) + "\n")
    os.replace(tmp, path)


def mpm_drag(sim_name: str, duration: float, rig_name: str = "paper_e25", viscosity: float = 1.0,
             speed: float = 0.1, average_from: float = 0.5, overrides: dict | None = None,
             bin_width: float = 0.25) -> dict:
    """The project's 3-D MPM (``conf/sim/<sim_name>.yaml`` with ``overrides``, e.g. ``{"dx": 0.0025, "device":
    "cuda"}``) stirring ``RIGS[rig_name]`` along its circle (the paper's rig with e = 25 mm by default: the MPM keeps
    the rod half a cell off the wall, 1 cm cells need e < 30 mm): the drag against the motion [N] averaged over the
    last ``1 − average_from`` of ``duration`` [s] and over bins of ``bin_width`` [s], and the cost per simulated
    second [s/s]."""
    import numpy as np
    import torch
    import yaml

    from diffstir.mpm import SimConfig, StirringSimulator
    from diffstir.rheology import Newtonian
    from diffstir.rig import Cup, Rig, Rod
    from diffstir.trajectory import circle

    settings = yaml.safe_load((Path(__file__).resolve().parents[1] / "conf" / "sim" / f"{sim_name}.yaml").read_text())
    settings.pop("_target_")
    settings.update(overrides or {})
    paper = RIGS[rig_name]
    rig = Rig(cup=Cup(radius=paper.cup_radius, fill_height=paper.fill, height=paper.fill + 0.04),
              rod=Rod(radius=paper.rod_radius, immersion_depth=paper.immersion, length=paper.fill + 0.1))
    sim = StirringSimulator(Newtonian(eta=viscosity), rig, SimConfig(**settings), density=DENSITY)
    trajectory = circle(paper.orbit, speed, duration, ramp_time=0.2)
    start = time.time()
    initial = sim.initial_state(trajectory)
    settled = time.time()
    with torch.no_grad():
        result = sim(trajectory, initial=initial)
    seconds = time.time() - settled
    t = result.times.cpu().numpy()
    phase = np.unwrap(np.arctan2(np.interp(t, trajectory.t, trajectory.xy[:, 1]),
                                 np.interp(t, trajectory.t, trajectory.xy[:, 0])))
    tangent = np.stack([-np.sin(phase), np.cos(phase)], -1)
    drag = -(result.force.double().cpu().numpy()[:, :2] * tangent).sum(-1)
    late = t >= average_from * duration
    bins = np.minimum((t // bin_width).astype(int), int(np.ceil(duration / bin_width)) - 1)
    binned = [{"from_s": b * bin_width, "to_s": min((b + 1) * bin_width, duration),
               "drag_N": float(drag[bins == b].mean())} for b in np.unique(bins)]
    return {"sim": sim_name, "overrides": overrides or {}, "rig": rig_name, "dx_m": sim.config.dx,
            "pressure": sim.config.pressure, "device": str(sim.config.device), "particles": int(initial.x.shape[0]),
            "dt_s": result.dt, "steps": len(t), "viscosity_pa_s": viscosity, "speed_m_per_s": speed,
            "duration_s": duration, "drag_N": float(drag[late].mean()), "drag_std_N": float(drag[late].std()),
            "drag_binned": binned,
            "settle_seconds": settled - start, "seconds": seconds, "seconds_per_simulated_second": seconds / duration}


def fit(table: Path, out: Path, command: str) -> dict:
    """Least squares of the factor 1 + ℓ a / h, ℓ = c · ``diffstir.slice_correction.features``, over the table's
    rows; σ the relative residuals' root mean square over the fit's degrees of freedom (rows − coefficients)."""
    import numpy as np

    from diffstir.slice_correction import FEATURES, GROUPS, features

    rows = json.loads(table.read_text())["rows"]
    dimensionless = [{"h_over_a": r["h_over_a"], "g_over_a": r["g_over_a"], "wall_gap_over_a": r["wall_gap_over_a"],
                      "e_over_R": r["e_over_R"], "R_over_a": r["R_over_a"], "n": r["law"].get("n", 1.0),
                      "reynolds": r["reynolds"]} for r in rows]
    design = np.array([features(g) / g["h_over_a"] for g in dimensionless])
    target = np.array([r["ratio"] - 1.0 for r in rows])
    coefficients, *_ = np.linalg.lstsq(design, target, rcond=None)
    residual = (target - design @ coefficients) / (1.0 + target)  # relative to the factor
    sigma = float(np.sqrt((residual**2).sum() / (len(rows) - len(FEATURES))))
    result = {"description": "F_3D / (F'_2D h) = 1 + ell a / h, ell = coefficients . features "
                             "(diffstir/slice_correction.py); sigma: the factor's relative 1-sigma uncertainty",
              "features": list(FEATURES), "coefficients": coefficients.tolist(), "sigma": sigma,
              "max_abs_residual": float(np.abs(residual).max()), "rows": len(rows),
              "ranges": {name: [min(g[name] for g in dimensionless), max(g[name] for g in dimensionless)]
                         for name in GROUPS},
              "source": str(table), "command": command, "date": datetime.date.today().isoformat(),
              "machine": f"{platform.machine()}, {os.cpu_count()} cores"}
    out.write_text(json.dumps(result, indent=1) + "\n")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("docs/data/slice_error.json"))
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    parser.add_argument("--rigs", nargs="+", choices=tuple(RIGS), default=tuple(RIGS))
    parser.add_argument("--only", nargs="+", choices=("stokes", "power_law", "inertia"),
                        default=("stokes", "power_law", "inertia"))
    parser.add_argument("--factors-from", type=Path, metavar="TABLE",
                        help="take each rig's mesh factor from the Stokes rows of this table instead of solving them")
    parser.add_argument("--mpm", metavar="SIM", help="instead: the 3-D MPM (conf/sim/SIM.yaml) on the paper's rig")
    parser.add_argument("--duration", type=float, default=3.0, help="the MPM's stir [s]")
    parser.add_argument("--mpm-rig", choices=tuple(RIGS), default="paper_e25", help="the MPM's rig")
    parser.add_argument("--set", nargs="+", default=[], metavar="FIELD=VALUE",
                        help="the MPM's settings over conf/sim/SIM.yaml's, e.g. dx=0.0025 device=cuda")
    parser.add_argument("--fit", type=Path, metavar="TABLE",
                        help="instead: fit the correction model to TABLE and write it to --out")
    args = parser.parse_args()
    command = "python scripts/slice_error.py " + " ".join(sys.argv[1:])
    if args.fit:
        if args.out.exists() and not args.overwrite:
            parser.error(f"{args.out} exists; pass --overwrite to replace it")
        print(json.dumps(fit(args.fit, args.out, command), indent=1))
        return
    if args.mpm:
        import yaml

        overrides = {key: yaml.safe_load(value) for key, value in (item.split("=", 1) for item in args.set)}
        print(json.dumps(mpm_drag(args.mpm, args.duration, args.mpm_rig, overrides=overrides), indent=1))
        return
    if args.out.exists() and not args.overwrite:
        parser.error(f"{args.out} exists; pass --overwrite to replace it")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    from diffstir.rheology import PowerLaw

    rows, factors = [], {}
    if args.factors_from:
        stokes = [r for r in json.loads(args.factors_from.read_text())["rows"] if r["mesh_factor"] is None]
        factors = {r["rig"]: r["ratio"] / r["coarse"]["ratio"] for r in stokes}
    newtonian = {"name": "newtonian", "viscosity_pa_s": 1.0}
    for name in [r for r in args.rigs if r not in factors]:  # Stokes first: the mesh factors
        rig = RIGS[name]
        fine = forces(rig, 1.0, 0.1, FINE_CELL, SLAB_CELL, False)
        coarse = forces(rig, 1.0, 0.1, COARSE_CELL, COARSE_CELL, False)
        factors[name] = fine["ratio"] / coarse["ratio"]
        if "stokes" in args.only:
            rows.append(row(name, rig, newtonian, 0.1, 0.0, fine, None))
            rows[-1]["coarse"] = coarse
            write(args.out, rows, command)
        print(f"{name}: Stokes ratio {fine['ratio']:.5f} (coarse {coarse['ratio']:.5f}, κ {factors[name]:.5f}; "
              f"{fine['seconds']:.0f} + {coarse['seconds']:.0f} s)", flush=True)
    if "power_law" in args.only:
        for name in [r for r in POWER_LAW_RIGS if r in args.rigs]:
            for n in FLOW_INDICES:
                law = PowerLaw(k=1.0, n=n, shear_rate_reg=1e-6)
                result = forces(RIGS[name], law, 0.1, COARSE_CELL, COARSE_CELL, False)
                rows.append(row(name, RIGS[name], {"name": "power_law", "k_pa_s_n": 1.0, "n": n}, 0.1, 0.0, result,
                                factors[name]))
                write(args.out, rows, command)
                print(f"{name}: power law n {n}: ratio {rows[-1]['ratio']:.5f} ({result['seconds']:.0f} s)",
                      flush=True)
    if "inertia" in args.only:
        for name in [r for r in INERTIA if r in args.rigs]:
            rig = RIGS[name]
            for viscosity, speed in INERTIA[name]:
                reynolds = DENSITY * speed * 2 * rig.rod_radius / viscosity
                try:
                    result = forces(rig, viscosity, speed, COARSE_CELL, COARSE_CELL, True)
                except RuntimeError as error:  # a Picard iteration that does not converge leaves no row
                    print(f"{name}: η {viscosity} Pa s, U {speed} m/s, Re {reynolds:.3g}: {error}", flush=True)
                    continue
                rows.append(row(name, rig, {"name": "newtonian", "viscosity_pa_s": viscosity}, speed, reynolds,
                                result, factors[name]))
                write(args.out, rows, command)
                print(f"{name}: η {viscosity} Pa s, U {speed} m/s, Re {reynolds:.3g}: ratio {rows[-1]['ratio']:.5f} "
                      f"({result['seconds']:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
