"""The loss a diagnosis candidate reaches at parameters you choose, on a case of the diagnosis benchmark
(docs/diagnosis.md): how well a candidate *could* fit, apart from how far its fit got.

The case is built as ``diagnosis_benchmark.py`` builds it (base fluid, concealed effect, moderate strength, seed),
its Newtonian law identified the same way; then the physics candidate is simulated once per ``--params`` set.
``--eta`` gives the law's viscosity [Pa·s] directly (the candidate's viscosity scale is η / η_identified).

    python scripts/candidate_loss.py --fluid castor_oil --effect thixotropy --candidate thixotropy --eta 0.65 \\
        --params alpha=1,breakdown=0.3,rebuild_time=2 alpha=1,breakdown=0.3,rebuild_time=1

``--frozen`` simulates every point at the identified law's sound speed instead of its own (what a physics fit
held before ``diffstir.diagnosis.compare.refrozen``). Without ``--params`` it prints how far the sensor candidates'
linearised base reading p0 + (d p/d ln s) ln s is from the law simulated at ``--eta``
(``diffstir.diagnosis.compare.ScaleReadings``):

    python scripts/candidate_loss.py --fluid castor_oil --effect sensor_deadband --eta 0.6
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from diagnosis_benchmark import STRENGTHS, Lab, coarse, fluids
from diffstir.diagnosis.base import base_from_identification, simulated_reading
from diffstir.diagnosis.candidates import PHYSICS_CANDIDATES, CachedReplay, Context, PhysicsModel, scaled_law
from diffstir.diagnosis.compare import ScaleReadings
from diffstir.fitting import FitSettings
from diffstir.fitting.initial import characteristic_shear_rate
from diffstir.fitting.problem import StirProblem, Windows
from diffstir.identification import identify


def parse(text: str) -> dict[str, float]:
    pairs = [item.split("=") for item in text.split(",")]
    if any(len(pair) != 2 for pair in pairs):
        raise SystemExit(f"--params {text!r}: expected name=value,name=value")
    return {name: float(value) for name, value in pairs}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fluid", default="castor_oil", help="base fluid of the benchmark")
    parser.add_argument("--effect", default="thixotropy", help="concealed effect of the benchmark")
    parser.add_argument("--strength", default="moderate", choices=list(STRENGTHS))
    parser.add_argument("--seed", type=int, default=0, help="sensor-noise seed of the case")
    parser.add_argument("--candidate", default="thixotropy", choices=list(PHYSICS_CANDIDATES))
    parser.add_argument("--eta", type=float, required=True, help="the law's viscosity [Pa s]")
    parser.add_argument("--params", nargs="+", default=[], help="candidate parameters, name=value,... (none: the "
                        "linearised base reading's gap at --eta)")
    parser.add_argument("--identify-iterations", type=int, default=3, help="as the benchmark's")
    parser.add_argument("--frozen", action="store_true", help="simulate every point at the identified law's sound "
                        "speed (StirProblem.frozen), as a fit that starts there holds it, not at each point's own")
    args = parser.parse_args()
    torch.set_num_threads(1)
    config = coarse()
    lab = Lab(fluids()[args.fluid], config)
    recording, truth = lab.recording(args.effect, STRENGTHS[args.strength], args.seed)
    ident = identify(recording, ["newtonian"], config=config, baseline=False, progress=False, size_estimate=False,
                     fit=FitSettings(window=None, holdout_fraction=0.0, max_iterations=args.identify_iterations))
    eta_identified = ident.selected.model.params_si()["eta"]
    problem = StirProblem(recording, config, ident.density["value"], Windows.of(recording, None, 0.0))
    base = base_from_identification(ident, problem)
    ctx = Context(times=problem.times, measured=problem.measured, base_reading=base.predicted,
                  scale_column=base.scale_column, accel_reading=None, noise=0.0,
                  shear_rate=characteristic_shear_rate(problem), duration=problem.trajectory.duration,
                  rebuild_time=1.0, law=base.law, rod_radius=problem.rig.rod.radius)
    model = PhysicsModel(PHYSICS_CANDIDATES[args.candidate], base.law, ctx)
    # simulates the model's material with its slip length, as the fits do
    replay = CachedReplay(problem.frozen(base.law) if args.frozen else problem, model)
    print(f"{args.effect} concealed in {args.fluid} (truth {truth}), seed {args.seed}; identified η "
          f"{eta_identified:.4g} Pa·s, its loss {problem.loss(base.predicted):.5f} N")
    if not args.params:
        scale = args.eta / eta_identified
        simulated = simulated_reading(problem, scaled_law(base.law, scale))
        linearised = ScaleReadings(ctx).model(0.0)(np.log(scale))
        print(f"at η = {args.eta:g} Pa·s (ln s = {np.log(scale):.3f}): mean |linearised − simulated| "
              f"{np.mean(np.abs(linearised - simulated)):.5f} N; loss of the simulated law "
              f"{problem.loss(simulated):.5f} N, of the linearised reading {problem.loss(linearised):.5f} N")
        return
    print(f"| {args.candidate} parameters | η [Pa·s] | loss [N] |\n|---|---|---|")
    for text in args.params:
        values = {**model.params_si(), **parse(text), "viscosity_scale": args.eta / eta_identified}
        model.set_theta(model.theta_of(values))
        with torch.no_grad():
            reading = np.asarray(replay.simulate(model.material), dtype=np.float64)
        print(f"| {text} | {args.eta:g} | {problem.loss(reading):.5f} |", flush=True)


if __name__ == "__main__":
    main()
