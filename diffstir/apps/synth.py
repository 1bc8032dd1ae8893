"""diffstir-synth: write a virtual-lab recording and, beside it, the truth it was made from.

    diffstir-synth lab/fluid=ketchup lab/programme=speed_steps lab/physics=thixotropic seed=3 out=outputs/lab
    diffstir-synth lab/blend=f60_water lab/programme=paper out=outputs/lab      # two fluids mixing (docs/mixing.md)
"""

from __future__ import annotations

import time
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate, to_absolute_path
from omegaconf import DictConfig, OmegaConf

from diffstir.apps import Run, command
from diffstir.errors import OutputError
from diffstir.lab import (
    Blend, Fluid, HiddenPhysicsSpec, SensorModel, stirring_programme, synthesise, synthesise_blend, truth_path,
    write_lab_recording,
)


@command("diffstir-synth", "synth")
def main(cfg: DictConfig) -> None:
    lab = OmegaConf.to_container(cfg.lab, resolve=True)
    rig, sim_config = instantiate(cfg.rig), instantiate(cfg.lab.sim)
    fluid = Fluid.from_mapping(lab["fluid"])
    programme = lab["programme"]
    trajectory = stirring_programme(programme["segments"], radius=programme["radius"],
                                    ramp_time=programme["ramp_time"], start_angle=programme["start_angle"])
    choices = HydraConfig.get().runtime.choices
    name = cfg.name or choices["lab/blend" if lab.get("blend") else "lab/fluid"]
    path = Path(to_absolute_path(str(cfg.out))) / name
    for existing in (path, truth_path(path)):
        if existing.exists() and not cfg.overwrite:
            raise OutputError(f"{existing}: already exists; give another name= or out=, or overwrite=true")
    started = time.perf_counter()
    sensor = SensorModel(**lab["sensor"])
    if lab.get("blend"):
        result = synthesise_blend(_blend(lab["blend"]), trajectory, rig=rig, sim_config=sim_config, sensor=sensor,
                                  seed=int(cfg.seed), name=name, label=cfg.label, programme=programme)
    else:
        result = synthesise(fluid, trajectory, rig=rig, sim_config=sim_config, sensor=sensor,
                            physics=HiddenPhysicsSpec.from_mapping(lab["physics"]), seed=int(cfg.seed), name=name,
                            label=cfg.label, programme=programme)
    Run.writes(path.parent)
    recording, truth = write_lab_recording(result, path, overwrite=bool(cfg.overwrite))
    print(f"{result.truth['simulator']['steps']} steps of {result.truth['simulator']['dt']:.3g} s in "
          f"{time.perf_counter() - started:.0f} s; wrote {recording} ({result.recording.t.size} rows) and {truth}")


def _blend(cfg: dict) -> Blend:
    """A ``Blend`` from a ``lab/blend`` config: two fluid mappings and the mixing settings."""
    settings = {k: v for k, v in cfg.items() if k not in ("first", "second")}
    return Blend(first=Fluid.from_mapping(cfg["first"]), second=Fluid.from_mapping(cfg["second"]), **settings)


if __name__ == "__main__":
    main()
