"""diffstir-synth: write a virtual-lab recording and, beside it, the truth it was made from.

    diffstir-synth lab/fluid=ketchup lab/programme=speed_steps lab/physics=thixotropic seed=3 out=outputs/lab
    diffstir-synth lab/blend=f60_water lab/programme=paper out=outputs/lab      # two fluids mixing (docs/mixing.md)
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from dataclasses import fields
from pathlib import Path
from typing import NamedTuple

from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate, to_absolute_path
from omegaconf import DictConfig, OmegaConf

from diffstir.apps import Run, command
from diffstir.errors import ConfigError, DiffstirError, OutputError, check_choices
from diffstir.lab import (
    Blend, FiniteElementTruth, Fluid, HiddenPhysicsSpec, SensorModel, programme_path, synthesise,
    synthesise_blend, truth_path, write_lab_recording,
)
from diffstir.mpm import SimConfig
from diffstir.rig import Rig
from diffstir.trajectory import Trajectory


@command("diffstir-synth", "synth")
def main(cfg: DictConfig) -> None:
    setup = lab_setup(cfg)
    choices = HydraConfig.get().runtime.choices
    name = cfg.name or choices["lab/blend" if setup.blend else "lab/fluid"]
    path = Path(to_absolute_path(str(cfg.out))) / name
    for existing in (path, truth_path(path)):
        if existing.exists() and not cfg.overwrite:
            raise OutputError(f"{existing}: already exists; give another name= or out=, or overwrite=true")
    started = time.perf_counter()
    common = dict(rig=setup.rig, sim_config=setup.sim_config, sensor=setup.sensor, seed=int(cfg.seed), name=name,
                  label=cfg.label, programme=setup.programme)
    if setup.blend:
        result = synthesise_blend(setup.blend, setup.trajectory, **common)
    else:
        result = synthesise(setup.fluid, setup.trajectory, physics=setup.physics, **common)
    Run.writes(path.parent)
    recording, truth = write_lab_recording(result, path, overwrite=bool(cfg.overwrite))
    print(f"{result.truth['simulator']['steps']} steps of {result.truth['simulator']['dt']:.3g} s in "
          f"{time.perf_counter() - started:.0f} s; wrote {recording} ({result.recording.t.size} rows) and {truth}")


class LabSetup(NamedTuple):
    """What a ``diffstir-synth`` configuration describes, built: the rig, the truth's simulation settings, the
    fluid (or the blend of two), the stirring programme (its mapping and its trajectory), the sensor and the hidden
    physics."""

    rig: Rig
    sim_config: SimConfig | FiniteElementTruth
    fluid: Fluid
    blend: Blend | None
    programme: dict
    trajectory: Trajectory
    sensor: SensorModel
    physics: HiddenPhysicsSpec


def lab_setup(cfg: DictConfig) -> LabSetup:
    """The ``LabSetup`` of a composed ``synth`` configuration; a wrong setting raises a ConfigError that names its
    group before any simulation."""
    lab = OmegaConf.to_container(cfg.lab, resolve=True)
    programme = lab["programme"]
    with _refused_as("lab/programme"):
        trajectory = programme_path(programme)
    with _refused_as("lab/fluid"):
        fluid = Fluid.from_mapping(lab["fluid"])
    with _refused_as("lab/blend"):
        blend = _blend(lab["blend"]) if lab.get("blend") else None
    check_choices("lab.sensor", list(lab["sensor"]), [f.name for f in fields(SensorModel)])
    with _refused_as("lab/sensor"):
        sensor = SensorModel(**lab["sensor"])
    with _refused_as("lab/physics"):
        physics = HiddenPhysicsSpec.from_mapping(lab["physics"])
    return LabSetup(rig=instantiate(cfg.rig), sim_config=instantiate(cfg.lab.sim), fluid=fluid, blend=blend,
                    programme=programme, trajectory=trajectory, sensor=sensor, physics=physics)


@contextlib.contextmanager
def _refused_as(group: str) -> Iterator[None]:
    """Raise a lab's ValueError, TypeError or KeyError (a value outside its range, an unknown or a missing field)
    as a ConfigError that names the config ``group``."""
    try:
        yield
    except DiffstirError:
        raise
    except KeyError as error:
        raise ConfigError(f"{group}: no setting {error.args[0]!r} (conf/{group}/ shows each group's settings)"
                          ) from error
    except (TypeError, ValueError) as error:
        raise ConfigError(f"{group}: {error}") from error


def _blend(cfg: dict) -> Blend:
    """A ``Blend`` from a ``lab/blend`` config: two fluid mappings and the mixing settings."""
    settings = {k: v for k, v in cfg.items() if k not in ("first", "second")}
    return Blend(first=Fluid.from_mapping(cfg["first"]), second=Fluid.from_mapping(cfg["second"]), **settings)


if __name__ == "__main__":
    main()
