"""diffstir-plan: the stirring programme that makes a fluid's law identifiable, for the rig and the arm.

    diffstir-plan out=outputs/plan
    diffstir-plan prior.viscosity=[0.01,1] plan.budget=6 plan.radius=0.02
    diffstir-plan after=outputs/fit/report.json out=outputs/next

With ``after``, the sequential mode: the next stir after the stirs whose flow-curve report that is
(``planning.sequential``), or that their family is decided.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import torch
from tqdm import tqdm
from hydra.utils import instantiate, to_absolute_path
from omegaconf import DictConfig, OmegaConf

from diffstir.apps import Run, check_processes, command, config_workers
from diffstir.errors import ConfigError, OutputError
from diffstir.mpm import SimConfig
from diffstir.planning import ArmLimits, PlanSettings, Prior, plan, rig_calibration
from diffstir.planning.result import PROGRAMME, write_programme
from diffstir.planning.sequential import StirSoFar, next_segment
from diffstir.rig import Rig

#: The files a plan writes, and those of the sequential mode's next segment.
FILES = ("plan.json", "plan.md", "plan.png", PROGRAMME, "stir_path.csv")
NEXT_FILES = ("next.json", PROGRAMME, "stir_path.csv")


@command("diffstir-plan", "plan")
def main(cfg: DictConfig) -> None:
    check_processes(cfg)
    torch.set_num_threads(int(cfg.threads))
    rig, sim_config, prior, settings = plan_inputs(cfg)
    out = Path(to_absolute_path(str(cfg.out)))
    existing = [out / name for name in (FILES if cfg.after is None else NEXT_FILES) if (out / name).exists()]
    if existing and not cfg.overwrite:
        raise OutputError(f"{existing[0]}: already exists; give another out= or overwrite=true")
    if cfg.after is not None:
        plan_next(cfg, rig, sim_config, prior, settings, out)
        return
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


def plan_next(cfg: DictConfig, rig: Rig, sim_config: SimConfig, prior: Prior, settings: PlanSettings,
              out: Path) -> None:
    """The sequential mode: ``next.json``, and, unless the stir is decided or its budget spent, the next stir's
    programme and path."""
    so_far = stir_so_far(Path(to_absolute_path(str(cfg.after))))
    with CalibrationProgress() as progress:
        calibration = rig_calibration(rig, prior, settings, sim_config, workers=config_workers(cfg),
                                      cache_dir=cfg.cache_dir, report=progress)
    step = next_segment(so_far, calibration, prior, settings)
    Run.writes(out, *NEXT_FILES)
    (out / "next.json").write_text(json.dumps({**step.to_dict(), "elapsed": so_far.elapsed}, indent=2) + "\n")
    if step.speed is None:
        state = (f"decided: {step.family}" if step.decided
                 else f"not decided ({step.family}); no stir fits the budget left")
        print(f"plan: {state}, confidence {step.confidence:.3g} after {so_far.elapsed:.3g} s of stirring; wrote "
              f"{out / 'next.json'}")
        return
    paths = write_programme(step.programme(settings.radius), out)
    print(f"plan: next stir {step.speed:g} m/s for {step.duration:.3g} s ({step.score:.3g} nats, "
          f"{step.rates[step.speed]:.3g} nats/s; so far "
          f"{step.family or 'no family'}, confidence {step.confidence:.3g}); wrote {out / 'next.json'}, "
          f"{paths['programme']}, {paths['path']}")


def stir_so_far(path: Path) -> StirSoFar:
    """The stir so far from its flow-curve report ``path``, checked in one line."""
    expected = "expected the report.json of diffstir-fit experiment=flow_curve"
    try:
        summary = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise ConfigError(f"after={path}: unreadable ({type(error).__name__}); {expected}") from None
    if not (isinstance(summary, dict) and isinstance(summary.get("joint_fit"), dict)
            and summary["joint_fit"].get("fitted_to") == "points" and isinstance(summary.get("points"), list)):
        raise ConfigError(f"{path}: joint_fit.fitted_to is not 'points'; {expected}")
    try:
        so_far = StirSoFar.from_report(summary)
    except (KeyError, TypeError, ValueError, AttributeError) as error:
        raise ConfigError(f"{path}: points: unreadable ({type(error).__name__}: {error}); {expected}") from None
    if not so_far.speeds:
        raise ConfigError(f"{path}: points: none classified; the stir so far resolved no viscosity")
    return so_far


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
