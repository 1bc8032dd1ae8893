"""Identification accuracy on virtual-lab recordings the fitter has never seen (docs/accuracy.md).

Two parts, each printing markdown tables:

* ``newtonian``: a sweep of Newtonian viscosities (default 1 mPa·s to 10 Pa·s) stirred at one speed, identified with
  the Newtonian law at the fitting defaults (coarse-to-fine, ``conf/sim/coarse2d.yaml`` then ``slice2d.yaml``) from a
  truth simulated on ``conf/lab/sim/truth2d.yaml`` (2 mm cells, finer than the fit). Per fluid: the density and
  the viscosity with their 95 % intervals, the error, whether the interval holds the truth, and whether the
  recording resolves viscosity at all (``resolvable``: a doubling of η must change the reading by more than the
  noise and the sensor's resolution; where it does not, the report says "not identifiable"). Beside it the estimate
  from the reading's size (``fitting.magnitude``, the report's ``magnitude``): its viscosity, interval, error and
  whether it resolves the viscosity.
* ``laws``: fluids of every non-Newtonian class (presets of ``conf/lab/fluid`` or ``EXTRA_FLUIDS``) stirred at three
  speeds, identified with every
  default law and the corotated baseline: the paper's Tables II-IV in shape (parameters per law with the truth, the
  force deviation per law, our estimate against the baseline's) and the law family selected. These fluids run on
  the coarse grids of the behaviour benchmark (truth ``--law-truth-dx``, fit ``coarse2d`` only), because a
  yield-stress fluid's capped viscosity makes a 2 mm truth hours long on two cores; ``--law-fine
  --law-truth-dx 0.002`` fits coarse-to-fine as ``diffstir-fit`` does, on a truth finer than the fit.

Every sensor reading goes through the paper's sensor preset (``conf/lab/sensor/paper.yaml``) with seed
``--seed`` + case index. One torch thread.

    python scripts/identification_benchmark.py --part newtonian [--viscosities 0.001 0.01 ...] [--out FILE.json]
    python scripts/identification_benchmark.py --part newtonian --viscosities 0.05 --newtonian-speed 0.02 \
        --newtonian-duration 6      # a thin fluid at a slower, longer stir
    python scripts/identification_benchmark.py --part laws [--fluids cs24 ketchup ...] [--out FILE.json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import time
from dataclasses import replace
from pathlib import Path

import torch
import yaml
from hydra.utils import instantiate
from omegaconf import OmegaConf

from diffstir.fitting import FitSettings
from diffstir.fitting.family import NEWTONIAN_CHANGE
from diffstir.fitting.uncertainty import COARSE_FORCE_ERROR, MODEL_FORCE_ERROR
from diffstir.identification import identify
from diffstir.lab import Fluid, SensorModel, make_fluid_law, stirring_programme, synthesise
from diffstir.report_files import format_interval

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
NEWTONIAN_PROGRAMME = [{"speed": 0.1, "duration": 1.3}]                  # m/s, s: 15 mm circle, period 0.94 s
LAW_PROGRAMME = [{"speed": s, "duration": 0.6} for s in (0.03, 0.06, 0.12)]  # m/s, s: a factor 4 in speed
RADIUS, RAMP = 0.015, 0.2  # m, s
def sim(path: str):
    return instantiate(OmegaConf.load(CONF / path))


def sensor_preset(name: str, stated: bool = True) -> SensorModel:
    """The sensor preset ``conf/lab/sensor/<name>.yaml``; ``stated`` False: its recordings do not state the
    sensor's response time (``stated_time_constant``), which the fit then leaves out."""
    sensor = SensorModel(**yaml.safe_load((CONF / "lab" / "sensor" / f"{name}.yaml").read_text()))
    return sensor if stated else replace(sensor, stated_time_constant=None)


#: fluids beside the presets: classes the presets lack at this stir's shear rates (the paper's jam thins over
#: 0.1-100 1/s with η0 = 8 Pa·s, too slow to simulate here; its corn starches thicken only above 40 1/s)
EXTRA_FLUIDS = {
    "jam_like": Fluid("jam_like", 1330.0, {"name": "carreau", "params": {"eta0": 2.0, "eta_inf": 0.05, "lam": 1.0,
                                                                         "n": 0.4}}),
    "thickening": Fluid("thickening", 1150.0, {"name": "power_law", "params": {"k": 0.3, "n": 1.3}}),
}


def fluid_preset(name: str) -> Fluid:
    if name in EXTRA_FLUIDS:
        return EXTRA_FLUIDS[name]
    return Fluid.from_mapping(yaml.safe_load((CONF / "lab" / "fluid" / f"{name}.yaml").read_text()))


def true_class(law: dict, probed: tuple[float, float]) -> str:
    """The class a fluid shows over the probed shear rates [1/s]: yield stress for a law with τ_y > 0, otherwise
    by how its η changes across the band (less than ``NEWTONIAN_CHANGE``: Newtonian there), as
    ``diffstir.fitting.family`` reads a fitted law."""
    if law.get("params", {}).get("tau_y", 0.0) > 0.0:  # a tabulated curve has no parameters
        return "yield_stress"
    eta = make_fluid_law(law).double()(torch.tensor(probed, dtype=torch.float64)).detach()
    change = float(torch.log(eta[1] / eta[0]))
    return "newtonian" if abs(change) < NEWTONIAN_CHANGE else "shear_thinning" if change < 0 else "shear_thickening"


def save(path: Path | None, rows: list[dict]) -> None:
    """Write the rows so far to ``path`` (JSON): a rerun of the same command skips them."""
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(rows, indent=1, default=float))


def finished(path: Path | None) -> list[dict]:
    return json.loads(path.read_text()) if path is not None and path.exists() else []


def newtonian_part(args) -> list[dict]:
    truth_config, fine, coarse = sim("lab/sim/truth2d.yaml"), sim("sim/slice2d.yaml"), sim("sim/coarse2d.yaml")
    stir = [{"speed": args.newtonian_speed, "duration": args.newtonian_duration}]
    trajectory = stirring_programme(stir, radius=RADIUS, ramp_time=RAMP)
    sensor, rows, done = sensor_preset(args.sensor, not args.unstated_response), [], finished(args.out)
    print("| η true [Pa·s] | ρ true | ρ [95 % CI] | η fitted [95 % CI] | error | CI holds truth | resolvable | "
          "η from size [95 % CI] | error | CI holds truth | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for i, eta in enumerate(args.viscosities):
        if any(r["eta_true"] == eta for r in done):
            rows.append(next(r for r in done if r["eta_true"] == eta))
            continue
        t0 = time.perf_counter()
        density = args.density
        fluid = Fluid(name=f"newtonian {eta:g}", density=density, law={"name": "newtonian", "params": {"eta": eta}})
        lab = synthesise(fluid, trajectory, sim_config=truth_config, sensor=sensor, seed=args.seed + i)
        model_error = MODEL_FORCE_ERROR if args.model_error is None else args.model_error
        result = identify(lab.recording, ("newtonian",), config=fine, coarse=coarse, baseline=False, progress=False,
                          fit=FitSettings(window=None, fine_iterations=args.fine_iterations,
                                          sensor_nuisance=args.sensor_nuisance, model_error=model_error))
        law = result.summary()["laws"]["newtonian"]
        fitted, (lo, hi) = law["params"]["eta"], law["ci95"]["eta"] or (None, None)  # null: not identifiable
        rho, size = result.density, result.magnitude
        row = {"size": {"eta": size["viscosity"], "ci95": size["ci95"], "error": size["viscosity"] / eta - 1.0,
                        "covered": holds(*size["ci95"], eta), "resolved": size["resolved"],
                        "log_slope": size["log_slope"]},
               "eta_true": eta, "eta": fitted, "ci95": [lo, hi], "error": fitted / eta - 1.0,
               "covered": holds(lo, hi, eta), "resolvable": result.resolvable["viscosity"],
               "density_true": density, "density": rho["value"], "density_ci95": rho["ci95"],
               "density_covered": holds(*rho["ci95"], density),
               "seconds": time.perf_counter() - t0}
        rows.append(row)
        save(args.out, rows)
        verdict = "" if row["resolvable"] else " (not identifiable)"
        print(f"| {eta:g} | {density:g} | {rho['value']:.1f} [{rho['ci95'][0]:.1f}, {rho['ci95'][1]:.1f}] | "
              f"{fitted:.4g} [{_fmt(lo)}, {_fmt(hi)}]{verdict} | {100 * row['error']:+.1f} % | "
              f"{'yes' if row['covered'] else 'no'} | {'yes' if row['resolvable'] else 'no'} | "
              f"{_size_cells(row['size'])} | {row['seconds']:.0f} |", flush=True)
    return rows


def laws_part(args) -> list[dict]:
    coarse = sim("sim/coarse2d.yaml")
    truth_config = replace(coarse, dx=args.law_truth_dx)
    trajectory = stirring_programme(LAW_PROGRAMME, radius=RADIUS, ramp_time=RAMP)
    sensor, rows, done = sensor_preset(args.sensor, not args.unstated_response), [], finished(args.out)
    for i, name in enumerate(args.fluids):
        if any(r["fluid"] == name for r in done):
            rows.append(next(r for r in done if r["fluid"] == name))
            continue
        t0 = time.perf_counter()
        fluid = fluid_preset(name)
        lab = synthesise(fluid, trajectory, sim_config=truth_config, sensor=sensor, seed=args.seed + 100 + i)
        stages = {"config": sim("sim/slice2d.yaml"), "coarse": coarse} if args.law_fine else {"config": coarse}
        model_error = args.model_error if args.model_error is not None else (
            MODEL_FORCE_ERROR if args.law_fine else COARSE_FORCE_ERROR)
        result = identify(lab.recording, **stages, baseline=True, progress=False, size_estimate=False,
                          fit=FitSettings(window=None, max_iterations=args.iterations,
                                          fine_iterations=args.fine_iterations, sensor_nuisance=args.sensor_nuisance,
                                          model_error=model_error))
        summary = result.summary()
        law = fluid.make_law().double()
        rate = summary["apparent_viscosity"]["effective_shear_rate"]
        eta_true = float(law(torch.tensor([rate], dtype=torch.float64)).item())
        selected = summary["selected"]
        row = {"fluid": name, "law": fluid.law, "true_class": true_class(fluid.law, summary["shear_rate_range"]),
               "shear_rate_range": summary["shear_rate_range"], "selected": selected,
               "class": summary["family"]["class"], "family": summary["family"],
               "lowest_loss_class": summary["laws"][summary["selection"]["lowest_loss"]]["family"]["class"],
               "effective_shear_rate": rate, "eta_true": eta_true,
               "eta": summary["apparent_viscosity"]["at_effective_shear_rate"],
               "eta_ci95": summary["apparent_viscosity"]["at_effective_shear_rate_ci95"],
               "baseline_eta": summary["baseline"]["apparent_viscosity"]["at_effective_shear_rate"],
               "laws": {k: {"params": v["params"], "ci95": v["ci95"], "loss": v["loss"],
                            "identifiable": v["identifiable"], "bic": v["bic"], "sensor": v["sensor"],
                            "family": v["family"]} for k, v in summary["laws"].items()},
               "baseline": {"params": summary["baseline"]["params"], "loss": summary["baseline"]["loss"]},
               "lowest_loss": summary["selection"].get("lowest_loss"),
               "density_true": fluid.density, "density": summary["density"]["value"],
               "density_ci95": summary["density"]["ci95"], "seconds": time.perf_counter() - t0}
        row["error"] = row["eta"] / eta_true - 1.0
        row["baseline_error"] = row["baseline_eta"] / eta_true - 1.0
        rows.append(row)
        save(args.out, rows)
        print(f"\n### {name}: {fluid.law['name']} {fluid.law['params']}, ρ {fluid.density} kg/m³ "
              f"({row['seconds']:.0f} s)\n")
        print("| law | parameters (SI) [95 % CI] | identifiable | sensor | class: slope [95 % CI] | loss [N] | BIC |")
        print("|---|---|---|---|---|---|---|")
        for k, v in row["laws"].items():
            text = ", ".join(f"{p} {x:.4g} {format_interval(v['ci95'][p])}" for p, x in v["params"].items())
            ident = ", ".join(p for p, ok in v["identifiable"].items() if not ok) or "all"
            nuisances = ", ".join(f"{p} {x:.3g} {v['sensor']['units'][p]}" for p, x in v["sensor"].items()
                                  if p != "units") or "-"
            fam = v["family"]
            print(f"| {k}{' (selected)' if k == selected else ''} | {text} | "
                  f"{'all' if ident == 'all' else 'not ' + ident} | {nuisances} | {fam['class']}: "
                  f"{fam['slope']:.2f} [{_fmt(fam['slope_ci95'][0])}, {_fmt(fam['slope_ci95'][1])}] | "
                  f"{v['loss']:.4g} | {v['bic']:.1f} |")
        b = row["baseline"]
        print("| corotated baseline | " + ", ".join(f"{p} {x:.4g}" for p, x in b["params"].items())
              + f" | - | - | - | {b['loss']:.4g} | - |")
        print(f"\nclass {row['class']} (true {row['true_class']}); γ̇_eff {rate:.3g} 1/s; η(γ̇_eff) true "
              f"{eta_true:.4g}, ours {row['eta']:.4g} [{row['eta_ci95'][0]:.4g}, {row['eta_ci95'][1]:.4g}] "
              f"({100 * row['error']:+.1f} %), corotated {row['baseline_eta']:.4g} "
              f"({100 * row['baseline_error']:+.1f} %); density {row['density']:.1f} "
              f"[{row['density_ci95'][0]:.1f}, {row['density_ci95'][1]:.1f}]", flush=True)
    print("\n| fluid | true class | selected (class) | η(γ̇_eff) true | ours | error | corotated | error |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['fluid']} | {r['true_class']} | {r['selected']} ({r['class']}) | {r['eta_true']:.4g} | "
              f"{r['eta']:.4g} | {100 * r['error']:+.1f} % | {r['baseline_eta']:.4g} | "
              f"{100 * r['baseline_error']:+.1f} % |")
    return rows


def holds(lo: float | None, hi: float | None, value: float) -> bool:
    """Whether [lo, hi] holds ``value``; a bound the report leaves null (it overflowed) is unbounded."""
    return (lo is None or lo <= value) and (hi is None or value <= hi)


def _size_cells(size: dict) -> str:
    """The size estimate's three cells: η [95 % CI] (flagged when not resolved), error, whether the CI holds."""
    verdict = "" if size["resolved"] else " (not resolved)"
    return (f"{size['eta']:.4g} [{_fmt(size['ci95'][0])}, {_fmt(size['ci95'][1])}]{verdict} | "
            f"{100 * size['error']:+.1f} % | {'yes' if size['covered'] else 'no'}")


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.3g}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=["newtonian", "laws"], required=True)
    parser.add_argument("--viscosities", type=float, nargs="+", default=[0.001, 0.01, 0.05, 0.2, 1.0, 3.0, 10.0],
                        help="Pa s")
    parser.add_argument("--density", type=float, default=1000.0, help="kg/m^3, the Newtonian sweep's")
    parser.add_argument("--newtonian-speed", type=float, default=NEWTONIAN_PROGRAMME[0]["speed"],
                        help="the Newtonian sweep's rod speed [m/s] on its 15 mm circle")
    parser.add_argument("--newtonian-duration", type=float, default=NEWTONIAN_PROGRAMME[0]["duration"],
                        help="the Newtonian sweep's stir at that speed [s], after a 0.2 s ramp")
    parser.add_argument("--fluids", nargs="+", default=["jam_like", "thickening", "ketchup"],
                        help="presets in conf/lab/fluid, or jam_like, thickening")
    parser.add_argument("--law-truth-dx", type=float, default=0.004, help="m, the law part's truth cells")
    parser.add_argument("--law-fine", action="store_true",
                        help="law part: fit coarse-to-fine (coarse2d, then slice2d) as diffstir-fit does")
    parser.add_argument("--iterations", type=int, default=FitSettings().max_iterations,
                        help="the most Gauss-Newton iterations per law (conf/fit.yaml's)")
    parser.add_argument("--fine-iterations", type=int, default=FitSettings().fine_iterations,
                        help="the most Broyden iterations on the fine grid (conf/fit.yaml's)")
    parser.add_argument("--sensor", default="paper", help="preset in conf/lab/sensor")
    parser.add_argument("--unstated-response", action="store_true",
                        help="recordings that do not state the sensor's response time: the fit leaves it out")
    parser.add_argument("--sensor-nuisance", type=lambda text: tuple(n for n in text.split(",") if n),
                        default=(), help="sensor parameters profiled out of each fit: lag, offset (default: none)")
    parser.add_argument("--model-error", type=float, default=None,
                        help="relative 1-σ force error of the fitting grid, in every interval (default: 0.03 on "
                             "the 2.5 mm grid, 0.063 when the law part fits on the 5 mm grid alone)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=None,
                        help="write the rows as JSON here after every case; a rerun skips the cases it holds")
    args = parser.parse_args()
    if args.out is not None and args.out.is_dir():
        parser.error(f"--out {args.out} is a directory; give the JSON file the rows go to, e.g. {args.out}/rows.json")
    torch.set_num_threads(1)
    started = time.perf_counter()
    print(f"{datetime.date.today()}, {platform.machine()}, {os.cpu_count()} CPUs, load average "
          f"{os.getloadavg()[0]:.1f} at start, torch {torch.__version__}, 1 thread\n")
    rows = newtonian_part(args) if args.part == "newtonian" else laws_part(args)
    if args.part == "newtonian":
        resolved = [r for r in rows if r["resolvable"]]
        within = [r for r in resolved if abs(r["error"]) <= 0.10]
        print(f"\nresolvable: {len(resolved)}/{len(rows)}; within 10 %: {len(within)}/{len(resolved)}; "
              f"viscosity intervals holding the truth: {sum(r['covered'] for r in rows)}/{len(rows)}; "
              f"density within 1 %: {sum(abs(r['density'] / r['density_true'] - 1) <= 0.01 for r in rows)}/"
              f"{len(rows)}, intervals holding it: {sum(r['density_covered'] for r in rows)}/{len(rows)}")
        sized = [r["size"] for r in rows if "size" in r]
        resolved = [s for s in sized if s["resolved"]]
        print(f"from the reading's size: resolved {len(resolved)}/{len(sized)}; within 10 %: "
              f"{sum(abs(s['error']) <= 0.10 for s in resolved)}/{len(resolved)}; intervals holding the truth: "
              f"{sum(s['covered'] for s in sized)}/{len(sized)}")
    else:
        print(f"\nfamily right: {sum(r['class'] == r['true_class'] for r in rows)}/{len(rows)} (lowest loss: "
              f"{sum(r['lowest_loss_class'] == r['true_class'] for r in rows)}/{len(rows)}); η(γ̇_eff) within "
              f"10 %: {sum(abs(r['error']) <= 0.10 for r in rows)}/{len(rows)} (corotated "
              f"{sum(abs(r['baseline_error']) <= 0.10 for r in rows)}/{len(rows)}); intervals holding the truth: "
              f"{sum(holds(*r['eta_ci95'], r['eta_true']) for r in rows)}/{len(rows)}")
    print(f"{time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
