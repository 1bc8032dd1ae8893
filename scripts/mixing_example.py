"""Mixing in the virtual lab, end to end: two Newtonian fluids stirred together (``diffstir.lab.synthesise_blend``),
the apparent viscosity's time course from the recording alone (``diffstir.mixing.analyse_mixing``), and both
against the truth: the dissipation-weighted viscosity and the 95 % mixing time of the concentration field, and,
window by window, the Newtonian-equivalent viscosity (``--equivalent K``): the viscosity of the homogeneous
Newtonian fluid (the blend's density) whose truth force on the rod has the blend's mean magnitude in that window,
on the truth's own grid, interpolated in ln-ln between K such fluids log-spaced from η2 to η1. It is what a
window's Newtonian fit reads at best: the dissipation-weighted viscosity of a field that is not yet mixed need not
drag the rod as hard as any homogeneous fluid of that viscosity (docs/mixing.md).

    python scripts/mixing_example.py [--out DIR] [--duration 6] [--window 0.75] [--viscosities 1.0 0.1]
        [--fraction 0.5] [--layout core] [--strain-mixing 0.3]
    python scripts/mixing_example.py --fit-sim sim/slice2d.yaml --truth-sim lab/sim/truth2d.yaml --truth-dx 0 \
        --model-error 0.03    # the 2.5 mm grid against a 2 mm truth instead of 5 mm against 4 mm, about 4x slower

Writes DIR/blend (recording), DIR/blend.truth.json, DIR/report/report.json and time_course.png, DIR/equivalent.json
(the Newtonian-equivalent truth per window), and prints a markdown summary.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import yaml
from hydra.utils import instantiate
from omegaconf import OmegaConf

from diffstir.fitting.uncertainty import COARSE_FORCE_ERROR
from diffstir.lab import (Blend, Fluid, SensorModel, simulate_truth, stirring_programme, synthesise_blend,
                          write_lab_recording)
from diffstir.mixing import MixingSettings, analyse_mixing
from diffstir.rheology.blending import blend_range, lederer_roegiers

ROOT = Path(__file__).resolve().parents[1]
ALPHA = 0.6  # the truth's Lederer-Roegiers α [1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("outputs/mixing-example"))
    parser.add_argument("--duration", type=float, default=6.0, help="s of stirring at 0.08 m/s")
    parser.add_argument("--window", type=float, default=0.75, help="s per window of the time course")
    parser.add_argument("--fit-sim", default="sim/coarse2d.yaml", help="fitting grid, a file under conf/")
    parser.add_argument("--truth-sim", default="sim/coarse2d.yaml", help="truth grid, a file under conf/")
    parser.add_argument("--truth-dx", type=float, default=0.004, help="truth cell size [m] (0: the file's)")
    parser.add_argument("--model-error", type=float, default=COARSE_FORCE_ERROR,
                        help="relative force error of the fitting grid (0.03 for sim/slice2d.yaml)")
    parser.add_argument("--viscosities", type=float, nargs=2, default=[1.0, 0.1], help="eta1 > eta2 [Pa s]")
    parser.add_argument("--fraction", type=float, default=0.5, help="volume fraction of fluid 1 [1]")
    parser.add_argument("--layout", default="core", help="where fluid 1 starts: core, annulus, half")
    parser.add_argument("--strain-mixing", type=float, default=0.3, help="IEM mixing per unit shear strain [1]")
    parser.add_argument("--equivalent", type=int, default=5, help="homogeneous Newtonian truths for the "
                        "Newtonian-equivalent truth per window (0: none)")
    args = parser.parse_args()
    (eta1, eta2), fraction = args.viscosities, args.fraction
    torch.set_num_threads(1)
    fit_config = instantiate(OmegaConf.load(ROOT / "conf" / args.fit_sim))
    truth_config = instantiate(OmegaConf.load(ROOT / "conf" / args.truth_sim))
    if args.truth_dx:
        truth_config = replace(truth_config, dx=args.truth_dx)
    sensor = SensorModel(**yaml.safe_load((ROOT / "conf" / "lab" / "sensor" / "paper.yaml").read_text()))
    blend = Blend(first=Fluid(name="viscous", density=1260.0, law={"name": "newtonian", "params": {"eta": eta1}}),
                  second=Fluid(name="thin", density=1000.0, law={"name": "newtonian", "params": {"eta": eta2}}),
                  fraction=fraction, alpha=ALPHA, layout=args.layout, strain_mixing=args.strain_mixing)
    trajectory = stirring_programme([{"speed": 0.08, "duration": args.duration}], radius=0.015, ramp_time=0.2)
    started = time.perf_counter()
    lab = synthesise_blend(blend, trajectory, sim_config=truth_config, sensor=sensor,
                           name="blend")
    recording_dir, truth_file = write_lab_recording(lab, args.out / "blend", overwrite=True)
    truth_seconds = time.perf_counter() - started
    result = analyse_mixing(lab.recording, config=fit_config,
                            settings=MixingSettings(viscosities=[eta1, eta2], fraction=fraction, window=args.window,
                                                    model_error=args.model_error))
    result.write(args.out / "report")
    m = result.summary()["mixing"]
    history = json.loads(truth_file.read_text())["mixing"]
    low, high = blend_range(eta1, eta2, fraction)
    print("| quantity | from the recording | truth |\n|---|---|---|")
    print(f"| blend viscosity [Pa·s] | {m['blend_viscosity']:.4g} ({m['blend_viscosity_ci95'][0]:.4g}-"
          f"{m['blend_viscosity_ci95'][1]:.4g}) | {lederer_roegiers(eta1, eta2, fraction, ALPHA):.4g} (rule, "
          f"homogeneous); {history['dissipation_viscosity'][-1]:.4g} (dissipation-weighted at the end) |")
    print(f"| Lederer-Roegiers range α ∈ [0, 1] [Pa·s] | {low:.4g}-{high:.4g}, blend inside: "
          f"{m['lederer_roegiers']['blend_in_range']} | - |")
    alpha_ci = m["lederer_roegiers"]["implied_alpha_ci95"]
    print(f"| implied α | {m['lederer_roegiers']['implied_alpha']} ({alpha_ci[0]}-{alpha_ci[1]}) | {ALPHA} |")
    print(f"| time to homogeneity [s] | {m['homogeneity_time']:.3g} | {history['mixing_time_95']} (CoV of c < 5 %) |")
    print(f"| first window viscosity [Pa·s] | {m['time_course'][0]['viscosity']:.4g} | "
          f"{np.interp(m['time_course'][0]['time'], history['times'], history['dissipation_viscosity']):.4g} |")
    windows = m["time_course"]
    times, dissipation = np.array(history["times"]), np.array(history["dissipation_viscosity"])
    print("\n| window [s] | from the recording [Pa·s] (95 % CI) | truth, dissipation-weighted | truth, "
          "Newtonian-equivalent |\n|---|---|---|---|")
    equivalent = (newtonian_equivalent(lab, blend, trajectory, truth_config, windows, args.equivalent)
                  if args.equivalent else [None] * len(windows))
    for w, eq in zip(windows, equivalent):
        inside = (times >= w["start"]) & (times <= w["end"])
        print(f"| {w['start']:.2f}-{w['end']:.2f} | {w['viscosity']:.3g} ({w['viscosity_ci95'][0]:.3g}-"
              f"{w['viscosity_ci95'][1]:.3g}) | {dissipation[inside].mean():.3g} | {_fmt(eq)} |")
    (args.out / "equivalent.json").write_text(json.dumps(
        {"windows": [{"start": w["start"], "end": w["end"], "newtonian_equivalent": eq} for w, eq in
                     zip(windows, equivalent)], "ladder": args.equivalent, "units": {"newtonian_equivalent": "Pa s"}}))
    print(f"\ntruth {truth_seconds:.0f} s, analysis {result.seconds:.0f} s; wrote {recording_dir} and "
          f"{args.out / 'report'}")


def newtonian_equivalent(lab, blend: Blend, trajectory, truth_config, windows: list[dict], count: int
                         ) -> list[float | None]:
    """Per window, the Newtonian-equivalent truth viscosity [Pa·s] (module docstring); None where the blend's
    mean |force| lies outside the homogeneous fluids' range or they do not drag more as η grows."""
    eta1, eta2 = (fluid.law["params"]["eta"] for fluid in (blend.first, blend.second))
    ladder = np.geomspace(eta2, eta1, count)

    def window_means(times: np.ndarray, force: np.ndarray) -> np.ndarray:
        magnitude = np.linalg.norm(force, axis=1)
        return np.array([magnitude[(times >= w["start"]) & (times <= w["end"])].mean() for w in windows])

    blended = window_means(lab.sim_times, lab.true_force)
    homogeneous = np.array([window_means(t.times, t.force) for t in (
        simulate_truth(Fluid(name=f"newtonian {eta:.3g}", density=blend.density,
                             law={"name": "newtonian", "params": {"eta": float(eta)}}), trajectory,
                       sim_config=truth_config) for eta in ladder)])
    result = []
    for k, target in enumerate(blended):
        drag = homogeneous[:, k]
        inside = bool(np.all(np.diff(drag) > 0) and drag[0] <= target <= drag[-1])
        result.append(float(np.exp(np.interp(np.log(target), np.log(drag), np.log(ladder)))) if inside else None)
    return result


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.3g}"


if __name__ == "__main__":
    main()
