"""What the force's derivatives cost, as ratios to a plain rollout in the same process (docs/benchmarks.md).

For a Carreau fluid (four parameters) stirred on a 15 mm circle, on each ``--sims`` scene (``conf/sim``), times

* ``plain``: one rollout without gradients (the reference, ratio 1);
* ``reverse``: one rollout and the backward pass of mean |F| through the checkpointed rollout: the gradient of one
  scalar with respect to every parameter;
* ``forward mode``: ``diffstir.mpm.force_sensitivities`` for all four parameters: the whole Jacobian
  d F(t) / d p, exact, one dual rollout per parameter;
* ``finite differences``: the same Jacobian by forward differences, one extra rollout per parameter (approximate).

Each method runs ``--repeats`` times, interleaved with the others, and the fastest run counts: on a shared machine
the ratios move much less than the seconds.

    python scripts/benchmark_sensitivities.py [--sims coarse2d slice2d] [--duration 0.5] [--repeats 2]
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import time
from pathlib import Path

import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from diffstir.mpm import StirringSimulator, force_sensitivities
from diffstir.rheology import Carreau
from diffstir.rig import Rig
from diffstir.trajectory import circle

CONF = Path(__file__).resolve().parents[1] / "conf" / "sim"


def methods(sim: StirringSimulator, trajectory) -> dict:
    law = sim.material.law

    def plain():
        with torch.no_grad():
            sim(trajectory)

    def reverse():
        sim.zero_grad()
        sim(trajectory).force.abs().mean().backward()

    def forward_mode():
        force_sensitivities(sim, trajectory)

    def finite_differences():
        values = law.parameters_si()
        with torch.no_grad():
            sim(trajectory)
            for name, value in values.items():
                law.set_parameters_si(**{name: value * (1 + 1e-3)})
                sim(trajectory)
                law.set_parameters_si(**{name: value})

    return {"plain": plain, "reverse": reverse, "forward mode": forward_mode,
            "finite differences": finite_differences}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sims", nargs="+", default=["coarse2d", "slice2d"], help="conf/sim presets")
    parser.add_argument("--duration", type=float, default=0.5, help="stirring time [s]")
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, {platform.machine()}, "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} at start, torch {torch.__version__}, "
          f"1 thread; Carreau (4 parameters), circle r = 15 mm at 0.05 m/s for {args.duration:g} s")
    print("| sim | steps | method | what it gives | wall [s] | ratio to plain |")
    print("|---|---|---|---|---|---|")
    gives = {"plain": "F(t)", "reverse": "gradient of one scalar", "forward mode": "d F(t)/d p, exact",
             "finite differences": "d F(t)/d p, approximate"}
    for name in args.sims:
        sim = StirringSimulator(Carreau(eta0=1.0, eta_inf=0.01, lam=0.5, n=0.6), Rig(),
                                instantiate(OmegaConf.load(CONF / f"{name}.yaml")), density=1000.0)
        trajectory = circle(radius=0.015, speed=0.05, duration=args.duration, ramp_time=0.1)
        runs = methods(sim, trajectory)
        runs["plain"]()  # settle, cache and warm up
        best = {k: float("inf") for k in runs}
        for _ in range(args.repeats):
            for key, run in runs.items():
                started = time.perf_counter()
                run()
                best[key] = min(best[key], time.perf_counter() - started)
        steps = round(args.duration / sim.time_step(trajectory))
        for key in runs:
            print(f"| {name} | {steps} | {key} | {gives[key]} | {best[key]:.2f} | {best[key] / best['plain']:.1f} |")


if __name__ == "__main__":
    main()
