"""Compare the simulator with closed-form solutions and print a markdown table (docs/validation.md).

    python scripts/validate_simulator.py [--checks couette power_law translate translate_viscosity convergence rest3d]
        [--rest-time 8]

Checks (the fitting default, conf/sim/slice2d.yaml, is 2.5 mm cells at c = 1 m/s; c = 2 m/s was the default until
2026-11-22 and is printed beside it):
- couette: rod spinning at the cup's centre, 2-D, mu = 1 Pa s, Omega = 2 rad/s (Re = 0.75); steady torque per unit
  length against 4 pi mu Omega a^2 b^2 / (b^2 - a^2).
- power_law: the same with a power-law fluid, K = 1 Pa s^n, n = 0.6, Omega = 1 rad/s (Re = 0.6 at the rod), against
  2 pi K a^2 [2 Omega / (n (1 - (a/b)^(2/n)))]^n.
- translate: rod translating at 1 mm/s at the centre, 2-D, mu = 1 and 0.2 Pa s; steady force per unit length against
  4 pi mu U / [ln(b/a) - (b^2 - a^2)/(b^2 + a^2)], at sound speeds 1, 2 and 0.5 m/s.
- translate_viscosity: the translating rod at mu = 1 and 0.2 Pa s on 2.5 and 2 mm cells at c = 1 and 2 m/s: how the
  drag's excess over the exact one scales with the viscosity and the bulk modulus (not run by default).
- convergence: the Newtonian and power-law Couette checks on 5, 2.5, 2 and 1.6 mm cells (not run by default).
- rest3d: the paper's 3-D scene at rest (8 s, the paper's recording length): the fluid's volume by its particles'
  J (sum J V0), the height of its centre of mass (at rest neither may change), and the vertical force against
  rho g V_immersed.

Runs with one intra-op thread: the simulator's tensors are small, and on a shared 2-core machine two threads made
every step many times slower (docs/benchmarks.md).
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from problems import couette_torque_newtonian, couette_torque_power_law, translating_rod_force  # noqa: E402

from diffstir.mpm import SimConfig, StirringSimulator  # noqa: E402
from diffstir.rheology import Newtonian, PowerLaw  # noqa: E402
from diffstir.rig import Rig  # noqa: E402
from diffstir.trajectory import spin, stationary, translate  # noqa: E402

RIG = Rig()
A, B = RIG.rod.radius, RIG.cup.radius


def steady(values: torch.Tensor) -> float:
    """Mean over the last 30 % of a series."""
    return values[int(0.7 * len(values)):].mean().item()


def couette(dx: float, sound_speed: float) -> tuple[str, float, float]:
    sim = StirringSimulator(Newtonian(eta=1.0), RIG, SimConfig(dim=2, dx=dx, sound_speed=sound_speed), density=1000.0)
    with torch.no_grad():
        result = sim(spin(2.0, duration=0.6, ramp_time=0.1))
    return (f"Couette torque, 2-D, dx = {dx * 1e3:g} mm, c = {sound_speed:g} m/s [N]", -steady(result.torque),
            couette_torque_newtonian(1.0, 2.0, A, B))


def power_law_couette(dx: float, sound_speed: float) -> tuple[str, float, float]:
    k, n, omega = 1.0, 0.6, 1.0
    sim = StirringSimulator(PowerLaw(k=k, n=n), RIG, SimConfig(dim=2, dx=dx, sound_speed=sound_speed), density=1000.0)
    with torch.no_grad():
        result = sim(spin(omega, duration=0.6, ramp_time=0.1))
    return (f"power-law (n = {n}) Couette torque, 2-D, dx = {dx * 1e3:g} mm, c = {sound_speed:g} m/s [N]",
            -steady(result.torque), couette_torque_power_law(k, n, omega, A, B))


def translating(dx: float, sound_speed: float, mu: float = 1.0) -> tuple[str, float, float]:
    sim = StirringSimulator(Newtonian(eta=mu), RIG, SimConfig(dim=2, dx=dx, sound_speed=sound_speed), density=1000.0)
    with torch.no_grad():
        result = sim(translate((1e-3, 0.0), duration=1.0, start=(-0.5e-3, 0.0)))
    viscosity = "" if mu == 1.0 else f", mu = {mu:g} Pa s"
    return (f"translating rod drag, 2-D, dx = {dx * 1e3:g} mm, c = {sound_speed:g} m/s{viscosity} [N/m]",
            -steady(result.force[:, 0]), translating_rod_force(mu, 1e-3, A, B))


def rest3d(duration: float) -> list[tuple[str, float, float]]:
    config = SimConfig(dim=3, dx=0.01, sound_speed=4.5, cfl=0.45)
    sim = StirringSimulator(Newtonian(eta=0.1), RIG, config, density=1000.0)
    trajectory = stationary(duration)
    start = sim.initial_state(trajectory)
    with torch.no_grad():
        result = sim(trajectory, initial=start)
    volume = lambda s: (s.J.sum() * sim.scene.particle_volume).item()  # noqa: E731
    height = lambda s: s.x[:, 2].mean().item()  # noqa: E731
    buoyancy = 1000.0 * 9.81 * math.pi * A**2 * RIG.rod.immersion_depth
    return [(f"3-D rest (1 cm cells), fluid volume by J, sum J V0, after {duration:g} s / at start",
             volume(result.state) / volume(start), 1.0),
            (f"3-D rest (1 cm cells), centre of mass height after {duration:g} s / at start",
             height(result.state) / height(start), 1.0),
            ("3-D rest (1 cm cells), vertical force on the rod [N] vs rho g V", steady(result.force[:, 2]), buoyancy)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checks", nargs="+", default=["couette", "power_law", "translate", "rest3d"])
    parser.add_argument("--rest-time", type=float, default=8.0, help="duration of the rest3d check [s]")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"{datetime.date.today()}, {platform.machine()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at "
          f"start, torch {torch.__version__}, 1 thread, float32")
    print("| check | simulated | closed form | ratio |")
    print("|---|---|---|---|")
    checks = {
        "couette": lambda: [couette(0.005, 1.0), couette(0.0025, 1.0), couette(0.0025, 2.0)],
        "translate": lambda: [translating(0.0025, 1.0), translating(0.0025, 1.0, 0.2), translating(0.0025, 2.0),
                              translating(0.0025, 0.5)],
        "translate_viscosity": lambda: [translating(dx, c, mu) for c in (1.0, 2.0) for dx in (0.0025, 0.002)
                                        for mu in (1.0, 0.2)],
        "power_law": lambda: [power_law_couette(0.0025, 1.0), power_law_couette(0.0025, 2.0)],
        "convergence": lambda: [check(dx, 1.0) for dx in (0.005, 0.0025, 0.002, 0.0016)
                                for check in (couette, power_law_couette)],
        "rest3d": lambda: rest3d(args.rest_time),
    }
    for name in args.checks:
        for label, value, reference in checks[name]():
            print(f"| {label} | {value:.5g} | {reference:.5g} | {value / reference:.3f} |", flush=True)


if __name__ == "__main__":
    main()
