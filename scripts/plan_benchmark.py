"""The planned stir against one speed: does the programme diffstir-plan designs name each fluid's family?
(docs/planning.md, What a planned stir identifies)

Fluids of every family, each stirred twice: with the default plan's programme for the paper's rig
(``conf/lab/programme/paper_plan.yaml``, 8 s at 0.01-0.16 m/s) and with the one-speed default
(``conf/lab/programme/example.yaml``, 0.05 m/s for 2.5 s). Each truth is simulated once per fluid and programme on
``conf/lab/sim/truth2d.yaml`` (2-D MPM, 2 mm cells, finer than the fit: truth 2-D MPM, so the figures show the
analysis against a finer run of its own kind of simulator, not against a real cup) and read by the paper's sensor
(``conf/lab/sensor/paper.yaml``) with seeds 0..S-1.

- planned: analysed as ``diffstir-fit experiment=flow_curve`` does (``behaviour.analysis=flow_curve`` on
  ``sim=slice2d``); its class, and each parameter of the truth's law among the laws fitted to the points with
  whether its 95 % interval holds the truth (an open interval holds it and says the parameter is not identified);
- one speed: analysed as ``diffstir-fit`` does (``identify``, coarse then fine), the family of its selected law
  (``fitting.law_family``).

The truth's family is the one its law shows over the plan's effective shear rates (``identification_benchmark
.true_class``). ``--refit`` fits the laws again to each planned case's stored points, the analysis's last step
(``behaviour.flow_laws.laws_of_points``, no simulation), so a change in how the laws are fitted is measured on the
same points. A yield-stress truth on the 2 mm grid takes hours (its capped viscosity), and each planned analysis
about 4-10 minutes on 2 cores: the full table is a study of many hours, resumed by rerunning the same command.

    python scripts/plan_benchmark.py --out FILE.json [--fluids carreau_example ...] [--seeds 3] [--skip-single]
    python scripts/plan_benchmark.py --out FILE.json --refit
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import platform
import time
from pathlib import Path

import torch
import yaml
from identification_benchmark import CONF, finished, fluid_preset, save, sensor_preset, sim, true_class

from diffstir.behaviour import BehaviourSettings, characterise
from diffstir.behaviour.flow_laws import laws_of_points
from diffstir.fitting import Z95, FitSettings
from diffstir.identification import identify
from diffstir.lab import Fluid, make_fluid_law, stirring_programme
from diffstir.lab.synth import read_truth, simulate_truth
from diffstir.planning.calibration import SHIPPED, Calibration
from diffstir.rheology import fit_flow_curve, load_flow_curves

FLOW_CURVES = Path(__file__).resolve().parents[1] / "diffstir" / "data" / "flow-curves"

#: One fluid per family, and the two measured flow curves bundled in diffstir/data/flow-curves.
FLUIDS = {
    "castor_oil": None,                                                      # Newtonian, 0.65 Pa·s
    "carreau_example": None,                                                 # Carreau, the bundled example's
    "cross": Fluid("cross", 1050.0, {"name": "cross", "params": {"eta0": 2.0, "eta_inf": 0.02, "lam": 1.0,
                                                                 "n": 0.7}}),
    "thickening": None,                                                      # power law, n = 1.3
    "ketchup": None,                                                         # Herschel-Bulkley
    "bingham": Fluid("bingham", 1100.0, {"name": "bingham", "params": {"tau_y": 1.0, "eta_p": 0.3}}),
    "carbopol_glycerin": None,                                               # tabulated: a microgel
    "wlm_polymer": Fluid("wlm_polymer", 1000.0, {"name": "tabulated",
                                                 "flow_curve": "caggioni_wlm_polymer_temp_series/T_20"}),
}


#: The programme presets (conf/lab/programme/) of the two kinds of case.
PROGRAMMES = {"planned": "paper_plan", "example": "example"}


def fluid_named(name: str) -> Fluid:
    return FLUIDS.get(name) or fluid_preset(name)


#: A tabulated curve is a yield-stress fluid's when a Herschel-Bulkley fit to its table gives the yield stress this
#: share of the stress at the band's slowest shear rate [1] (the share at which ``classify`` counts one is 2 σ_m).
TABLE_YIELD_SHARE = 0.1


def truth_family(law: dict, band: tuple[float, float]) -> str:
    """The family ``law`` shows over ``band`` [1/s] (``true_class``); a tabulated curve's from its table: a
    yield stress when a Herschel-Bulkley fit to the table carries ``TABLE_YIELD_SHARE`` of the slowest stress."""
    if law["name"] == "tabulated":
        dataset, sample = law["flow_curve"].split("/")
        fit = fit_flow_curve("herschel_bulkley", load_flow_curves(FLOW_CURVES / f"{dataset}.csv")[sample])
        with torch.no_grad():
            slowest = float(make_fluid_law(law).double()(torch.tensor([band[0]], dtype=torch.float64))[0])
        if fit.params["tau_y"] > TABLE_YIELD_SHARE * slowest * band[0]:
            return "yield_stress"
    return true_class(law, band)


def programme(name: str) -> tuple[dict, object]:
    """The programme preset ``conf/lab/programme/<name>.yaml`` and its trajectory."""
    spec = yaml.safe_load((CONF / "lab" / "programme" / f"{name}.yaml").read_text())
    return spec, stirring_programme(spec["segments"], radius=spec["radius"], ramp_time=spec["ramp_time"],
                                    start_angle=spec.get("start_angle", 0.0))


def coverage(truth_law: dict, laws: dict) -> list[dict]:
    """Each parameter of the truth's law among the fitted ``laws`` (a report's ``joint_fit.laws``): its interval
    and whether it holds the truth; empty where the truth's law was not fitted (a tabulated curve)."""
    law = laws.get(truth_law["name"])
    if law is None:
        return []
    rows = []
    for name, value in truth_law["params"].items():
        lo, hi = law["ci95"][name] if law["ci95"][name] is not None else (None, None)
        low = -math.inf if lo is None else lo
        high = math.inf if hi is None else hi
        rows.append({"parameter": name, "truth": value, "fitted": law["params"][name], "ci95": [lo, hi],
                     "identifiable": law["identifiable"][name], "holds": bool(low <= value <= high)})
    return rows


def planned_case(recording, config, workers: int) -> dict:
    started = time.perf_counter()
    result = characterise([recording], config=config, workers=workers,
                          settings=BehaviourSettings(analysis="flow_curve"))
    summary = result.summary()
    return {"class": summary["behaviour"]["class"], "confidence": summary["behaviour"]["confidence"],
            "selected": summary["joint_fit"]["selected"], "laws": summary["joint_fit"]["laws"],
            "points": [{k: p[k] for k in ("speed", "shear_rate", "viscosity", "viscosity_ci95")}
                       for p in summary["points"]],
            "seconds": time.perf_counter() - started}


def single_case(recording, workers: int) -> dict:
    started = time.perf_counter()
    result = identify(recording, config=sim("sim/slice2d.yaml"), coarse=sim("sim/coarse2d.yaml"), fit=FitSettings(),
                      progress=False, workers=workers)
    summary = result.summary()
    return {"class": summary["family"]["class"], "selected": summary["selection"]["selected"],
            "seconds": time.perf_counter() - started}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fluids", nargs="+", default=list(FLUIDS))
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--skip-single", action="store_true", help="the planned programme only")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, required=True, help="JSON of the cases; a rerun skips those in it")
    parser.add_argument("--refit", action="store_true", help="fit the laws again to the planned cases' points")
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = finished(args.out)
    if args.refit:
        for row in rows:
            if row["programme"] == "planned":
                refit(row)
        save(args.out, rows)
        print(table(rows))
        return
    done = {(r["fluid"], r["programme"], r["seed"]) for r in rows}
    truth_config, config, sensor = sim("lab/sim/truth2d.yaml"), sim("sim/slice2d.yaml"), sensor_preset("paper")
    planned_spec, _ = programme("paper_plan")
    calibration = Calibration.from_dict(json.loads(next(SHIPPED.glob("calibration-*.json")).read_text()))
    rates = sorted(calibration.shear_rate(s["speed"]) for s in planned_spec["segments"])  # the plan's γ̇_eff [1/s]
    for fluid_name in args.fluids:
        fluid = fluid_named(fluid_name)
        family = truth_family(fluid.law, (rates[0], rates[-1]))
        for kind in ("planned", "example") if not args.skip_single else ("planned",):
            seeds = [s for s in range(args.seeds) if (fluid_name, kind, s) not in done]
            if not seeds:
                continue
            _, trajectory = programme(PROGRAMMES[kind])
            clock = time.perf_counter()
            truth = simulate_truth(fluid, trajectory, sim_config=truth_config)
            truth_seconds = time.perf_counter() - clock
            for seed in seeds:
                recording = read_truth(truth, sensor, seed=seed, name=f"{fluid_name}_{kind}").recording
                case = planned_case(recording, config, args.workers) if kind == "planned" else single_case(
                    recording, args.workers)
                row = {"fluid": fluid_name, "programme": kind, "seed": seed, "truth_class": family,
                       "right": case["class"] == family, "truth_law": fluid.law, "truth_seconds": truth_seconds,
                       **case, "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="minutes"),
                       "machine": f"{platform.machine()}, {torch.get_num_threads()} torch thread per process"}
                if kind == "planned":
                    row["coverage"] = coverage(fluid.law, case["laws"])
                    against_truth(row["points"], fluid)
                rows.append(row)
                save(args.out, rows)
                print(f"{fluid_name} {kind} seed {seed}: {case['class']} (truth {family}), {case['seconds']:.0f} s",
                      flush=True)
    print(table(rows))


def against_truth(points: list[dict], fluid: Fluid) -> None:
    """Each report point (``shear_rate`` [1/s], ``viscosity`` [Pa·s], ``viscosity_ci95``) given the truth's
    viscosity at its shear rate, its relative error and whether its interval holds the truth."""
    law = fluid.make_law().double()
    for point in points:
        with torch.no_grad():
            eta = float(law(torch.tensor([point["shear_rate"]], dtype=torch.float64)))
        lo, hi = point["viscosity_ci95"]
        point.update(truth=eta, error=point["viscosity"] / eta - 1.0, holds=bool(lo <= eta <= hi))


def refit(row: dict) -> None:
    """The planned case ``row``'s laws fitted again to its points, those with a finite interval (the analysis's
    classified points), with each point's σ of ln η from its interval, and its coverage of the truth's law."""
    points = [p for p in row["points"] if p["viscosity_ci95"][0] and math.isfinite(p["viscosity_ci95"][1])]
    sigma = [math.log(p["viscosity_ci95"][1] / p["viscosity_ci95"][0]) / (2 * Z95) for p in points]
    laws = laws_of_points([p["shear_rate"] for p in points], [p["viscosity"] for p in points], sigma,
                          list(BehaviourSettings().joint_models)).summary()
    row.update(laws=laws["laws"], selected=laws["selected"], coverage=coverage(row["truth_law"], laws["laws"]),
               refit=datetime.datetime.now(datetime.UTC).isoformat(timespec="minutes"))


def table(rows: list[dict]) -> str:
    """The family rates per programme and the planned parameters' coverage, as markdown."""
    lines = ["| fluid | truth's family | planned: named (right/cases) | one speed: named (right/cases) |",
             "|---|---|---|---|"]
    for fluid in dict.fromkeys(r["fluid"] for r in rows):
        cells = []
        for kind in ("planned", "example"):
            cases = [r for r in rows if r["fluid"] == fluid and r["programme"] == kind]
            named = ", ".join(sorted({r["class"] for r in cases})) or "-"
            cells.append(f"{named} ({sum(r['right'] for r in cases)}/{len(cases)})" if cases else "-")
        family = next(r["truth_class"] for r in rows if r["fluid"] == fluid)
        lines.append(f"| {fluid} | {family} | {cells[0]} | {cells[1]} |")
    for kind in ("planned", "example"):
        cases = [r for r in rows if r["programme"] == kind]
        if cases:
            lines.append(f"\n{kind}: family right in {sum(r['right'] for r in cases)}/{len(cases)} cases")
    points = [p for r in rows if r["programme"] == "planned" for p in r["points"]]
    if points:
        errors = [p["error"] for p in points]
        lines.append(f"planned: the truth's viscosity inside the windows' 95 % intervals "
                     f"{sum(p['holds'] for p in points)}/{len(points)}, errors {min(errors):+.1%} to {max(errors):+.1%}")
    held = [c for r in rows if r["programme"] == "planned" for c in r.get("coverage", [])]
    if held:
        lines.append(f"planned: the truth's parameters inside their 95 % intervals {sum(c['holds'] for c in held)}"
                     f"/{len(held)} ({sum(c['identifiable'] for c in held)} identifiable)")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
