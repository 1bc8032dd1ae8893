"""Where a simulation resolution's own loss minimum lies: the paper's loss and the mean |reading| of Newtonian
fluids on a virtual-lab recording, over a list of viscosities (docs/accuracy-2d.md, Newtonian fluids).

The recording is the one ``identification_benchmark.py --part newtonian`` makes for the same true viscosity and
seed (the seed there is ``--seed`` + the viscosity's index in its list: 3 for 0.2 Pa·s, 6 for 10 Pa·s with the
defaults). Each viscosity costs one forward simulation on ``--sim``.

    python scripts/loss_scan.py --eta-true 10 --seed 6 --sim sim/slice2d.yaml --etas 10 10.5 11.3 12.5

``--frozen-at`` simulates each viscosity with the sound speed of another (``StirProblem.frozen``), as a fit holds
the sound speed of its start (``fitting.fit_model``): ``--etas 1 1 1 --frozen-at 0.8 1 1.25`` reads 1 Pa·s at
the sound speeds of 0.8, 1 and 1.25 Pa·s, the size of the bias a start that far off leaves in the reading.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from diffstir.density import density_estimate
from diffstir.fitting.models import FitModel
from diffstir.fitting.optimise import Readings
from diffstir.fitting.problem import StirProblem, Windows
from diffstir.lab import Fluid, stirring_programme, synthesise
from identification_benchmark import NEWTONIAN_PROGRAMME, RADIUS, RAMP, sensor_preset, sim


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eta-true", type=float, required=True, help="the lab fluid's viscosity [Pa s]")
    parser.add_argument("--seed", type=int, required=True, help="the lab sensor's noise seed")
    parser.add_argument("--sim", default="sim/slice2d.yaml", help="fitting resolution, a file under conf/")
    parser.add_argument("--etas", type=float, nargs="+", required=True, help="viscosities to simulate [Pa s]")
    parser.add_argument("--sensor", default="paper", help="sensor preset in conf/lab/sensor/")
    parser.add_argument("--frozen-at", type=float, nargs="+", default=None, help="simulate each of --etas at the "
                        "sound speed of this viscosity [Pa s] (one per viscosity; default: its own)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    trajectory = stirring_programme(NEWTONIAN_PROGRAMME, radius=RADIUS, ramp_time=RAMP)
    fluid = Fluid(name=f"newtonian {args.eta_true:g}", density=1000.0,
                  law={"name": "newtonian", "params": {"eta": args.eta_true}})
    recording = synthesise(fluid, trajectory, sim_config=sim("lab/sim/truth2d.yaml"),
                           sensor=sensor_preset(args.sensor), seed=args.seed).recording
    problem = StirProblem(recording, sim(args.sim), density_estimate(recording, None)["value"],
                          Windows.of(recording, None, 0.25))
    print(f"truth {args.eta_true:g} Pa s, seed {args.seed}, fitted on {args.sim}; "
          f"measured mean |reading| {problem.mean_reading():.5f} N\n")
    frozen_at = args.frozen_at or args.etas
    if len(frozen_at) != len(args.etas):
        raise SystemExit(f"--frozen-at gives {len(frozen_at)} viscosities for {len(args.etas)} in --etas")
    print("| η [Pa·s] | sound speed of η [Pa·s] | c [m/s] | mean \\|reading\\| [N] | loss [N] | s |")
    print("|---|---|---|---|---|---|")
    for eta, eta_c in zip(args.etas, frozen_at):
        t0 = time.perf_counter()
        held = problem.frozen(FitModel.named("newtonian", eta=eta_c).material)
        reading = Readings(held, FitModel.named("newtonian", eta=eta))(np.log([eta]))
        print(f"| {eta:g} | {eta_c:g} | {held.config.fixed_sound_speed:.3f} | {problem.mean_reading(reading):.5f} | "
              f"{problem.loss(reading):.5f} | {time.perf_counter() - t0:.0f} |", flush=True)


if __name__ == "__main__":
    main()
