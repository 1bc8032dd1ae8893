"""Archimedes density on virtual-lab recordings: the bias of the estimate and the coverage of its 95 % interval.

For each fluid density, the lab synthesises the density block (rod weight in air G, immersed reading R, depth h on
a 0.1 mm ruler) with a sensor preset, and diffstir.density estimates rho ± u from it. One recording (seed 0) per
row, and the mean bias and the interval's coverage over many seeds. Writes a markdown table to stdout.

    python scripts/lab_density_bias.py [--seeds 2000] [--sensor paper thin_film_one_sided]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import yaml

from diffstir.density import estimate_density
from diffstir.lab import SensorModel, density_block
from diffstir.rig import Rig

# the paper's Table I reference densities (kg/m^3) and its castor oil estimate (Table II)
FLUIDS = {"castor oil": 866.88, "water": 1000.0, "diluted syrup": 1139.3, "F60 syrup": 1290.0,
          "starch A": 1563.7, "starch B": 1845.5}
CONF = Path(__file__).resolve().parents[1] / "conf" / "lab" / "sensor"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2000)
    parser.add_argument("--sensor", nargs="+", default=["paper", "thin_film_one_sided"])
    args = parser.parse_args()
    rig = Rig()
    print("| sensor | fluid | rho true | rho est (seed 0) ± u | bias (seed 0) | mean bias over seeds | "
          "95 % interval covers |")
    print("|---|---|---|---|---|---|---|")
    for preset in args.sensor:
        sensor = SensorModel(**yaml.safe_load((CONF / f"{preset}.yaml").read_text()))
        for name, rho in FLUIDS.items():
            estimates = []
            for seed in range(args.seeds):
                m, _ = density_block(rho, rig, sensor, np.random.default_rng(seed))
                est = estimate_density(m, rod_radius=rig.rod.radius, force_resolution=sensor.resolution)
                estimates.append((est.value, est.std, est.ci95[0] <= rho <= est.ci95[1]))
            values, stds, covered = (np.array(c) for c in zip(*estimates))
            print(f"| {preset} | {name} | {rho:.1f} | {values[0]:.1f} ± {stds[0]:.1f} | "
                  f"{100 * (values[0] / rho - 1):+.2f} % | {100 * (values.mean() / rho - 1):+.3f} % | "
                  f"{100 * covered.mean():.1f} % |")


if __name__ == "__main__":
    main()
