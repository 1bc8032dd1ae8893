"""How much a fit's reading moves when the fluid settles at the sound speed the fit holds (docs/identification.md,
step 5, "Held, not settled at it").

A fit holds the sound speed c its starting law gets (``StirProblem.frozen``, ``SimConfig.rollout_sound_speed``) and
the fluid settles at the least sound speed, as the unheld simulator and the virtual lab's truth do; settling at c
instead starts from another particle arrangement. For Newtonian fluids of ``--viscosities`` on a recording (default:
the bundled example), this prints c and the mean |reading| both ways, and their rms difference over the rms reading.
``--sim`` names a weakly compressible preset (default: the fit's coarse stage); a projection has no sound speed.

    python scripts/settling_sound_speed.py [--recording DIR] [--sim coarse2d] [--viscosities 0.2 1 3]
"""

from __future__ import annotations

import argparse
import datetime
import platform
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from diffstir.fitting.models import FitModel
from diffstir.fitting.optimise import Readings
from diffstir.fitting.problem import StirProblem
from diffstir.recording import load_recording

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--recording", default=str(ROOT / "diffstir/data/examples/carreau_example"))
    parser.add_argument("--sim", default="coarse2d", help="a weakly compressible preset, a file of conf/sim/")
    parser.add_argument("--density", type=float, default=1050.0, help="the fluid's density [kg/m³]")
    parser.add_argument("--viscosities", type=float, nargs="+", default=[0.2, 1.0, 3.0], help="Pa s")
    args = parser.parse_args()
    torch.set_num_threads(1)
    config = instantiate(OmegaConf.load(ROOT / "conf/sim" / f"{args.sim}.yaml"))
    if config.pressure != "compressible":
        parser.error(f"--sim {args.sim}: pressure={config.pressure} has no sound speed to hold; "
                     "choose a compressible preset (coarse2d)")
    problem = StirProblem(load_recording(args.recording), config, args.density)
    print(f"{datetime.date.today()}, {platform.machine()}, torch {torch.__version__}, 1 thread; {args.recording} "
          f"on {args.sim}")
    print("| η [Pa·s] | held c [m/s] | mean \\|reading\\|, settled at the least c [mN] | settled at the held c [mN] "
          "| rms difference / rms reading |\n|---|---|---|---|---|")
    for eta in args.viscosities:
        model = FitModel.named("newtonian", eta=eta)
        held = problem.frozen(model.material)
        c = held.config.fixed_sound_speed
        settled_at_c = problem.with_config(replace(problem.config, sound_speed=c, compressibility=None,
                                                   rollout_sound_speed=None))
        a, b = (Readings(p, model)(model.theta()) for p in (held, settled_at_c))
        print(f"| {eta:g} | {c:.2f} | {1e3 * np.mean(np.abs(a)):.3f} | {1e3 * np.mean(np.abs(b)):.3f} | "
              f"{np.sqrt(np.mean((a - b) ** 2) / np.mean(a ** 2)):.4f} |", flush=True)


if __name__ == "__main__":
    main()
