"""Behaviour classification on virtual-lab fluids of every class, borderline ones included: the confusion matrix.

Each fluid is stirred by the lab (``diffstir.lab.synthesise``) along one programme of constant speeds (``--speeds``,
default four a factor 2 apart from 0.02 m/s, ``--segment`` s each), read through a sensor preset (``--sensor``,
default the paper's; noise seed ``--seed`` plus the fluid's place in ``FLUIDS``), and classified by
``diffstir.behaviour.characterise`` with ``--iterations`` Gauss-Newton steps per window, and with the laws of
``--joint-models`` fitted to every speed at once (default none: the per-speed points alone decide; with laws with
and without a yield stress, the joint fit decides the yield stress, ``docs/behaviour.md`` step 4) side by side in
``--workers`` processes.
The windows are fitted on ``--fit-sim`` (default ``conf/sim/slice2d.yaml``, 2.5 mm) with its relative force
error ``--model-error`` (default 0.03, that grid's) in every window's interval; the truth is simulated on
``--truth-sim`` (default ``conf/lab/sim/truth2d.yaml``, 2 mm; ``--truth-dx`` changes its cells), finer than the
fit, so the fit meets a discretisation gap. Prints one row per fluid and the confusion matrix as markdown.

    python scripts/behaviour_benchmark.py [--fluids castor_oil ...] [--sensor ideal] [--out DIR]
    python scripts/behaviour_benchmark.py --joint-models power_law herschel_bulkley --workers 2
    python scripts/behaviour_benchmark.py --fit-sim sim/coarse2d.yaml --truth-sim sim/coarse2d.yaml \
        --truth-dx 0.004 --model-error 0.063    # the 5 mm grid against a 4 mm truth, about 4x faster
    python scripts/behaviour_benchmark.py --speeds 0.005 0.01 0.02 0.04 0.08 0.16   # slower speeds too
    python scripts/behaviour_benchmark.py --joint-models power_law --slope-test joint_index   # the joint index decides
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import yaml
from hydra.utils import instantiate
from omegaconf import OmegaConf

from diffstir.behaviour import CLASSES, SLOPE_TESTS, BehaviourSettings, characterise
from diffstir.behaviour.classify import slope_agreement
from diffstir.behaviour.pipeline import reclassify, reported_joint_index
from diffstir.fitting.uncertainty import MODEL_FORCE_ERROR
from diffstir.lab import Fluid, SensorModel, stirring_programme, synthesise
from diffstir.recording import RecordingError

ROOT = Path(__file__).resolve().parents[1]
SPEEDS = (0.02, 0.04, 0.08, 0.16)  # m/s, the programme's default speeds
SEGMENT = 0.8                       # s per speed, by default
RADIUS = 0.015                      # m

#: name: (true class, law spec (SI), density kg/m^3); "borderline" fluids sit near a class boundary.
FLUIDS = {
    "castor_oil": ("newtonian", {"name": "newtonian", "params": {"eta": 0.65}}, 961.0),
    "glycerol_like": ("newtonian", {"name": "newtonian", "params": {"eta": 0.2}}, 1250.0),
    "jam_like_carreau": ("shear_thinning",
                         {"name": "carreau", "params": {"eta0": 2.0, "eta_inf": 0.05, "lam": 1.0, "n": 0.4}}, 1330.0),
    "borderline_thinning_n0.9": ("shear_thinning", {"name": "power_law", "params": {"k": 0.4, "n": 0.9}}, 1050.0),
    "thickening_n1.3": ("shear_thickening", {"name": "power_law", "params": {"k": 0.3, "n": 1.3}}, 1150.0),
    "borderline_thickening_n1.1": ("shear_thickening", {"name": "power_law", "params": {"k": 0.3, "n": 1.1}},
                                   1150.0),
    "bingham": ("yield_stress", {"name": "bingham", "params": {"tau_y": 3.0, "eta_p": 0.1}}, 1100.0),
    "ketchup": ("yield_stress", {"name": "herschel_bulkley", "params": {"tau_y": 2.663, "k": 3.442, "n": 0.5}},
                1156.1),
    "weak_yield_hb": ("yield_stress", {"name": "herschel_bulkley", "params": {"tau_y": 0.3, "k": 0.3, "n": 0.9}},
                      1100.0),
}


def add_lab_arguments(parser: argparse.ArgumentParser) -> None:
    """The options that make a fluid's lab recording (``lab_recording``): truth grid, sensor, noise seed, programme."""
    parser.add_argument("--truth-sim", default="lab/sim/truth2d.yaml", help="truth grid, a file under conf/")
    parser.add_argument("--truth-dx", type=float, default=None, help="truth cell size [m] (default: the file's)")
    parser.add_argument("--seed", type=int, default=0, help="noise seed; each fluid adds its place in FLUIDS")
    parser.add_argument("--sensor", default="paper", help="sensor preset in conf/lab/sensor/")
    parser.add_argument("--speeds", type=float, nargs="+", default=list(SPEEDS),
                        help="the programme's rod speeds [m/s], in the order stirred")
    parser.add_argument("--segment", type=float, default=SEGMENT, help="time at each speed [s]")


def lab_recording(name: str, args: argparse.Namespace):
    """The lab's stir of the fluid ``name`` along the programme ``args.speeds`` (``args.segment`` s each) on a
    ``RADIUS`` circle (``synthesise``'s result): truth on ``args.truth_sim`` (cells ``args.truth_dx`` when given),
    read through the sensor preset ``args.sensor`` with noise seed ``args.seed`` plus the fluid's place in
    ``FLUIDS``, so that it does not depend on which fluids run."""
    truth_config = instantiate(OmegaConf.load(ROOT / "conf" / args.truth_sim))
    if args.truth_dx is not None:
        truth_config = replace(truth_config, dx=args.truth_dx)
    sensor = SensorModel(**yaml.safe_load((ROOT / "conf" / "lab" / "sensor" / f"{args.sensor}.yaml").read_text()))
    trajectory = stirring_programme([{"speed": s, "duration": args.segment} for s in args.speeds], radius=RADIUS,
                                    ramp_time=0.2)
    _, law, density = FLUIDS[name]
    return synthesise(Fluid(name=name, density=density, law=law), trajectory, sim_config=truth_config,
                      sensor=sensor, seed=args.seed + list(FLUIDS).index(name), name=name)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fluids", nargs="+", default=list(FLUIDS), choices=list(FLUIDS))
    parser.add_argument("--fit-sim", default="sim/slice2d.yaml", help="fitting grid, a file under conf/")
    add_lab_arguments(parser)
    parser.add_argument("--iterations", type=int, default=2, help="Gauss-Newton iterations per window")
    parser.add_argument("--model-error", type=float, default=MODEL_FORCE_ERROR,
                        help="relative force error of the fitting grid in every window's interval (0: none)")
    parser.add_argument("--joint-models", nargs="*", default=[], help="laws fitted to all speeds at once")
    parser.add_argument("--joint-iterations", type=int, default=5, help="Gauss-Newton iterations of each joint law")
    parser.add_argument("--slope-test", default="combined", choices=list(SLOPE_TESTS),
                        help="what the slope test reads (diffstir.behaviour.characterise)")
    parser.add_argument("--workers", type=int, default=1, help="processes for the joint laws")
    parser.add_argument("--out", type=Path, default=None, help="write each fluid's summary JSON here")
    parser.add_argument("--from-reports", type=Path, nargs="+", default=None,
                        help="decide the classes of these saved summaries (--out's JSON) again under --slope-test "
                             "and --model-error, without simulating")
    args = parser.parse_args()
    torch.set_num_threads(1)
    started = time.perf_counter()
    confusion = np.zeros((len(CLASSES), len(CLASSES) + 1), dtype=int)
    print("| fluid | true class | class (confidence) | slope [95 % CI] | yield Λ | joint: selected, yield weight "
          "(ΔBIC) | joint index's slope [95 % CI], z against the points' | seconds |")
    print("|---|---|---|---|---|---|---|---|")
    outcomes = reports(args) if args.from_reports else simulated(args)
    for name, truth, summary, seconds in outcomes:
        if summary is None:  # the classifier refused (e.g. no speed resolved): an outcome to count
            confusion[CLASSES.index(truth), -1] += 1
            continue
        b = summary["behaviour"]
        confusion[CLASSES.index(truth), CLASSES.index(b["class"])] += 1
        stat, joint = b["yield_test"]["statistic"], b["yield_test"]["joint"]
        selected = "-" if summary["joint_fit"] is None else summary["joint_fit"]["selected"]
        evidence = "" if joint is None else f", {joint['weight']:.2f} ({joint['delta_bic']:+.1f})"
        check = b.get("slope_check")
        index = "-" if check is None else (f"{check['joint_index_slope']:.3f} [{check['joint_index_ci95'][0]:.3f}, "
                                           f"{check['joint_index_ci95'][1]:.3f}], {check['z']:+.1f}")
        print(f"| {name} | {truth} | {b['class']} ({b['confidence']:.2f}) | {b['slope']:.3f} "
              f"[{b['slope_ci95'][0]:.3f}, {b['slope_ci95'][1]:.3f}] | {'-' if stat is None else f'{stat:.2f}'} | "
              f"{selected}{evidence} | {index} | {seconds:.0f} |", flush=True)
    print("\nConfusion matrix (rows: true class, columns: classified as)\n")
    print("| true \\ classified | " + " | ".join(CLASSES) + " | refused |")
    print("|---|" + "---|" * (len(CLASSES) + 1))
    for k, cls in enumerate(CLASSES):
        print(f"| {cls} | " + " | ".join(str(v) for v in confusion[k]) + " |")
    correct = int(np.trace(confusion))
    print(f"\n{correct}/{confusion.sum()} correct; {time.perf_counter() - started:.0f} s on {platform.machine()}, "
          f"torch {torch.__version__}, {torch.get_num_threads()} thread")


def simulated(args: argparse.Namespace):
    """(name, true class, summary or None where refused, seconds) of each fluid of ``args.fluids``, stirred by the
    lab and classified; each summary also written to ``args.out`` when given."""
    fit_config = instantiate(OmegaConf.load(ROOT / "conf" / args.fit_sim))
    for name in args.fluids:
        truth, law, _ = FLUIDS[name]
        t0 = time.perf_counter()
        lab = lab_recording(name, args)
        try:
            result = characterise([lab.recording], config=fit_config, workers=args.workers,
                                  settings=BehaviourSettings(iterations=args.iterations, joint_models=args.joint_models,
                                                             joint_iterations=args.joint_iterations,
                                                             model_error=args.model_error, slope_test=args.slope_test))
        except RecordingError as error:
            print(f"| {name} | {truth} | refused: {error} | - | - | - | - | {time.perf_counter() - t0:.0f} |",
                  flush=True)
            yield name, truth, None, time.perf_counter() - t0
            continue
        summary = result.summary()
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            (args.out / f"{name}.json").write_text(json.dumps({"truth": truth, "law": law, **summary}, indent=2))
        yield name, truth, summary, time.perf_counter() - t0


def reports(args: argparse.Namespace):
    """The same for the saved summaries ``args.from_reports``, their classes decided again
    (``diffstir.behaviour.reclassify``; seconds: each run's own)."""
    for path in args.from_reports:
        summary = json.loads(path.read_text())
        c = reclassify(summary, slope_test=args.slope_test, model_error=args.model_error)
        behaviour = c.summary()
        index = reported_joint_index(summary)
        if index is not None:
            behaviour["slope_check"] = slope_agreement(c.slope, index)
        yield path.stem, summary["truth"], {**summary, "behaviour": behaviour}, summary["seconds"]


if __name__ == "__main__":
    main()
