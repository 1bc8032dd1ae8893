"""Mean drag on the rod against viscosity, on the paper's rig stirred on a circle, at two resolutions.

    python scripts/viscosity_sweep.py [--sims paper3d slice2d] [--viscosities 1e-3 1e-2 1e-1 1 10]
                                      [--duration 0.3] [--plot docs/figures/viscosity_sweep.png]

A Newtonian fluid of each viscosity is stirred by the paper's rod (radius 12.5 mm) with its axis on a circle of
radius 15 mm about the cup's axis at 0.1 m/s (speed ramped up over the first 0.1 s); the mean drag is the mean
magnitude of the horizontal force on the rod after the ramp. Simulations come from ``conf/sim/<name>.yaml``: the
paper's 3-D grid (1 cm cells) and the fitting default, the 2-D slice (2.5 mm cells; force per unit length of rod).
Printed: a markdown table of the rod's Reynolds number Re = rho U 2a / eta, the drag and the local slope
d ln F / d ln eta between neighbouring viscosities (1 for a Stokes drag, Re << 1; towards 0 where inertia
dominates, Re >> 1, and also where numerical dissipation swamps the viscosity), and the wall time of each run; the plot
shows F against eta on log-log axes. A short stir (0.3 s by default) keeps the sweep to minutes: the drag is read
while the flow around the rod is still developing at the low viscosities, so the table compares resolutions at one
stirring programme rather than giving steady-state drag.
"""

from __future__ import annotations

import argparse
import datetime
import math
import platform
import time
from pathlib import Path

import torch
import yaml

from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.rheology import Newtonian
from diffstir.rig import Rig
from diffstir.trajectory import circle

CONF = Path(__file__).resolve().parents[1] / "conf" / "sim"
RADIUS, SPEED, RAMP = 0.015, 0.1, 0.1  # m, m/s, s
DENSITY = 1000.0  # kg/m³


def sim_config(name: str) -> SimConfig:
    """The simulation settings of ``conf/sim/<name>.yaml``."""
    settings = yaml.safe_load((CONF / f"{name}.yaml").read_text())
    settings.pop("_target_")
    return SimConfig(**settings)


def mean_drag(config: SimConfig, viscosity: float, duration: float) -> tuple[float, float, float]:
    """Mean horizontal force magnitude on the rod after the ramp [N] (2-D: [N/m]), the time step [s] and the
    wall time of the run [s]."""
    sim = StirringSimulator(Newtonian(eta=viscosity), Rig(), config, density=DENSITY)
    trajectory = circle(RADIUS, SPEED, duration, ramp_time=RAMP)
    start = time.perf_counter()
    with torch.no_grad():
        result = sim(trajectory)
    wall = time.perf_counter() - start
    after_ramp = result.times >= RAMP
    return result.force[after_ramp, :2].norm(dim=-1).mean().item(), result.dt, wall


def plot(rows: dict[str, list[tuple[float, float]]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(rows), figsize=(4.5 * len(rows), 3.6), constrained_layout=True, squeeze=False)
    for ax, (name, points) in zip(axes[0], rows.items()):
        eta, force = zip(*points)
        ax.loglog(eta, force, "o-", label="simulated")
        ax.loglog(eta, [force[-1] * e / eta[-1] for e in eta], "k:", lw=0.8, label="slope 1 (viscous)")
        ax.set_xlabel("viscosity η [Pa·s]")
        ax.set_ylabel("mean drag [N/m]" if sim_config(name).dim == 2 else "mean drag [N]")
        ax.set_title(f"{name}: dx = {sim_config(name).dx * 1e3:g} mm, {sim_config(name).dim}-D", fontsize=9)
        ax.legend(fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sims", nargs="+", default=["paper3d", "slice2d"])
    parser.add_argument("--viscosities", nargs="+", type=float, default=[1e-3, 1e-2, 1e-1, 1.0, 10.0])
    parser.add_argument("--duration", type=float, default=0.3, help="stirring time [s]")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--plot", type=Path, default=Path("docs/figures/viscosity_sweep.png"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"{datetime.date.today()}, {platform.machine()}, torch {torch.__version__}, {args.threads} thread(s); "
          f"circle r = {RADIUS * 1e3:g} mm at {SPEED} m/s for {args.duration} s, drag averaged after {RAMP} s")
    print("| sim | eta [Pa s] | Re | mean drag | d ln F / d ln eta | dt [ms] | wall [s] |")
    print("|---|---|---|---|---|---|---|")
    rows: dict[str, list[tuple[float, float]]] = {}
    for name in args.sims:
        config = sim_config(name)
        unit = "N/m" if config.dim == 2 else "N"
        rows[name] = []
        for eta in sorted(args.viscosities):
            force, dt, wall = mean_drag(config, eta, args.duration)
            slope = ""
            if rows[name]:
                eta0, force0 = rows[name][-1]
                slope = f"{math.log(force / force0) / math.log(eta / eta0):.3f}"
            rows[name].append((eta, force))
            reynolds = DENSITY * SPEED * 2 * Rig().rod.radius / eta
            print(f"| {name} | {eta:g} | {reynolds:.3g} | {force:.4g} {unit} | {slope} | {dt * 1e3:.3f} | {wall:.0f} |",
                  flush=True)
    plot(rows, args.plot)
    print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
