"""The sequential mode in the virtual lab: stir, analyse, plan the next stir, until the family is decided or the
budget is spent (docs/planning.md, The sequential mode).

Each stir's truth is simulated on ``conf/lab/sim/truth2d.yaml`` (2-D MPM, 2 mm cells, finer than the fit: truth
2-D MPM) and read through the paper's sensor (``conf/lab/sensor/paper.yaml``, seed ``--seed`` + the stir's index).
The stirs so far are analysed together as ``diffstir-fit experiment=flow_curve recordings=[...]`` does, and
``planning.next_segment`` gives the next stir, as ``diffstir-plan after=REPORT`` does, with the paper rig's shipped
calibration. The first stir holds two speeds (``--first``, a factor 4 apart by default) for half a segment each:
the flow-curve analysis needs two resolved speeds; each later stir holds one speed from rest.

    python scripts/sequential_stir.py --fluid carreau_example --out FILE.json [--first 0.02 0.08] [--seed 0]
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import time
from pathlib import Path

import torch
from identification_benchmark import sensor_preset, sim
from plan_benchmark import FLUIDS, against_truth, fluid_named, truth_family

from diffstir.behaviour import BehaviourSettings, characterise
from diffstir.lab import programme_path
from diffstir.lab.synth import read_truth, simulate_truth
from diffstir.planning import PlanSettings, Prior
from diffstir.planning.calibration import SHIPPED, Calibration
from diffstir.planning.sequential import FIRST_SPEEDS, StirSoFar, first_stir, next_segment


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fluid", choices=list(FLUIDS), required=True)
    parser.add_argument("--first", type=float, nargs="+", default=list(FIRST_SPEEDS),
                        help="the first stir's speeds [m/s]")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, required=True, help="JSON of the steps")
    args = parser.parse_args()
    torch.set_num_threads(1)
    settings, prior = PlanSettings(), Prior()
    calibration = Calibration.from_dict(json.loads(next(SHIPPED.glob("calibration-*.json")).read_text()))
    fluid = fluid_named(args.fluid)
    programme = first_stir(settings, tuple(args.first))
    steps, recordings = [], []
    while True:
        started = time.perf_counter()
        trajectory = programme_path(programme)
        truth = simulate_truth(fluid, trajectory, sim_config=sim("lab/sim/truth2d.yaml"))
        recordings.append(read_truth(truth, sensor_preset("paper"), seed=args.seed + len(recordings),
                                     name=f"{args.fluid}_{len(recordings)}").recording)
        simulated = time.perf_counter() - started
        result = characterise(recordings, config=sim("sim/slice2d.yaml"), workers=args.workers,
                              settings=BehaviourSettings(analysis="flow_curve"))
        summary = result.summary()
        so_far = StirSoFar.from_report(summary)
        planning = time.perf_counter()
        step = next_segment(so_far, calibration, prior, settings)
        planned = time.perf_counter() - planning
        rates = [p["shear_rate"] for p in summary["points"]]
        points = [{k: p[k] for k in ("speed", "shear_rate", "viscosity", "viscosity_ci95")} for p in summary["points"]]
        against_truth(points, fluid)
        steps.append({"fluid": args.fluid, "seed": args.seed, "programme": programme, "elapsed": so_far.elapsed,
                      "truth_family": truth_family(fluid.law, (min(rates), max(rates))),
                      "analysis_class": summary["behaviour"]["class"],
                      "analysis_confidence": summary["behaviour"]["confidence"],
                      "points": points,
                      "step": step.to_dict(), "truth_seconds": simulated, "plan_seconds": planned,
                      "seconds": time.perf_counter() - started,
                      "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="minutes"),
                      "machine": f"{platform.machine()}, {args.workers} processes of 1 torch thread"})
        args.out.write_text(json.dumps(steps, indent=1, default=float))
        print(f"{so_far.elapsed:.3g} s: {step.family} ({step.confidence:.3g}), next "
              f"{'-' if step.speed is None else f'{step.speed:g} m/s'}, {steps[-1]['seconds']:.0f} s", flush=True)
        if step.speed is None:
            break
        programme = step.programme(settings.radius)

if __name__ == "__main__":
    main()
