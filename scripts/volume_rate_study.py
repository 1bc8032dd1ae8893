"""Where the translating rod's excess drag comes from, and what a projected volume rate does (docs/validation.md).

``validate_simulator.py`` is the acceptance check; this is the study behind its translating-rod defect. It prints
markdown tables:

    python scripts/volume_rate_study.py [--parts drag slow stir rest3d]

Parts:
- drag: the rod translating at 1 mm/s (2-D, 2.5 mm cells) for 1 s at mu = 1 and 0.2 Pa s and sound speeds 1, 2 and
  4 m/s, with the simulator's volume rate (each particle's J integrates its own velocity divergence, dJ/dt = J tr C)
  with a projected rate (the divergence averaged onto the grid nodes with the particles' B-spline weights and
  interpolated back, so that J only sees what the grid resolves), and with a relaxed J (the particle's own rate,
  then J relaxed over 0.05 s towards its projection, which damps J's variation within a cell and smooths the
  rest). Prints the drag against the exact one and the rms and mean of J - 1 within two cells of the rod
  (about 1.5 minutes per sound speed).
- slow: the behaviour benchmark's slowest stir (circle of 15 mm radius at 0.02 m/s, 1.6 s, 0.2 Pa s) with the
  simulator's rate at sound speeds 1, 2 and 4 m/s on 2.5 mm cells and 1 and 2 m/s on 2 mm cells: the mean horizontal
  force over the last half; a Mach number of 0.01-0.04 leaves a physical fluid's force unchanged. Then, at the
  default c = 2 m/s, the benchmark's three slower speeds on both grids, with the 2.5 mm force's elasticity
  d ln F / d ln eta from 0.16 and 0.25 Pa s (~10 minutes).
- stir: the paper's circular stir (15 mm radius, 0.1 m/s) for 3 s in 2-D at 0.2 Pa s with the three rates: the mean
  horizontal force over the last 40 % and the share of particles whose nine grid nodes all hold at least half the
  mass of a node inside the resting fluid, a measure of how evenly the particles still fill the fluid (~5 minutes).
- rest3d: the paper's 3-D scene (1 cm cells) at rest for 8 s with the three rates: the height of the fluid's
  centre of mass, after / before (~4 minutes each).

The projected and relaxed rates are study variants installed here with ``unittest.mock.patch``, not options of
the simulator: on the measured evidence neither was a cure (docs/validation.md). The study runs the numerics it was
made for (``FORMER``: APIC transfers, each particle's own J, no settling); the simulator's cure since 2026-11-24 is
the relaxation of J towards the packing the grid measures (``diffstir.mpm.packing``).
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import sys
from contextlib import nullcontext
from pathlib import Path
from unittest import mock

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from problems import translating_rod_force  # noqa: E402

import diffstir.mpm.step as mpm_step  # noqa: E402
from diffstir.mpm import SimConfig, StirringSimulator  # noqa: E402
from diffstir.mpm.state import State  # noqa: E402
from diffstir.rheology import Newtonian  # noqa: E402
from diffstir.rig import Rig  # noqa: E402
from diffstir.trajectory import circle, stationary, translate  # noqa: E402

RIG = Rig()
A, B = RIG.rod.radius, RIG.cup.radius
DX = 0.0025
PARTICLE_G2P = mpm_step.g2p


RELAXATION_TIME = 0.05  # s, of the relaxed variant


def project(st, values: torch.Tensor, num_nodes: int) -> torch.Tensor:
    """P(values): per-particle ``values`` averaged onto the grid nodes with the particles' B-spline weights and
    interpolated back, (N,)."""
    index, weight = st.index.reshape(-1), st.weight
    numerator = torch.zeros(num_nodes, dtype=values.dtype).scatter_add(0, index, (weight * values[:, None]).view(-1))
    denominator = torch.zeros_like(numerator).scatter_add(0, index, weight.reshape(-1))
    return ((numerator / denominator.clamp_min(1e-12))[st.index] * weight).sum(1)


def projected_g2p(scene, st, v_grid, state, dt, *rest):
    """``step.g2p`` with J advanced by the grid-projected divergence P(tr C) instead of the particle's own."""
    new = PARTICLE_G2P(scene, st, v_grid, state, dt, *rest)
    divergence = new.C.diagonal(dim1=-2, dim2=-1).sum(-1)
    return State(x=new.x, v=new.v, C=new.C, J=state.J * (1.0 + dt * project(st, divergence, scene.grid.num_nodes)))


def relaxed_g2p(scene, st, v_grid, state, dt, *rest):
    """``step.g2p`` with J, after its own update, relaxed towards P(J) at the rate 1 / ``RELAXATION_TIME``."""
    new = PARTICLE_G2P(scene, st, v_grid, state, dt, *rest)
    smooth = project(st, new.J, scene.grid.num_nodes)
    return State(x=new.x, v=new.v, C=new.C, J=new.J + (dt / RELAXATION_TIME) * (smooth - new.J))


VARIANTS = {"projected": projected_g2p, "relaxed": relaxed_g2p}


def volume_rate(kind: str):
    """Context in which the simulator uses its own volume rate (``particle``) or a study variant."""
    if kind == "particle":
        return nullcontext()
    return mock.patch.object(mpm_step, "g2p", VARIANTS[kind])


FORMER = dict(flip=0.0, volume_relaxation=0.0)  # the numerics this study examined


def simulator(mu: float, config: SimConfig) -> StirringSimulator:
    if config.dim == 2:
        config = config.replace(settle_time=0.0)
    return StirringSimulator(Newtonian(eta=mu), RIG, config.replace(**FORMER), density=1000.0)


def drag(kind: str, mu: float, sound_speed: float) -> tuple[float, float, float]:
    """(drag over exact, rms of J − 1 within two cells of the rod, mean J − 1 there) after 1 s at 1 mm/s."""
    speed, duration = 1e-3, 1.0
    sim = simulator(mu, SimConfig(dim=2, dx=DX, sound_speed=sound_speed))
    with volume_rate(kind), torch.no_grad():
        result = sim(translate((speed, 0.0), duration=duration, start=(-0.5 * speed * duration, 0.0)))
    steady = -result.force[int(0.7 * len(result.force)):, 0].mean().item()
    axis = torch.tensor([0.5 * speed * duration, 0.0], dtype=result.state.x.dtype)
    near = (result.state.x - axis).norm(dim=1) < A + 2 * DX
    j = result.state.J[near] - 1.0
    return steady / translating_rod_force(mu, speed, A, B), j.pow(2).mean().sqrt().item(), j.mean().item()


def slow(dx: float, sound_speed: float, mu: float = 0.2, speed: float = 0.02) -> float:
    """Mean horizontal force over the last half of a 1.6 s circular stir [N/m] at ``speed`` [m/s], ``mu`` [Pa s]."""
    sim = simulator(mu, SimConfig(dim=2, dx=dx, sound_speed=sound_speed))
    with torch.no_grad():
        force = sim(circle(radius=0.015, speed=speed, duration=1.6)).force.norm(dim=1)
    return force[len(force) // 2:].mean().item()


def stir(kind: str) -> tuple[float, float]:
    """(mean horizontal force over the last 40 % [N/m], share of evenly filled particles) after a 3 s stir."""
    sim = simulator(0.2, SimConfig(dim=2, dx=DX, sound_speed=2.0))
    with volume_rate(kind), torch.no_grad():
        result = sim(circle(radius=0.015, speed=0.1, duration=3.0))
        buffer, stencil = mpm_step.p2g(sim.scene, result.state, 1e-9)
    force = result.force.norm(dim=1)
    node_mass = buffer[:, sim.scene.dim][stencil.index]
    away_from_wall = (B - result.state.x.norm(dim=1)) > 3 * DX
    filled = (node_mass > 0.5 * sim.scene.node_mass).all(1)
    return force[int(0.6 * len(force)):].mean().item(), (filled & away_from_wall).float().sum().item() / len(filled)


def rest3d(kind: str) -> float:
    sim = simulator(0.1, SimConfig(dim=3, dx=0.01, sound_speed=4.5, cfl=0.45))
    trajectory = stationary(8.0)
    start = sim.initial_state(trajectory)
    with volume_rate(kind), torch.no_grad():
        result = sim(trajectory, initial=start)
    return (result.state.x[:, 2].mean() / start.x[:, 2].mean()).item()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", nargs="+", default=["drag", "slow", "stir", "rest3d"],
                        choices=["drag", "slow", "stir", "rest3d"])
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, {platform.machine()}, "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at start, torch {torch.__version__}, "
          "1 thread, float32")
    if "drag" in args.parts:
        print("\n| volume rate | mu [Pa s] | c [m/s] | drag / exact | rms(J - 1) near rod | mean(J - 1) near rod |")
        print("|---|---|---|---|---|---|")
        for kind in ("particle", "projected", "relaxed"):
            for mu in (1.0, 0.2):
                for c in (1.0, 2.0, 4.0):
                    ratio, rms, mean = drag(kind, mu, c)
                    print(f"| {kind} | {mu:g} | {c:g} | {ratio:.3f} | {rms:.2e} | {mean:+.1e} |", flush=True)
    if "slow" in args.parts:
        print("\n| cells [mm] | c [m/s] | force at 0.02 m/s, 0.2 Pa s [N/m] |")
        print("|---|---|---|")
        for dx, speeds in ((0.0025, (1.0, 2.0, 4.0)), (0.002, (1.0, 2.0))):
            for c in speeds:
                print(f"| {dx * 1e3:g} | {c:g} | {slow(dx, c):.4f} |", flush=True)
        print("\n| speed [m/s] | force, 2.5 mm [N/m] | force, 2 mm [N/m] | ratio | d ln F / d ln eta, 2.5 mm |")
        print("|---|---|---|---|---|")
        for speed in (0.02, 0.04, 0.08):
            coarse, fine = slow(0.0025, 2.0, speed=speed), slow(0.002, 2.0, speed=speed)
            low, high = (slow(0.0025, 2.0, mu, speed) for mu in (0.2 / 1.25, 0.2 * 1.25))
            elasticity = math.log(high / low) / math.log(1.25**2)
            print(f"| {speed:g} | {coarse:.4f} | {fine:.4f} | {coarse / fine:.3f} | {elasticity:.3f} |", flush=True)
    if "stir" in args.parts:
        print("\n| volume rate | mean force, last 40 % [N/m] | evenly filled particles |")
        print("|---|---|---|")
        for kind in ("particle", "projected", "relaxed"):
            force, filled = stir(kind)
            print(f"| {kind} | {force:.4f} | {filled:.3f} |", flush=True)
    if "rest3d" in args.parts:
        print("\n| volume rate | 3-D rest, 8 s: centre of mass height after / before |")
        print("|---|---|")
        for kind in ("particle", "projected", "relaxed"):
            print(f"| {kind} | {rest3d(kind):.3f} |", flush=True)


if __name__ == "__main__":
    main()
