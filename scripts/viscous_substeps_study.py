"""The shear stress's substeps against the whole step shortened to the viscous limit: force and time of one stir.

    python scripts/viscous_substeps_study.py --viscosities 1 5 20 --pressures compressible projection
    python scripts/viscous_substeps_study.py --closed-form

For each pressure and Newtonian viscosity [Pa·s], the paper's stir (circle of radius 15 mm at 0.1 m/s, 1 s, 0.2 s
ramp) on the 2-D fitting slice (``conf/sim/slice2d.yaml``), once with ``viscous_substeps`` and once without: the
step, the substeps, the mean force per unit length over the last half [N/m], the forces' ratio and the rollout's
wall time. ``--closed-form``: instead, closed forms of ``validate_simulator.py`` with and without substeps: the
power-law Couette torque (its viscosity bound is the cap, its viscosity in the gap 1-2 Pa·s) at fixed steps, which
tells the substeps' error from the step's, and the translating rod at 20 Pa·s. Prints markdown tables
(docs/validation.md).
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time
from functools import partial
from pathlib import Path

import torch
import yaml

from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.rheology import Newtonian
from diffstir.rig import Rig
from diffstir.trajectory import circle

SLICE = Path(__file__).resolve().parents[1] / "conf" / "sim" / "slice2d.yaml"


def stir(config: SimConfig, eta: float) -> tuple[float, int, float, float]:
    """The step [s], the substeps, the mean force magnitude over the stir's last half [N/m] and the wall time [s]."""
    trajectory = circle(radius=0.015, speed=0.1, duration=1.0, ramp_time=0.2)
    sim = StirringSimulator(Newtonian(eta=eta), Rig(), config, density=1000.0)
    start = time.perf_counter()
    with torch.no_grad():
        result = sim(trajectory)
    seconds = time.perf_counter() - start
    force = result.force[len(result.force) // 2:].norm(dim=1).mean().item()
    return result.dt, sim.substeps(trajectory, result.dt), force, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--viscosities", nargs="+", type=float, default=[1.0, 5.0, 20.0], help="Pa·s")
    parser.add_argument("--pressures", nargs="+", default=["compressible", "projection"],
                        choices=["compressible", "projection"])
    parser.add_argument("--closed-form", action="store_true", help="closed forms split and unsplit instead")
    args = parser.parse_args()
    torch.set_num_threads(1)
    settings = {k: v for k, v in yaml.safe_load(SLICE.read_text()).items() if k != "_target_"}
    base = SimConfig(**settings)
    print(f"{datetime.date.today()}, {platform.machine()}, {os.cpu_count()} CPUs, load average "
          f"{os.getloadavg()[0]:.1f} at start, torch {torch.__version__}, 1 thread, {base.dtype}\n")
    if args.closed_form:
        closed_form(base, args.pressures)
        return
    print("| pressure | η [Pa·s] | unsplit: Δt [µs], force [N/m], time [s] | substeps: Δt [µs], m, force [N/m], "
          "time [s] | force ratio | time ratio |")
    print("|---|---|---|---|---|---|")
    for pressure in args.pressures:
        for eta in args.viscosities:
            dt0, _, f0, t0 = stir(base.replace(pressure=pressure, viscous_substeps=False), eta)
            dt1, m, f1, t1 = stir(base.replace(pressure=pressure, viscous_substeps=True), eta)
            print(f"| {pressure} | {eta:g} | {dt0 * 1e6:.0f}, {f0:.4f}, {t0:.1f} | {dt1 * 1e6:.0f}, {m}, {f1:.4f}, "
                  f"{t1:.1f} | {f1 / f0:.3f} | {t0 / t1:.2f}x |", flush=True)


def closed_form(base: SimConfig, pressures: list[str]) -> None:
    """Closed forms over their values, split and unsplit: the power-law Couette torque at the step the config
    chooses and at 0.5 and 0.25 ms, and the translating rod's drag at 20 Pa·s (the cap)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from validate_simulator import power_law_couette, translating

    print("| check | pressure | Δt | substeps | unsplit |\n|---|---|---|---|---|")
    cases = [("power-law Couette torque", power_law_couette, dt) for dt in (None, 5e-4, 2.5e-4)]  # s
    cases.append(("translating rod drag, 20 Pa·s", partial(translating, mu=20.0), None))
    for pressure in pressures:
        for name, check, dt in cases:
            ratios = []
            for split in (True, False):
                _, value, reference = check(base.replace(pressure=pressure, dt=dt, viscous_substeps=split),
                                            pressure)
                ratios.append(value / reference)
            print(f"| {name} | {pressure} | {'chosen' if dt is None else f'{dt * 1e3:g} ms'} | {ratios[0]:.4f} | "
                  f"{ratios[1]:.4f} |", flush=True)


if __name__ == "__main__":
    main()
