"""The stir's effective shear rate on the bundled example: how it depends on the probe's flow index and on the
viscosity, and the rate at which the example's Carreau truth reads like a Newtonian fluid (docs/identification.md).

    python scripts/effective_shear_rate.py [--recording diffstir/data/examples/carreau_example]

On the coarse fitting grid (``conf/sim/coarse2d.yaml``), over identify's default window. For a probe of index n and
viscosity η_N at U/a, its Newtonian equivalent is η_N exp(ln(F_n / F_N) / s), with F the mean |reading| and
s = d ln F / d ln η at η_N, and γ̇ = U/a (η_eq / η_N)^(1/(n-1)). The last line solves η_truth(γ̇) = η_eq of the
truth law's own readings.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf
from scipy.optimize import brentq

from diffstir.fitting.initial import characteristic_shear_rate, effective_shear_rate
from diffstir.fitting.models import FitModel
from diffstir.fitting.optimise import Readings
from diffstir.fitting.problem import StirProblem, Windows
from diffstir.lab import make_fluid_law, truth_path
from diffstir.recording import load_recording

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recording", type=Path, default=ROOT / "diffstir/data/examples/carreau_example")
    parser.add_argument("--viscosities", type=float, nargs="+", default=[0.01, 0.1, 1.0, 10.0], help="Pa s")
    args = parser.parse_args()
    torch.set_num_threads(1)
    rec = load_recording(args.recording)
    truth = json.loads(truth_path(args.recording).read_text())
    config = instantiate(OmegaConf.load(ROOT / "conf/sim/coarse2d.yaml"))
    problem = StirProblem(rec, config, truth["fluid"]["density"], Windows.of(rec, 2.0, 0.25))
    rate0 = characteristic_shear_rate(problem)

    def mean(name: str, **params) -> float:
        model = FitModel.named(name, **params)
        return problem.mean_reading(Readings(problem, model)(model.theta()))

    law = make_fluid_law(truth["fluid"]["law"]).double()
    f_truth = mean(truth["fluid"]["law"]["name"], **truth["fluid"]["law"]["params"])
    # the truth's Newtonian equivalent on this grid: bisect the Newtonian reading in ln η
    eta_eq = math.exp(brentq(lambda x: math.log(mean("newtonian", eta=math.exp(x)) / f_truth), -5.0, 3.0,
                             xtol=1e-3))
    print(f"U/a = {rate0:.3f} 1/s; the truth's Newtonian equivalent on this grid: {eta_eq:.4g} Pa s\n")
    print("| probe | η_N [Pa s] | γ̇_eff [1/s] |\n|---|---|---|")
    f_n, f_h = mean("newtonian", eta=eta_eq), mean("newtonian", eta=eta_eq * math.exp(0.15))
    s = math.log(f_h / f_n) / 0.15
    for n in (0.5, 0.7, 0.85):
        f_p = mean("power_law", k=eta_eq * rate0 ** (1 - n), n=n)
        rate = rate0 * math.exp(math.log(f_p / f_n) / s / (n - 1))
        print(f"| single power law, n = {n} | {eta_eq:.4g} | {rate:.3g} |")
    for eta in [eta_eq] + args.viscosities:
        print(f"| pair n = 1 ± 0.15 (identify) | {eta:.4g} | {effective_shear_rate(problem, eta):.3g} |", flush=True)
    rate = brentq(lambda g: float(law(torch.tensor([g], dtype=torch.float64)).detach()) - eta_eq, 1e-3, 1e3)
    print(f"\nthe truth law {truth['fluid']['law']} has its Newtonian-equivalent viscosity at {rate:.3g} 1/s")


if __name__ == "__main__":
    main()
