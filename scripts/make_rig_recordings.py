"""Short virtual-lab recordings with the effects a real rig's recordings have, bundled as test data in
diffstir/data/examples/ (each with its truth file beside it; docs/virtual-lab.md, Recordings as rigs write them).

    python scripts/make_rig_recordings.py [--out diffstir/data/examples] [--only rig_dead_start ...] [--overwrite]

| recording | fluid | stir | sensor preset (conf/lab/sensor/) |
|---|---|---|---|
| rig_jitter_1khz | carreau_example | 15 mm circle, 0.10 m/s, 1.0 s | rig_tracker_1khz: 30 um position jitter, 1 kHz |
| rig_dead_start | carreau_example | 15 mm circle, 0.10 m/s, 1.5 s | rig_thin_film_1khz: one-sided, 0.4 s dead start |
| rig_behaviour_slow, _mid, _fast | carreau_example | 6 mm circle at 0.03, 0.06, 0.12 m/s, 1.4, 0.8, 0.55 s | rig_encoder_200hz: 1 um |
| rig_blend | 1.0 and 0.1 Pa s Newtonian, half each | 15 mm circle, 0.08 m/s, 2.4 s (four 0.5 s windows of the default mixing experiment) | rig_encoder_200hz |
| rig_fe3d_6s | carreau_example | 15 mm circle, 0.05 m/s, 6 s | paper |
| rig_planned_short | carreau_example | conf/lab/programme/paper_plan.yaml's four speeds, 0.8 s each instead of 2 s | paper |

The truth simulation is the lab's default (conf/lab/sim/truth2d.yaml, 2 mm cells) in the paper's rig
(conf/rig/paper.yaml), except rig_fe3d_6s's: the stir in the 3-D cup by finite elements (conf/lab/sim/fe3d.yaml);
seed 0 for each. The blend is scripts/mixing_example.py's (α = 0.6, core layout, 0.3 mixing
per unit strain).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch
import yaml
from hydra.utils import instantiate
from omegaconf import OmegaConf

from diffstir.lab import (
    Blend, Fluid, HiddenPhysicsSpec, SensorModel, programme_path, synthesise, synthesise_blend,
    write_lab_recording,
)

ROOT = Path(__file__).resolve().parents[1]
RAMP = 0.1  # s: each programme's cosine ramp from rest


def _preset(group: str, name: str) -> dict:
    return yaml.safe_load((ROOT / "conf" / "lab" / group / f"{name}.yaml").read_text())


def _programme(radius: float, speed: float, duration: float) -> dict:
    """One constant-speed segment on a circle of ``radius`` [m] at ``speed`` [m/s] for ``duration`` [s]."""
    return {"radius": radius, "ramp_time": RAMP, "start_angle": 0.0,
            "segments": [{"speed": speed, "duration": duration}]}


def _shortened(name: str, duration: float) -> dict:
    """The programme preset ``conf/lab/programme/<name>.yaml`` with every segment lasting ``duration`` [s]."""
    programme = _preset("programme", name)
    return {**programme, "segments": [{**segment, "duration": duration} for segment in programme["segments"]]}


BLEND = {"first": {"name": "viscous", "density": 1260.0, "law": {"name": "newtonian", "params": {"eta": 1.0}}},
         "second": {"name": "thin", "density": 1000.0, "law": {"name": "newtonian", "params": {"eta": 0.1}}},
         "fraction": 0.5, "alpha": 0.6, "layout": "core", "strain_mixing": 0.3}

#: name -> (programme, sensor preset, blend or None, truth preset in conf/lab/sim/)
RECORDINGS = {
    "rig_jitter_1khz": (_programme(0.015, 0.10, 1.0), "rig_tracker_1khz", None, "truth2d"),
    "rig_dead_start": (_programme(0.015, 0.10, 1.5), "rig_thin_film_1khz", None, "truth2d"),
    "rig_behaviour_slow": (_programme(0.006, 0.03, 1.4), "rig_encoder_200hz", None, "truth2d"),
    "rig_behaviour_mid": (_programme(0.006, 0.06, 0.8), "rig_encoder_200hz", None, "truth2d"),
    "rig_behaviour_fast": (_programme(0.006, 0.12, 0.55), "rig_encoder_200hz", None, "truth2d"),
    "rig_blend": (_programme(0.015, 0.08, 2.4), "rig_encoder_200hz", BLEND, "truth2d"),
    "rig_fe3d_6s": (_programme(0.015, 0.05, 6.0), "paper", None, "fe3d"),
    "rig_planned_short": (_shortened("paper_plan", 0.8), "paper", None, "truth2d"),
}


def make(name: str, out: Path, overwrite: bool) -> None:
    programme, sensor_preset, blend, truth = RECORDINGS[name]
    rig = instantiate(OmegaConf.load(ROOT / "conf" / "rig" / "paper.yaml"))
    sim_config = instantiate(OmegaConf.load(ROOT / "conf" / "lab" / "sim" / f"{truth}.yaml"))
    sensor = SensorModel(**_preset("sensor", sensor_preset))
    trajectory = programme_path(programme)
    started = time.perf_counter()
    if blend is not None:
        lab = synthesise_blend(Blend.from_mapping(blend), trajectory, rig=rig, sim_config=sim_config, sensor=sensor,
                               seed=0, name=name, programme=programme)
    else:
        lab = synthesise(Fluid.from_mapping(_preset("fluid", "carreau_example")), trajectory, rig=rig,
                         sim_config=sim_config, sensor=sensor, physics=HiddenPhysicsSpec(), seed=0, name=name,
                         programme=programme)
    lab.truth["sensor_preset"] = sensor_preset
    recording, truth = write_lab_recording(lab, out / name, overwrite=overwrite)
    print(f"{recording} ({lab.recording.t.size} rows) and {truth} in {time.perf_counter() - started:.0f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "diffstir" / "data" / "examples")
    parser.add_argument("--only", nargs="*", choices=sorted(RECORDINGS), default=sorted(RECORDINGS))
    parser.add_argument("--overwrite", action="store_true", help="replace recordings that exist")
    args = parser.parse_args()
    torch.set_num_threads(1)
    for name in args.only:
        make(name, args.out, args.overwrite)


if __name__ == "__main__":
    main()
