"""The planned stir against one speed: does the programme diffstir-plan designs name each fluid's family?
(docs/accuracy-plan.md, The benchmark)

Fluids of every family, each stirred twice: with the default plan's programme for the paper's rig
(``conf/lab/programme/paper_plan.yaml``, 8 s at 0.01-0.16 m/s) and with the one-speed default
(``conf/lab/programme/example.yaml``, 0.05 m/s for 2.5 s). Each truth is simulated once per fluid and programme on
``conf/lab/sim/truth2d.yaml`` with the implicit shear stress and a 200 Pa·s cap (``TRUTH_SETTINGS``; 2-D MPM, 2 mm
cells, finer than the fit: truth 2-D MPM, so the figures show the analysis against a finer run of its own kind of
simulator, not against a real cup) and read by the paper's sensor (``conf/lab/sensor/paper.yaml``) with seeds
F..F+S-1 (``--first-seed``, ``--seeds``).

- planned: analysed as ``diffstir-fit experiment=flow_curve`` does (``behaviour.analysis=flow_curve`` on
  ``sim=slice2d``); its class, each window's point with its standard errors of ln η (the noise's and baseline's
  ``log_std``, the simulator's ``model_log_std``) and the rungs it was read off, and each parameter of the truth's law
  among the laws fitted to the points with whether its 95 % interval holds the truth (an open interval holds it and
  says the parameter is not identified);
- one speed: analysed as ``diffstir-fit`` does (``identify``, coarse then fine), the family of its selected law
  (``fitting.law_family``).

The truth's family is the one its law shows over the plan's effective shear rates (``identification_benchmark
.true_class``). ``--refit`` fits the laws again to each planned case's stored points, the analysis's last step
(``behaviour.flow_laws.laws_of_points``, no simulation), so a change in how the laws are fitted is measured on the
same points. On one core a truth of the 8 s programme takes about 2-4 minutes, a planned analysis 4-10 and a
one-speed one 6-16: the full table is a study of many hours, resumed by rerunning the same command. ``--truths DIR``
keeps each truth simulation in DIR (``<fluid>_<programme>.npz``, with what made it) and reads it back instead of
simulating it again; ``--jobs N`` runs N cases side by side, one process each (the truths they need first, N at a
time), for a machine of many cores; ``--simulate-only`` makes the truths alone, and ``--merge`` gathers the rows of
runs made elsewhere. ``--planned`` benchmarks another plan's programme (``diffstir-plan out=DIR``'s
``DIR/lab/programme/planned.yaml``); give it its own ``--truths`` folder. A case that fails (a refusal) is kept with
its error and counted as not right; a rerun skips it as it skips the others.

    python scripts/plan_benchmark.py --out FILE.json [--fluids carreau_example ...] [--seeds 3] [--first-seed 0]
                                     [--programmes planned example] [--truths DIR] [--planned PLAN.yaml]
    python scripts/plan_benchmark.py --truths DIR --simulate-only [--jobs 6] [--fluids bingham ...] [--programmes ...]
    python scripts/plan_benchmark.py --out FILE.json --merge OTHER.json ... [--refit]
    python scripts/plan_benchmark.py --out FILE.json --refit
"""

from __future__ import annotations

import argparse
import datetime
import functools
import json
import math
import multiprocessing
import os
import platform
import signal
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
import yaml
from identification_benchmark import CONF, finished, fluid_preset, save, sensor_preset, sim, true_class

from diffstir.behaviour import BehaviourSettings, characterise
from diffstir.behaviour.flow_laws import laws_of_points
from diffstir.fitting import Z95, FitSettings
from diffstir.identification import identify
from diffstir.lab import Fluid, HiddenPhysicsSpec, make_fluid_law, programme_path
from diffstir.lab.synth import TruthSimulation, read_truth, simulate_truth
from diffstir.rig import Rig
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


#: The programmes (``conf/lab/programme`` files) of the two kinds of case; ``--planned`` replaces the planned one.
PROGRAMMES = {"planned": CONF / "lab" / "programme" / "paper_plan.yaml",
              "example": CONF / "lab" / "programme" / "example.yaml"}


#: ``SimConfig`` settings that replace those of the truth's and the analyses' simulators (``--sim``).
SIM_SETTINGS: dict = {}
#: The truth's own settings over ``conf/lab/sim/truth2d.yaml``: the implicit shear stress and a 200 Pa·s cap, so
#: that no fluid's truth is capped (Carbopol reads 29-114 Pa·s over the plan's band, a yield-stress fluid's far field
#: more) and its step does not shorten with the viscosity.
TRUTH_SETTINGS = {"viscous_solver": "implicit", "viscosity_cap": 200.0}


def use_settings(path: Path, sim_settings: dict) -> None:
    """Make ``path`` (a ``lab/programme`` file, such as ``diffstir-plan``'s ``lab/programme/planned.yaml``) the
    planned cases' programme and ``sim_settings`` the simulators' changed settings in this process; a pool's
    processes run it first (``in_pool``)."""
    PROGRAMMES["planned"] = path
    SIM_SETTINGS.clear()
    SIM_SETTINGS.update(sim_settings)


def simulator(path: str):
    """The ``SimConfig`` of ``conf/<path>`` with the ``--sim`` settings."""
    return sim(path).replace(**SIM_SETTINGS)


def truth_simulator():
    """The truth's ``SimConfig``: ``conf/lab/sim/truth2d.yaml`` with ``TRUTH_SETTINGS``, then the ``--sim`` ones."""
    return sim("lab/sim/truth2d.yaml").replace(**{**TRUTH_SETTINGS, **SIM_SETTINGS})


def sim_setting(text: str) -> tuple[str, object]:
    """``KEY=VALUE`` of ``--sim``: a ``SimConfig`` field and its YAML value."""
    key, _, value = text.partition("=")
    if not key or not _:
        raise argparse.ArgumentTypeError(f"{text!r}: expected KEY=VALUE, such as viscous_solver=implicit")
    return key, yaml.safe_load(value)


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


def programme(path: Path) -> tuple[dict, object]:
    """The programme of the ``conf/lab/programme`` file ``path`` and its trajectory."""
    spec = yaml.safe_load(path.read_text())
    return spec, programme_path(spec)


def truth_identity(fluid: Fluid, kind: str) -> dict:
    """What a truth simulation of ``fluid`` stirred by the ``kind`` programme is made from (the truth settings less
    their device): a stored truth is read back only where this is unchanged."""
    spec, _ = programme(PROGRAMMES[kind])
    config = {k: v for k, v in asdict(truth_simulator()).items() if k != "device"}
    return json.loads(json.dumps({"fluid": {"name": fluid.name, "density": fluid.density, "law": fluid.law},
                                  "programme": spec, "sim": config, "rig": asdict(Rig())}))


def store_truth(path: Path, truth: TruthSimulation, seconds: float, identity: dict) -> None:
    """Write ``truth``'s force [N] at its times [s] to ``path`` (.npz) with ``identity`` and what it cost; the file
    appears whole or not at all."""
    made = {"dt": truth.dt, "discretisation": truth.discretisation, "per_unit_length": truth.per_unit_length,
            "slice_factor": truth.slice_factor, "seconds": seconds, "machine": machine(),
            "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="minutes")}
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".partial.npz")
    np.savez(partial, times=truth.times, force=truth.force, identity=json.dumps(identity), made=json.dumps(made))
    partial.replace(path)


def stored_truth(path: Path, fluid_name: str, kind: str) -> tuple[TruthSimulation, float] | None:
    """The truth stored at ``path`` and its wall time [s]; None where there is none. A stored truth made from
    anything else than the current fluid, programme, rig and truth settings is refused, naming the file."""
    if not path.exists():
        return None
    fluid = fluid_named(fluid_name)
    with np.load(path) as data:
        identity, made = json.loads(str(data["identity"])), json.loads(str(data["made"]))
        times, force = data["times"], data["force"]
    if identity != truth_identity(fluid, kind):
        raise SystemExit(f"{path}: made from other settings than the current {fluid_name} {kind} truth; move it "
                         f"away to simulate it again")
    _, trajectory = programme(PROGRAMMES[kind])
    truth = TruthSimulation(fluid, trajectory, Rig(), truth_simulator(), HiddenPhysicsSpec(), times,
                            force, made["dt"], made["discretisation"], made["per_unit_length"], made["slice_factor"])
    return truth, made["seconds"]


@functools.lru_cache(maxsize=1)  # the cases of one fluid and programme follow each other in one process
def truth_of(fluid_name: str, kind: str, store: Path | None) -> tuple[TruthSimulation, float]:
    """``fluid_name``'s truth under the ``kind`` programme and its wall time [s]: read from ``store`` where it is
    there, else simulated on ``truth_simulator()`` (and stored, where ``store`` is given)."""
    path = None if store is None else store / f"{fluid_name}_{kind}.npz"
    found = None if path is None else stored_truth(path, fluid_name, kind)
    if found is not None:
        return found
    _, trajectory = programme(PROGRAMMES[kind])
    clock = time.perf_counter()
    truth = simulate_truth(fluid_named(fluid_name), trajectory, sim_config=truth_simulator())
    seconds = time.perf_counter() - clock
    if path is not None:
        store_truth(path, truth, seconds, truth_identity(fluid_named(fluid_name), kind))
    return truth, seconds


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} CPUs, 1 torch thread per process"


def plan_band() -> tuple[float, float]:
    """The least and greatest effective shear rate [1/s] of the planned programme's speeds (the shipped
    calibration's k_s)."""
    spec, _ = programme(PROGRAMMES["planned"])
    calibration = Calibration.from_dict(json.loads(next(SHIPPED.glob("calibration-*.json")).read_text()))
    rates = sorted(calibration.shear_rate(s["speed"]) for s in spec["segments"])
    return rates[0], rates[-1]


#: A truth's law that the analysis fits as a special case of another: that law, and its parameters from the truth's.
NESTED = {"bingham": ("herschel_bulkley", lambda p: {"tau_y": p["tau_y"], "k": p["eta_p"], "n": 1.0})}


def coverage(truth_law: dict, laws: dict) -> list[dict]:
    """Each parameter of the truth's law among the fitted ``laws`` (a report's ``joint_fit.laws``), or of the law
    that holds it (``NESTED``): its interval and whether it holds the truth; empty where no fitted law holds the
    truth's (a tabulated curve)."""
    name, params = truth_law["name"], truth_law.get("params")
    if name in NESTED:
        name, params = NESTED[name][0], NESTED[name][1](params)
    law = laws.get(name)
    if law is None:
        return []
    rows = []
    for parameter, value in params.items():
        lo, hi = law["ci95"][parameter] if law["ci95"][parameter] is not None else (None, None)
        low = -math.inf if lo is None else lo
        high = math.inf if hi is None else hi
        rows.append({"parameter": parameter, "truth": value, "fitted": law["params"][parameter], "ci95": [lo, hi],
                     "identifiable": law["identifiable"][parameter], "holds": bool(low <= value <= high)})
    return rows


def planned_case(recording, config, workers: int) -> dict:
    started = time.perf_counter()
    result = characterise([recording], config=config, workers=workers,
                          settings=BehaviourSettings(analysis="flow_curve"))
    summary = result.summary()
    return {"class": summary["behaviour"]["class"], "confidence": summary["behaviour"]["confidence"],
            "selected": summary["joint_fit"]["selected"], "laws": summary["joint_fit"]["laws"],
            "points": [{k: p[k] for k in ("speed", "shear_rate", "viscosity", "viscosity_ci95", "log_std",
                                          "model_log_std", "baseline")} for p in summary["points"]],
            "rungs": summary["programmes"][0]["rungs"],
            "seconds": time.perf_counter() - started}


def single_case(recording, workers: int) -> dict:
    started = time.perf_counter()
    result = identify(recording, config=simulator("sim/slice2d.yaml"), coarse=simulator("sim/coarse2d.yaml"),
                      fit=FitSettings(), progress=False, workers=workers)
    summary = result.summary()
    return {"class": summary["family"]["class"], "selected": summary["selection"]["selected"],
            "seconds": time.perf_counter() - started}

def case_row(fluid_name: str, kind: str, seed: int, workers: int, store: Path | None) -> dict:
    """The benchmark's row of ``fluid_name``'s truth under the ``kind`` programme, read by the paper's sensor with
    ``seed`` and analysed with ``workers`` processes."""
    torch.set_num_threads(1)
    fluid = fluid_named(fluid_name)
    family = truth_family(fluid.law, plan_band())
    truth, truth_seconds = truth_of(fluid_name, kind, store)
    recording = read_truth(truth, sensor_preset("paper"), seed=seed, name=f"{fluid_name}_{kind}").recording
    case = planned_case(recording, simulator("sim/slice2d.yaml"), workers) if kind == "planned" else single_case(
        recording, workers)
    row = {"fluid": fluid_name, "programme": kind, "seed": seed, "truth_class": family,
           "segments": programme(PROGRAMMES[kind])[0]["segments"],
           "right": case["class"] == family, "truth_law": fluid.law, "truth_seconds": truth_seconds,
           "sim": dict(SIM_SETTINGS), **case,
           "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="minutes"), "machine": machine()}
    if kind == "planned":
        row["coverage"] = coverage(fluid.law, case["laws"])
        against_truth(row["points"], fluid)
    return row


def _attempt(task: tuple) -> tuple[tuple, dict | None, str | None]:
    """``case_row`` of ``task`` in a pool's process: the task, its row, or the error that ended it."""
    try:
        return task, case_row(*task), None
    except Exception as error:  # one case's failure is reported and leaves the others running
        return task, None, f"{type(error).__name__}: {error}"


def _make_truth(task: tuple) -> str:
    """Simulate and store one truth (a ``--simulate-only`` task); its line for the log."""
    torch.set_num_threads(1)
    fluid_name, kind, store = task
    truth, seconds = truth_of(fluid_name, kind, store)
    return f"{fluid_name} {kind}: {truth.times.size} steps of {truth.dt:.2e} s, {seconds:.0f} s"


def in_pool(function, tasks: list, jobs: int):
    """``function`` of each task as it finishes: in this process when ``jobs`` is 1, else ``jobs`` processes
    side by side, ended with this one (SIGTERM exits 143), each on this process's planned programme."""
    if jobs <= 1:
        yield from map(function, tasks)
        return
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    pool = multiprocessing.get_context("spawn").Pool(jobs, maxtasksperchild=1, initializer=use_settings,
                                                     initargs=(PROGRAMMES["planned"], dict(SIM_SETTINGS)))
    try:
        yield from pool.imap_unordered(function, tasks)
    finally:
        pool.terminate()
        pool.join()


def simulate_only(pairs: list[tuple[str, str]], store: Path, jobs: int) -> None:
    """The missing truths of ``pairs`` (fluid, programme), ``jobs`` at a time, each stored as soon as it ends."""
    missing = [(f, k, store) for f, k in pairs if not (store / f"{f}_{k}.npz").exists()]
    if missing:
        print(f"{len(missing)} truths to simulate, {jobs} at a time: "
              f"{', '.join(f'{f} {k}' for f, k, _ in missing)}", flush=True)
    for line in in_pool(_make_truth, missing, jobs):
        print(line, flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fluids", nargs="+", choices=list(FLUIDS), default=list(FLUIDS))
    parser.add_argument("--seeds", type=int, default=3, help="sensor seeds per fluid and programme")
    parser.add_argument("--first-seed", type=int, default=0, help="the seeds are FIRST_SEED .. FIRST_SEED+SEEDS-1")
    parser.add_argument("--programmes", nargs="+", choices=list(PROGRAMMES), default=list(PROGRAMMES),
                        help="planned: the default plan's; example: the one-speed default")
    parser.add_argument("--planned", type=Path, default=PROGRAMMES["planned"],
                        help="the planned cases' programme: a lab/programme file, such as diffstir-plan's "
                             "OUT/lab/programme/planned.yaml (default: the default plan's)")
    parser.add_argument("--sim", nargs="+", type=sim_setting, default=[], metavar="KEY=VALUE",
                        help="settings of the truth's and the analyses' simulators, such as dt_max=0.001 (give "
                             "the cases their own --truths and --out)")
    parser.add_argument("--workers", type=int, default=2, help="processes of one analysis (1 with --jobs > 1)")
    parser.add_argument("--jobs", type=int, default=1, help="cases (or truths) run side by side")
    parser.add_argument("--truths", type=Path, help="folder of stored truth simulations, read and added to")
    parser.add_argument("--simulate-only", action="store_true", help="simulate the missing truths into --truths")
    parser.add_argument("--out", type=Path, help="JSON of the cases; a rerun skips those in it")
    parser.add_argument("--refit", action="store_true", help="fit the laws again to the planned cases' points")
    parser.add_argument("--merge", nargs="+", type=Path, default=[], metavar="FILE",
                        help="add the cases of these JSONs that --out lacks")
    args = parser.parse_args()
    use_settings(args.planned.resolve(), dict(args.sim))
    try:
        truth_simulator()
    except (TypeError, ValueError) as error:
        parser.error(f"--sim: {error}")
    pairs = [(f, k) for f in args.fluids for k in args.programmes]
    if args.simulate_only:
        if args.truths is None:
            parser.error("--simulate-only needs --truths DIR")
        simulate_only(pairs, args.truths, args.jobs)
        return
    if args.out is None:
        parser.error("the following arguments are required: --out (or --simulate-only)")
    if args.jobs > 1 and args.truths is None:
        parser.error("--jobs > 1 needs --truths DIR: the cases of one fluid and programme share its truth")
    torch.set_num_threads(1)
    rows = finished(args.out)
    done = {(r["fluid"], r["programme"], r["seed"]) for r in rows}
    if args.merge or args.refit:
        for path in args.merge:
            rows += [r for r in finished(path) if (r["fluid"], r["programme"], r["seed"]) not in done]
            done = {(r["fluid"], r["programme"], r["seed"]) for r in rows}
        for row in rows if args.refit else ():
            if row["programme"] == "planned" and row["class"] is not None:
                refit(row)
        save(args.out, rows)
        print(table(rows))
        return
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    tasks = [(f, k, s, args.workers if args.jobs <= 1 else 1, args.truths) for f, k in pairs for s in seeds
             if (f, k, s) not in done]
    if args.jobs > 1:
        simulate_only(sorted({(f, k) for f, k, *_ in tasks}, key=pairs.index), args.truths, args.jobs)
    for (fluid_name, kind, seed, *_), row, error in in_pool(_attempt, tasks, args.jobs):
        if row is None:  # kept, and counted as not right: a refusal names no family
            row = {"fluid": fluid_name, "programme": kind, "seed": seed, "class": None, "error": error,
                   "truth_class": truth_family(fluid_named(fluid_name).law, plan_band()), "right": False,
                   "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="minutes"), "machine": machine()}
            print(f"{fluid_name} {kind} seed {seed}: failed: {error}", flush=True)
        else:
            print(f"{fluid_name} {kind} seed {seed}: {row['class']} (truth {row['truth_class']}), "
                  f"{row['seconds']:.0f} s", flush=True)
        rows.append(row)
        save(args.out, rows)
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
            named = ", ".join(sorted({r["class"] or "refused" for r in cases})) or "-"
            cells.append(f"{named} ({sum(r['right'] for r in cases)}/{len(cases)})" if cases else "-")
        family = next(r["truth_class"] for r in rows if r["fluid"] == fluid)
        lines.append(f"| {fluid} | {family} | {cells[0]} | {cells[1]} |")
    for kind in ("planned", "example"):
        cases = [r for r in rows if r["programme"] == kind]
        if cases:
            lines.append(f"\n{kind}: family right in {sum(r['right'] for r in cases)}/{len(cases)} cases")
    points = [p for r in rows if r["programme"] == "planned" for p in r.get("points", [])]
    if points:
        errors = [p["error"] for p in points]
        lines.append(f"planned: the truth's viscosity inside the windows' 95 % intervals "
                     f"{sum(p['holds'] for p in points)}/{len(points)}, errors {min(errors):+.1%} to "
                     f"{max(errors):+.1%}")
    held = [c for r in rows if r["programme"] == "planned" for c in r.get("coverage", [])]
    if held:
        identified = [c for c in held if c["identifiable"]]
        lines.append(f"planned: the truth law's identified parameters inside their 95 % intervals "
                     f"{sum(c['holds'] for c in identified)}/{len(identified)}; {len(held) - len(identified)} "
                     f"parameters not identified (fitting.uncertainty.identifiable_half_width)")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
