"""diffstir-plan: the stirring programme that makes a fluid's law identifiable, for the rig and the arm.

    diffstir-plan out=outputs/plan
    diffstir-plan prior.viscosity=[0.01,1] plan.budget=6 plan.radius=0.02
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch
from tqdm import tqdm
from hydra.utils import instantiate, to_absolute_path
from omegaconf import DictConfig, OmegaConf

from diffstir.apps import Run, check_processes, command, config_workers
from diffstir.errors import ConfigError, OutputError
from diffstir.mpm import SimConfig
from diffstir.planning import ArmLimits, PlanSettings, Prior, plan
from diffstir.planning.result import PROGRAMME
from diffstir.rig import Rig

#: The files a plan writes.
FILES = ("plan.json", "plan.md", "plan.png", PROGRAMME, "stir_path.csv")


@command("diffstir-plan", "plan")
def main(cfg: DictConfig) -> None:
    check_processes(cfg)
    torch.set_num_threads(int(cfg.threads))
    rig, sim_config, prior, settings = plan_inputs(cfg)
    out = Path(to_absolute_path(str(cfg.out)))
    existing = [out / name for name in FILES if (out / name).exists()]
    if existing and not cfg.overwrite:
        raise OutputError(f"{existing[0]}: already exists; give another out= or overwrite=true")
    with CalibrationProgress() as progress:
        result = plan(rig, prior, settings, config=sim_config, workers=config_workers(cfg),
                      cache_dir=cfg.cache_dir, report=progress)
    Run.writes(out, *FILES)
    paths = result.write(out)
    programme = result.assessment.programme
    print(f"plan: {', '.join(f'{u:g}' for u in programme.speeds)} m/s for {programme.duration:.3g} s each on a "
          f"{1000 * programme.radius:g} mm circle; criterion {result.assessment.score:.3g} nats against "
          f"{result.baseline.score:.3g} at {settings.baseline_speed:g} m/s alone ({result.seconds:.0f} s); wrote "
          + ", ".join(str(paths[k]) for k in ("md", "programme", "path")))


class CalibrationProgress:
    """Says when the rig is calibrated, and counts its simulations on a progress bar."""

    def __init__(self):
        self.bar = None

    def __call__(self, event: tuple) -> None:
        if event[0] == "calibration":
            print(f"diffstir-plan: calibrating this rig on the fitting simulator, once: {event[1]} simulations "
                  f"(cached in {event[2]})", flush=True)
            self.bar = tqdm(total=event[1], unit="simulation", leave=False)
        elif event[0] == "evaluation" and self.bar is not None:
            self.bar.update(1)

    def __enter__(self) -> "CalibrationProgress":
        return self

    def __exit__(self, *exc) -> None:
        if self.bar is not None:
            self.bar.close()


def plan_inputs(cfg: DictConfig) -> tuple[Rig, SimConfig, Prior, PlanSettings]:
    """The rig, the fitting simulator, the prior and the plan's settings of the config, each checked."""
    rig, sim_config = instantiate(cfg.rig), instantiate(cfg.sim)
    prior = _settings(Prior, cfg.prior, "prior")
    node = OmegaConf.to_container(cfg.plan, resolve=True)
    arm = _settings(ArmLimits, node.pop("arm", {}), "plan.arm")
    settings = _settings(PlanSettings, {**node, "arm": arm}, "plan")
    settings.check_rig(rig)
    return rig, sim_config, prior, settings


def _settings(cls, node, prefix: str):
    """``cls`` built from the config ``node`` (lists as tuples), an unknown key refused in one line."""
    values = OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ConfigError(f"{prefix}: unknown setting {unknown[0]!r}; expected one of {sorted(known)}")
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


if __name__ == "__main__":
    main()
