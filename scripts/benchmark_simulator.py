"""Time the simulator: ms per step forward and forward+backward, and peak memory, in one process.

    python scripts/benchmark_simulator.py [--steps 100] [--scenes paper3d slice2d fine3d]

The reference run is the forward pass without gradients in the same process; ratios against it are what to
compare across machines. Peak memory is the process's maximum resident set size (Linux ru_maxrss).
"""

from __future__ import annotations

import argparse
import datetime
import platform
import resource
import time

import torch

from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.rheology import Carreau
from diffstir.rig import Rig
from diffstir.trajectory import circle

SCENES = {
    "paper3d": SimConfig(dim=3, dx=0.01, sound_speed=4.5, cfl=0.45, dt=1e-3, settle_time=0.3),
    "fine3d": SimConfig(dim=3, dx=0.005, sound_speed=10.0, settle_time=0.3),
    "slice2d": SimConfig(dim=2, dx=0.0025, sound_speed=2.0),
}


def run(name: str, config: SimConfig, steps: int) -> dict:
    law = Carreau(eta0=1.0, eta_inf=0.01, lam=0.5, n=0.6)
    sim = StirringSimulator(law, Rig(), config, density=1000.0)
    probe = circle(0.015, 0.1, 1.0, ramp_time=0.2)
    dt = sim.time_step(probe)
    trajectory = circle(0.015, 0.1, steps * dt, ramp_time=0.2)
    initial = sim.initial_state(trajectory)
    timings = {}
    for label, grad in (("forward", False), ("forward+backward", True)):
        for _ in range(2):  # the second run is the one timed (warm, as inside an optimisation loop)
            start = time.perf_counter()
            with torch.set_grad_enabled(grad):
                result = sim(trajectory, initial=initial)
                if grad:
                    result.force.abs().mean().backward()
            elapsed = time.perf_counter() - start
        timings[label] = 1e3 * elapsed / len(result.times)
    return {"scene": name, "particles": initial.num_particles, "grid": "x".join(map(str, sim.scene.grid.shape)),
            "dt_ms": 1e3 * result.dt, **timings}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"{datetime.date.today()} {platform.machine()} {platform.processor() or ''} torch {torch.__version__}, "
          f"{args.threads} threads, {args.steps} steps, float32")
    print("| scene | particles | grid | dt [ms] | forward [ms/step] | fwd+bwd [ms/step] | ratio |")
    print("|---|---|---|---|---|---|---|")
    for name in args.scenes:
        r = run(name, SCENES[name], args.steps)
        print(f"| {r['scene']} | {r['particles']} | {r['grid']} | {r['dt_ms']:.3f} | {r['forward']:.2f} | "
              f"{r['forward+backward']:.2f} | {r['forward+backward'] / r['forward']:.2f} |")
    print(f"peak resident memory: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB")


if __name__ == "__main__":
    main()
