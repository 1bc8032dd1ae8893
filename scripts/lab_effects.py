"""Example recordings of the virtual lab with and without each sensor effect and each hidden-physics effect, for
docs/virtual-lab.md.

    python scripts/lab_effects.py --out docs/figures

One fluid (castor oil, the preset) is stirred forwards, rests and is stirred backwards on the truth grid given by
``--dx`` (the shipped figures: 4 mm, to keep the run short). Sensor effects: one truth simulation read by the
ideal sensor and by the ideal sensor with each effect of the paper's sensor preset alone (and the one-sided
thin-film sensor). Hidden physics: one truth simulation per effect preset of conf/lab/physics/, read by the ideal
sensor. The script prints the mean |reading| of each against the effect-free one.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import matplotlib
import numpy as np
import torch
import yaml

from diffstir.lab import Fluid, HiddenPhysicsSpec, SensorModel, read_truth, simulate_truth, stirring_programme
from diffstir.mpm import SimConfig

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SEGMENTS = [{"speed": 0.06, "duration": 1.5}, {"speed": 0.0, "duration": 0.7}, {"speed": -0.06, "duration": 1.5}]


def preset(group: str, name: str) -> dict:
    return yaml.safe_load((ROOT / "conf" / "lab" / group / f"{name}.yaml").read_text())


def plot_effects(base, recordings: dict, kind: str, base_label: str, colour: str, reference: float, *,
                 row_height: float, title: str, path: Path) -> None:
    """One panel per recording against the effect-free ``base``; print each one's mean |reading| [N] and its
    change from ``reference`` as a table row labelled ``kind``."""
    fig, axes = plt.subplots(len(recordings), 1, figsize=(8, row_height * len(recordings)), sharex=True)
    for ax, (name, rec) in zip(axes, recordings.items()):
        ax.plot(base.t, base.force, "k-", lw=0.8, label=base_label)
        ax.plot(rec.t, rec.force, f"{colour}-", lw=0.8, label=name)
        ax.legend(loc="upper right", fontsize=7)
        ax.set_ylabel("F [N]")
        mean = float(np.mean(np.abs(rec.force)))
        print(f"| {kind}: {name} | {mean:.4f} | {100 * (mean / reference - 1):+.1f} % |")
    axes[-1].set_xlabel("t [s]")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("docs/figures"))
    parser.add_argument("--dx", type=float, default=0.004, help="truth cell size [m]")
    args = parser.parse_args()
    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    config = replace(SimConfig(dim=2), dx=args.dx)
    fluid = Fluid.from_mapping(preset("fluid", "castor_oil"))
    trajectory = stirring_programme(SEGMENTS, radius=0.015, ramp_time=0.2)
    ideal = SensorModel(**{**preset("sensor", "ideal"), "mode": "component", "axis": (0.0, 1.0),
                           "sample_rate": 100.0})
    paper = preset("sensor", "paper")
    started = time.perf_counter()
    truth = simulate_truth(fluid, trajectory, sim_config=config)
    base = read_truth(truth, ideal).recording
    sensor_effects = {key: {key: paper[key]} for key in
                      ("noise_std", "resolution", "lag_time", "drift_rate", "drift_walk", "offset")}
    sensor_effects["gain_error 3 %"] = {"gain_error": 0.03}
    sensor_effects["dead_band 10 mN"] = {"dead_band": 0.01}
    sensor_effects["one-sided (thin film)"] = {"one_sided": True}
    physics = {name: HiddenPhysicsSpec.from_mapping(preset("physics", name))
               for name in ("thixotropic", "viscoelastic", "wall_slip", "warming")}

    print("| effect | mean abs reading [N] | change |\n|---|---|---|")
    reference = float(np.mean(np.abs(base.force)))
    print(f"| none (ideal sensor) | {reference:.4f} | - |")
    sensed = {name: read_truth(truth, SensorModel(**{**ideal.as_dict(), **change}), seed=1).recording
              for name, change in sensor_effects.items()}
    plot_effects(base, sensed, "sensor", "ideal sensor", "C1", reference, row_height=1.6,
                 title="castor oil, stir / rest / reverse: each sensor effect alone",
                 path=args.out / "lab_sensor_effects.png")
    hidden = {name: read_truth(simulate_truth(fluid, trajectory, sim_config=config, physics=spec), ideal).recording
              for name, spec in physics.items()}
    plot_effects(base, hidden, "physics", "no hidden physics", "C0", reference, row_height=1.8,
                 title="castor oil, stir / rest / reverse: each hidden-physics preset (ideal sensor)",
                 path=args.out / "lab_physics_effects.png")
    print(f"\n{time.perf_counter() - started:.0f} s; wrote {args.out}/lab_sensor_effects.png and "
          f"lab_physics_effects.png")


if __name__ == "__main__":
    main()
