"""Benchmark of diffstir.diagnosis on virtual-lab recordings with one concealed effect.

Each case is a lab recording (coarse 2-D slice, the paper's rig) of a Newtonian base fluid stirred forwards
(0.06 m/s), held, and stirred backwards at half the speed, read by a component sensor with white noise and
quantisation, plus one effect the fitter is not told about (or none: a clean recording). The Newtonian law is
identified (``identify``, coarse, whole recording) and the recording diagnosed (``diagnose``). Printed and
written to ``--out``: the confusion matrix of the named effect against the concealed one, the false-alarm rate on
clean recordings, the share named right at moderate strength, and the median reduction of the loss where an effect
was present.

    python scripts/diagnosis_benchmark.py                                       # the default run (~31 min, 1 core)
    python scripts/diagnosis_benchmark.py --strengths weak,moderate,strong --clean-seeds 0,1,2,3,4,5   # larger
    python scripts/diagnosis_benchmark.py --effects "" --clean-seeds 2,3,4,5,6,7,8,9   # clean recordings only

Strengths ("moderate"; "weak" is half, "strong" twice): sensor lag τ = 0.1 s; dead band 25 % of the clean
reading's rms; offset drift reaching 30 % of that rms over the recording; a moving mass whose force m a has 30 %
of that rms; thixotropy α = 1 (k = 0.3, t_r = 2 s); viscoelasticity θ = 0.1 s (β = 0.5); a 2 mm slip length;
a viscosity falling by 1 − e^(−0.3) = 26 % over the recording (b = 0.5 1/K, r = 0.32 K/s); a Bingham yield stress
of half the Newtonian stress at U/a.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import time
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

from diffstir.diagnosis import CANDIDATES, DiagnosisSettings, diagnose
from diffstir.fitting import FitSettings
from diffstir.identification import identify
from diffstir.lab import Fluid, HiddenPhysicsSpec, SensorModel, stirring_programme, synthesise
from diffstir.mpm import SimConfig
from diffstir.mpm.hidden_physics import TemperatureDrift, Thixotropy, Viscoelasticity

ROOT = Path(__file__).resolve().parents[1]
EFFECTS = tuple(c for c in CANDIDATES if c != "none")
STRENGTHS = {"weak": 0.5, "moderate": 1.0, "strong": 2.0}
PROGRAMME = dict(segments=[{"speed": 0.06, "duration": 0.8}, {"speed": 0.0, "duration": 0.3},
                           {"speed": -0.03, "duration": 0.8}], radius=0.015, ramp_time=0.15)
SENSOR = SensorModel(mode="component", axis=(0.0, 1.0), sample_rate=100.0, resolution=0.005, noise_std=0.003)
#: The warming truth's sensitivity b [1/K]: only κ = b r shows in a force, and b at the lab's upper bound keeps the
#: rate r within the lab's ±1 K/s for every strength.
WARMING_SENSITIVITY = 0.5
#: The Bingham truth's Papanastasiou rate as a fraction of U/a: half the candidate's (diffstir.diagnosis), so the
#: candidate is not the truth's own law; the lab default (0.01 1/s) would cost ten times the simulation time.
TRUTH_REGULARISATION = 0.05


def fluids() -> dict[str, Fluid]:
    castor = OmegaConf.to_container(OmegaConf.load(ROOT / "conf/lab/fluid/castor_oil.yaml"))
    return {"castor_oil": Fluid.from_mapping(castor),
            "syrup_2Pas": Fluid("syrup 2 Pa s", 1300.0, {"name": "newtonian", "params": {"eta": 2.0}})}


def coarse() -> SimConfig:
    cfg = OmegaConf.to_container(OmegaConf.load(ROOT / "conf/sim/coarse2d.yaml"))
    cfg.pop("_target_")
    return SimConfig(**cfg)


class Lab:
    """Lab recordings of one base fluid: one clean truth simulation, re-read for the sensor-side effects."""

    def __init__(self, fluid: Fluid, config: SimConfig):
        self.fluid, self.config = fluid, config
        self.trajectory = stirring_programme(**PROGRAMME)
        self.clean = synthesise(fluid, self.trajectory, sim_config=config, sensor=SENSOR, seed=0)
        times = self.clean.sim_times
        self.velocity = np.gradient(self.trajectory.poses(times)[0], times, axis=0)
        self.accel = np.gradient(self.velocity, times, axis=0)
        self.rms = float(np.sqrt(np.mean(self.clean.recording.force ** 2)))
        self.duration = self.trajectory.duration
        self.shear_rate = abs(PROGRAMME["segments"][0]["speed"]) / 0.0125  # U/a [1/s], the rig's rod radius

    def reread(self, sensor: SensorModel, seed: int, force_xy=None):
        """The clean truth's force (or ``force_xy`` [N]) read through ``sensor`` with noise from ``seed``."""
        rng = np.random.default_rng(seed)
        force = self.clean.true_force if force_xy is None else force_xy
        reading = sensor.read(self.clean.sim_times, force, self.velocity, self.clean.recording.t, rng)
        return replace(self.clean.recording, force=reading)

    def recording(self, effect: str, strength: float, seed: int):
        """A recording with ``effect`` at ``strength`` (1: moderate) concealed, and its truth parameters."""
        s = strength
        eta = self.fluid.law["params"]["eta"]
        if effect == "none":
            return self.reread(SENSOR, seed), {}
        if effect == "sensor_lag":
            return self.reread(replace(SENSOR, lag_time=0.1 * s), seed), {"lag_time": 0.1 * s}
        if effect == "sensor_deadband":
            return self.reread(replace(SENSOR, dead_band=0.25 * s * self.rms), seed), {"dead_band": 0.25 * s * self.rms}
        if effect == "sensor_drift":
            rate = 0.3 * s * self.rms / self.duration
            return self.reread(replace(SENSOR, drift_rate=rate), seed), {"drift_rate": rate}
        if effect == "inertia":
            along = self.accel @ np.asarray(SENSOR.axis)
            mass = 0.3 * s * self.rms / float(np.sqrt(np.mean(along ** 2)))
            return self.reread(SENSOR, seed, self.clean.true_force - mass * self.accel), {"moving_mass": mass}
        fluid, physics, truth = self.fluid, HiddenPhysicsSpec(), {}
        if effect == "thixotropy":
            physics, truth = HiddenPhysicsSpec(thixotropy=Thixotropy(1.0 * s, 0.3, 2.0)), {"alpha": s}
        elif effect == "viscoelasticity":
            physics = HiddenPhysicsSpec(viscoelasticity=Viscoelasticity(0.1 * s, 0.5))
            truth = {"relaxation_time": 0.1 * s}
        elif effect == "wall_slip":
            physics, truth = HiddenPhysicsSpec(slip_length=2e-3 * s), {"slip_length": 2e-3 * s}
        elif effect == "temperature_drift":
            rate = 0.3 * s / (WARMING_SENSITIVITY * self.duration)
            physics = HiddenPhysicsSpec(temperature=TemperatureDrift(rate, WARMING_SENSITIVITY))
            truth = {"viscosity_drift_rate": rate * WARMING_SENSITIVITY}
        elif effect == "yield_stress":
            tau_y = 0.5 * s * eta * self.shear_rate
            law = {"tau_y": tau_y, "eta_p": eta, "shear_rate_reg": TRUTH_REGULARISATION * self.shear_rate}
            fluid = replace(self.fluid, law={"name": "bingham", "params": law})
            truth = {"tau_y": tau_y}
        else:
            raise ValueError(f"--effects: unknown effect {effect!r}; choose from {list(EFFECTS)}")
        lab = synthesise(fluid, self.trajectory, sim_config=self.config, sensor=SENSOR, physics=physics, seed=seed)
        return lab.recording, truth


def run_case(lab: Lab, effect: str, strength: str, seed: int, config: SimConfig, args, out: Path) -> dict:
    started = time.perf_counter()
    recording, truth = lab.recording(effect, STRENGTHS[strength], seed)
    ident = identify(recording, ["newtonian"], config=config, baseline=False, progress=False, size_estimate=False,
                     fit=FitSettings(window=None, holdout_fraction=0.0, max_iterations=args.identify_iterations))
    diag = diagnose(recording, ident, config=config,
                    settings=DiagnosisSettings(max_iterations=args.max_iterations))
    name = f"{effect}-{strength}-{lab.fluid.name.replace(' ', '_')}-{seed}"
    if args.write_reports:
        diag.write(out / name)
    none, refit = diag.fits["none"], diag.refit
    true_fit = diag.fits.get(effect) if effect != "none" else None
    return {"case": name, "effect": effect, "strength": strength, "fluid": lab.fluid.name, "seed": seed,
            "truth": truth, "verdict": diag.verdict, "best": diag.evidence["best"],
            "runner_up": diag.evidence["runner_up"], "gain_over_none": diag.evidence["gain_over_none"],
            "separation": diag.evidence["separation"], "tied": diag.evidence["tied"],
            "loss_before": none.loss, "loss_after": refit.loss if diag.verdict != "none" else none.loss,
            "loss_true_effect": None if true_fit is None or true_fit.note else true_fit.loss,
            "eta_identified": ident.selected.model.params_si()["eta"],
            "params": refit.params, "simulations": diag.summary()["simulations"], "noise": diag.location["noise"],
            "seconds": time.perf_counter() - started}


def noise_floor(row: dict, out: Path) -> float | None:
    """The loss [N] of a perfect model, mean |noise| = σ sqrt(2/π), σ from the case's row or its written report."""
    sigma = row.get("noise")
    report = out / row["case"] / "diagnosis.json"
    if sigma is None and report.exists():
        sigma = json.loads(report.read_text())["location"]["noise"]
    return None if sigma is None else sigma * math.sqrt(2.0 / math.pi)


def summarise(rows: list[dict], out: Path) -> str:
    """The confusion matrix and the headline rates, as markdown."""
    named = sorted({r["verdict"] for r in rows} | set(EFFECTS) | {"none", "ambiguous"},
                   key=lambda k: (list(EFFECTS) + ["none", "ambiguous"]).index(k))
    concealed = [e for e in list(EFFECTS) + ["none"] if any(r["effect"] == e for r in rows)]
    short = {e: e.replace("sensor_", "s_").replace("temperature", "temp").replace("viscoelasticity", "visco")
             .replace("thixotropy", "thixo") for e in named}
    lines = ["| concealed \\ named | " + " | ".join(short[n] for n in named) + " |",
             "|---" * (len(named) + 1) + "|"]
    for e in concealed:
        counts = [sum(1 for r in rows if r["effect"] == e and r["verdict"] == n) for n in named]
        lines.append(f"| {e} | " + " | ".join(str(c) if c else "." for c in counts) + " |")
    clean = [r for r in rows if r["effect"] == "none"]
    moderate = [r for r in rows if r["effect"] != "none" and r["strength"] == "moderate"]
    present = [r for r in rows if r["effect"] != "none"]
    right = sum(r["verdict"] == r["effect"] for r in moderate)
    ambiguous = sum(r["verdict"] == "ambiguous" for r in moderate)
    alarms = sum(r["verdict"] != "none" for r in clean)
    reductions = [1.0 - r["loss_after"] / r["loss_before"] for r in present]
    true_reductions = [1.0 - r["loss_true_effect"] / r["loss_before"] for r in present if r["loss_true_effect"]]
    floors = [(r, noise_floor(r, out)) for r in present]
    excess = [(r["loss_before"] - r["loss_after"]) / (r["loss_before"] - f) for r, f in floors
              if f is not None and r["loss_before"] > f]
    lines += ["",
              f"- named right at moderate strength: {right}/{len(moderate)}"
              + (f" ({right / len(moderate):.0%}); ambiguous: {ambiguous}" if moderate else ""),
              f"- false alarms on clean recordings: {alarms}/{len(clean)}"
              + (f" ({alarms / len(clean):.0%})" if clean else ""),
              f"- median loss reduction where an effect was present, by the refit the diagnosis adopted: "
              f"{statistics.median(reductions):.0%}" if reductions else "- no effect cases",
              f"- median loss reduction by the true effect's candidate: {statistics.median(true_reductions):.0%}"
              if true_reductions else "- no true-effect fits",
              f"- median share of the loss above the noise floor σ sqrt(2/π) removed by the adopted refit: "
              f"{statistics.median(excess):.0%}" if excess else "- no noise floors",
              f"- cases: {len(rows)}; wall time {sum(r['seconds'] for r in rows) / 60:.1f} min "
              f"(median {statistics.median(r['seconds'] for r in rows):.0f} s per case)"]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fluids", default="castor_oil,syrup_2Pas", help="base fluids (comma-separated)")
    parser.add_argument("--effects", default=",".join(EFFECTS), help="concealed effects (comma-separated)")
    parser.add_argument("--strengths", default="moderate", help="weak, moderate, strong (comma-separated)")
    parser.add_argument("--clean-seeds", default="0,1", help="sensor-noise seeds of the clean recordings")
    parser.add_argument("--seed", type=int, default=0, help="sensor-noise seed of the effect recordings")
    parser.add_argument("--max-iterations", type=int, default=3, help="Gauss-Newton evaluations per physics fit")
    parser.add_argument("--identify-iterations", type=int, default=3, help="Gauss-Newton evaluations, Newtonian")
    parser.add_argument("--out", default="outputs/diagnosis_benchmark", help="results directory")
    parser.add_argument("--write-reports", action="store_true", help="also write each case's diagnosis report")
    parser.add_argument("--resume", action="store_true", help="keep the cases already in --out/results.jsonl")
    args = parser.parse_args()
    torch.set_num_threads(1)
    config = coarse()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    all_fluids = fluids()
    unknown = sorted(set(args.fluids.split(",")) - set(all_fluids))
    if unknown:
        raise SystemExit(f"--fluids: unknown {unknown}; choose from {sorted(all_fluids)}")
    strengths = args.strengths.split(",")
    if set(strengths) - set(STRENGTHS):
        raise SystemExit(f"--strengths: choose from {list(STRENGTHS)}")
    started = datetime.now(timezone.utc)
    results = out / "results.jsonl"
    rows = [json.loads(line) for line in results.read_text().splitlines()] if args.resume and results.exists() else []
    done = {r["case"] for r in rows}
    with open(results, "a" if args.resume else "w") as log:
        for fluid_name in args.fluids.split(","):
            fluid = all_fluids[fluid_name]
            cases = [("none", "moderate", int(s)) for s in args.clean_seeds.split(",") if s]
            cases += [(e, st, args.seed) for e in args.effects.split(",") if e for st in strengths]
            cases = [c for c in cases if f"{c[0]}-{c[1]}-{fluid.name.replace(' ', '_')}-{c[2]}" not in done]
            lab = Lab(fluid, config) if cases else None
            for effect, strength, seed in cases:
                row = run_case(lab, effect, strength, seed, config, args, out)
                rows.append(row)
                log.write(json.dumps(row, default=float) + "\n")
                log.flush()
                print(f"{row['case']}: {row['verdict']} (best {row['best']}, ΔBIC {row['gain_over_none']:.1f}, "
                      f"separation {row['separation']:.1f}); loss {row['loss_before']:.4g} -> "
                      f"{row['loss_after']:.4g} N; {row['seconds']:.0f} s", flush=True)
    text = summarise(rows, out)
    header = (f"diagnosis benchmark, started {started:%Y-%m-%d %H:%M} UTC on {platform.machine()} "
              f"({platform.processor() or 'cpu'}), torch {torch.__version__}, 1 thread")
    (out / "summary.md").write_text(header + "\n\n" + text + "\n")
    print(header)
    print(text)


if __name__ == "__main__":
    main()
