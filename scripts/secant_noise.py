"""How short a secant step the simulated readings allow: d ln p / d ln η over steps h in ln η, against central
finite differences, and the gap between float32 and float64 readings.

The Newtonian benchmark's 3 Pa·s case (``identification_benchmark.py --part newtonian``: the lab's 2-D truth,
the paper's sensor, one 15 mm circle at 0.1 m/s for 1.3 s, seed 5) fitted on the default grid
(``conf/sim/slice2d.yaml``). The elasticity over a step h is the least-squares ratio
e(h) = (p(θ + h) − p(θ))·p(θ) / (h p(θ)·p(θ)), θ = ln η; its error is about the readings' relative noise
between nearby viscosities divided by h, which is why ``fitting.optimise`` makes no Broyden update over a step
shorter than ``SECANT_FRACTION`` · ``FD_STEP``.

    python scripts/secant_noise.py [--eta 3.0] [--steps 6.4e-4 2e-3 1e-2 5e-2]
"""

from __future__ import annotations

import argparse
import math
import platform
import time
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import torch
import yaml
from hydra.utils import instantiate
from omegaconf import OmegaConf

from diffstir.fitting.optimise import FD_STEP, SECANT_FRACTION
from diffstir.fitting.problem import StirProblem
from diffstir.lab import Fluid, SensorModel, stirring_programme, synthesise
from diffstir.rheology import Newtonian

CONF = Path(__file__).resolve().parents[1] / "conf"
PROGRAMME = [{"speed": 0.1, "duration": 1.3}]  # m/s, s: the Newtonian benchmark's stir
RADIUS, RAMP = 0.015, 0.2                       # m, s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eta", type=float, default=3.0, help="Pa s, the lab fluid and the point θ = ln η")
    parser.add_argument("--density", type=float, default=1000.0, help="kg/m^3")
    parser.add_argument("--seed", type=int, default=5, help="the benchmark's seed for 3 Pa s")
    parser.add_argument("--steps", type=float, nargs="+", default=[6.4e-4, 2e-3, SECANT_FRACTION * FD_STEP["log"],
                                                                   FD_STEP["log"]], help="secant steps h in ln η")
    args = parser.parse_args()
    torch.set_num_threads(1)
    started = time.perf_counter()
    truth = instantiate(OmegaConf.load(CONF / "lab" / "sim" / "truth2d.yaml"))
    fine = instantiate(OmegaConf.load(CONF / "sim" / "slice2d.yaml"))
    sensor = SensorModel(**yaml.safe_load((CONF / "lab" / "sensor" / "paper.yaml").read_text()))
    trajectory = stirring_programme(PROGRAMME, radius=RADIUS, ramp_time=RAMP)
    fluid = Fluid(name=f"newtonian {args.eta:g}", density=args.density,
                  law={"name": "newtonian", "params": {"eta": args.eta}})
    lab = synthesise(fluid, trajectory, sim_config=truth, sensor=sensor, seed=args.seed)
    problem = StirProblem(lab.recording, fine, args.density)

    def readings(log_eta: float, config=fine) -> np.ndarray:
        with torch.no_grad():
            p = problem.with_config(config).simulate(Newtonian(eta=math.exp(log_eta)))
        return p.double().cpu().numpy()[problem.train]

    theta = math.log(args.eta)
    p0 = readings(theta)
    p64 = readings(theta, replace(fine, dtype="float64"))
    print(f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, {platform.machine()}, torch {torch.__version__}, "
          f"{torch.get_num_threads()} thread; eta = {args.eta:g} Pa s on conf/sim/slice2d.yaml, "
          f"{p0.size} samples")
    print(f"float32 readings against float64 ones at the same eta, |p32 - p64| / |p64|: "
          f"{np.linalg.norm(p0 - p64) / np.linalg.norm(p64):.2e}")
    h = FD_STEP["log"]
    central = float((readings(theta + h) - readings(theta - h)) @ p0 / (2 * h * (p0 @ p0)))
    print(f"central finite difference over ±{h:g}: d ln p / d ln eta = {central:.3f}\n")
    print("| secant step h in ln eta | d ln p / d ln eta | / central | Broyden update (h >= "
          f"{SECANT_FRACTION * FD_STEP['log']:g}) |")
    print("|---|---|---|---|")
    for step in args.steps:
        secant = float((readings(theta + step) - p0) @ p0 / (step * (p0 @ p0)))
        used = "yes" if step >= SECANT_FRACTION * FD_STEP["log"] else "no"
        print(f"| {step:.2g} | {secant:.3f} | {secant / central:.2f} | {used} |", flush=True)
    print(f"\n{time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
