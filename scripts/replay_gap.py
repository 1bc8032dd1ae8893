"""How far the fitter's replay of a recording is from the virtual lab's truth when both simulate the same fluid
with the same numerics: the gap that the rod's replayed path alone leaves (``diffstir.trajectory.through_samples``).

The case is the clean recording of ``diagnosis_benchmark.py``'s base fluid, read without noise; the fitter's
reading of the true law at the true density is compared with it, for the replay along the samples' chords and
along the spline through them.

    python scripts/replay_gap.py --fluid syrup_2Pas
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np
import torch

from diagnosis_benchmark import SENSOR, Lab, coarse, fluids
from diffstir.diagnosis.base import simulated_reading
from diffstir.fitting.problem import StirProblem, Windows
from diffstir.trajectory import Trajectory


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fluid", default="syrup_2Pas", choices=list(fluids()), help="base fluid of the benchmark")
    args = parser.parse_args()
    torch.set_num_threads(1)
    config = coarse()
    lab = Lab(fluids()[args.fluid], config)
    recording = lab.reread(replace(SENSOR, noise_std=0.0, resolution=0.0), seed=0)
    problem = StirProblem(recording, config, lab.fluid.density, Windows.of(recording, None, 0.0))
    law = lab.fluid.make_law()
    chords = Trajectory(t=recording.t, xy=np.stack([recording.x, recording.y], axis=-1), z=0.0, angle=0.0)
    print(f"{args.fluid}: {recording.t.size} samples at {SENSOR.sample_rate:g} Hz from {recording.t[0]:g} s; "
          f"reading rms {np.sqrt(np.mean(problem.measured ** 2)) * 1e3:.1f} mN")
    print("| replay | mean abs gap [mN] | largest [mN] |\n|---|---|---|")
    for name, trajectory in (("chords", chords), ("spline", problem.trajectory)):
        problem.trajectory = trajectory
        gap = problem.measured - simulated_reading(problem, law)
        print(f"| {name} | {np.mean(np.abs(gap)) * 1e3:.3f} | {np.max(np.abs(gap)) * 1e3:.2f} |", flush=True)


if __name__ == "__main__":
    main()
