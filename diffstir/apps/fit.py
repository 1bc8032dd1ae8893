"""diffstir-fit: identify the fluid in a recording and write report.json, report.md, plots and TensorBoard logs.

    diffstir-fit recording=diffstir/data/examples/carreau_example out=outputs/carreau
    python -m diffstir.fit recording=diffstir/data/examples/carreau_example model=[newtonian,carreau]
    diffstir-fit experiment=behaviour recordings=[rec/slow,rec/fast] out=outputs/behaviour    # docs/behaviour.md
    diffstir-fit experiment=mixing recordings=[rec/blend] mixing.viscosities=[1.0,0.1] mixing.fraction=0.5
"""

from __future__ import annotations

from pathlib import Path

import torch
from hydra.utils import instantiate, to_absolute_path
from omegaconf import DictConfig, OmegaConf

from diffstir.apps import CONF_DIR, Run, check_processes, command, config_workers
from diffstir.behaviour import characterise
from diffstir.errors import ConfigError, OutputError, check_at_least, check_choices
from diffstir.fitting import FitSettings
from diffstir.identification import identify
from diffstir.mixing import analyse_mixing, time_windows
from diffstir.recording import load_recording
from diffstir.rheology import LAWS


@command("diffstir-fit", "fit")
def main(cfg: DictConfig) -> None:
    check_processes(cfg)
    check_at_least("density", cfg.density, 1.0, "kg/m^3")
    torch.set_num_threads(int(cfg.threads))
    if "behaviour" in cfg:
        return behaviour(cfg)
    if "mixing" in cfg:
        return mixing(cfg)
    check_choices("model", list(cfg.model), sorted(LAWS))
    settings = fit_settings(cfg)
    recording = load_recording(to_absolute_path(str(cfg.recording)))
    config = instantiate(cfg.sim)
    coarse = instantiate(cfg.coarse) if cfg.get("coarse") else None
    rectifier = rectifier_path(str(cfg.rectifier.checkpoint)) if cfg.rectifier.checkpoint else None
    out = Run.writes(Path(to_absolute_path(str(cfg.out))), "checkpoint.json")
    result = identify(recording, list(cfg.model), config=config, fit=settings, coarse=coarse, density=cfg.density,
                      baseline=cfg.baseline, checkpoint=out / "checkpoint.json", progress=cfg.progress,
                      log_dir=out / "tensorboard", workers=config_workers(cfg), overwrite=bool(cfg.overwrite))
    if rectifier is not None:
        result.refined = refined_viscosity(result, rectifier)
    (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    paths = result.write(out)
    av = result.apparent_viscosity(result.selection["selected"])
    print(f"{result.selection['selected']}: {av['at_effective_shear_rate']:.4g} Pa·s at "
          f"{av['effective_shear_rate']:.3g} 1/s; wrote {paths['json']} and {paths['md']}")
    if cfg.diagnose:
        diagnose_if_poor(result, cfg, out)


def fit_settings(cfg: DictConfig) -> FitSettings:
    """The ``fit:`` settings, composed on their schema (``FitSettings``, registered in ``diffstir.apps``), as the
    checked dataclass: a value outside its range or choices is a ConfigError before any simulation."""
    return OmegaConf.to_object(cfg.fit)


def diagnose_if_poor(result, cfg: DictConfig, out: Path) -> None:
    """``diagnose=true``: when the selected fit's residual is larger than the noise and structured, name the
    missing physics on the coarse (or the fit's) resolution into ``out/diagnosis/`` (docs/diagnosis.md)."""
    from diffstir.diagnosis import DiagnosisSettings, diagnose, needs_diagnosis

    check = needs_diagnosis(result)
    if not check["needed"]:
        print(f"residual within the noise (RSS/(N σ²) = {check['excess']:.2f}, lag-1 autocorrelation "
              f"{check['autocorrelation']:.2f}); no diagnosis needed")
        return
    config = instantiate(cfg.coarse) if cfg.get("coarse") else instantiate(cfg.sim)
    diag = diagnose(result.recording, result, config=config, settings=DiagnosisSettings(window=cfg.fit.window),
                    progress=cfg.progress, workers=config_workers(cfg))
    paths = diag.write(out / "diagnosis")
    print(f"diagnosis: {diag.verdict}; wrote {paths['json']}\n{diag.sentence}")


def rectifier_path(checkpoint: str) -> Path:
    """The rectifier checkpoint ``rectifier.checkpoint`` names: a relative path from the working directory, then
    from the diffstir checkout; ConfigError where neither exists."""
    path = Path(to_absolute_path(checkpoint))
    if not path.exists() and not Path(checkpoint).is_absolute():
        path = Path(CONF_DIR).parent / checkpoint
    if not path.exists():
        raise ConfigError(f"rectifier.checkpoint = {checkpoint}: no such file; give a rectifier.ckpt "
                          "(docs/rectifier.md) or rectifier.checkpoint=null for no refinement")
    return path


def refined_viscosity(result, path: Path) -> dict:
    """The rectifier's refinement of ``result``'s preliminary viscosity (docs/rectifier.md)."""
    from diffstir.rectifier.apply import load_rectifier, refine

    rectifier, metadata = load_rectifier(path)
    return refine(rectifier, metadata, result.preliminary, result.density["value"], str(path))


def behaviour(cfg: DictConfig) -> None:
    """``experiment=behaviour``: classify the fluid of ``recordings`` (docs/behaviour.md)."""
    settings = OmegaConf.to_object(cfg.behaviour)  # a BehaviourSettings, checked (its schema)
    if not cfg.recordings:
        raise ConfigError("recordings = []; give recordings=[a,b,...], recording directories of one fluid")
    recordings = [load_recording(to_absolute_path(str(r))) for r in cfg.recordings]
    config = instantiate(cfg.sim)
    out = Run.writes(Path(to_absolute_path(str(cfg.out))))
    refuse_existing(out, "report.json", cfg.overwrite)
    result = characterise(recordings, config=config, settings=settings, density=cfg.density,
                          workers=config_workers(cfg), progress=bool(cfg.progress))
    (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    paths = result.write(out)
    summary = result.summary()
    b = summary["behaviour"]
    source = (f"the class of {summary['joint_fit']['selected']}, the law the points select; slope" if b.get("laws")
              else "slope")
    print(f"{b['class']} (confidence {b['confidence']:.2f}; {source} {b['slope']:.3f}, 95 % CI "
          f"{b['slope_ci95'][0]:.3f} to {b['slope_ci95'][1]:.3f}, from the {b['slope_source']}); wrote {paths['json']}")


def mixing(cfg: DictConfig) -> None:
    """``experiment=mixing``: the viscosity's time course of one recording of a blend (docs/mixing.md)."""
    if len(cfg.recordings) != 1:
        raise ConfigError(f"recordings = {list(cfg.recordings)}; experiment=mixing analyses one recording")
    settings = OmegaConf.to_object(cfg.mixing)  # a MixingSettings, checked (its schema)
    recording = load_recording(to_absolute_path(str(cfg.recordings[0])))
    time_windows(recording, settings.window)  # a time course's windows, before the output folder and any simulation
    config = instantiate(cfg.sim)
    out = Run.writes(Path(to_absolute_path(str(cfg.out))))
    refuse_existing(out, "report.json", cfg.overwrite)
    result = analyse_mixing(recording, config=config, settings=settings, density=cfg.density,
                            progress=bool(cfg.progress))
    (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    paths = result.write(out)
    a = result.approach
    ci = a.homogeneity_interval
    interval = f" (95 % CI {ci[0]:.3g}-{ci[1]:.3g} s)" if ci else ""
    print(f"blend {a.plateau:.4g} Pa·s (95 % CI {a.plateau_ci95[0]:.4g}-{a.plateau_ci95[1]:.4g}), homogeneous after "
          f"{a.homogeneity_time:.3g} s{interval}; wrote {paths['json']}")


def refuse_existing(out: Path, report: str, overwrite: bool) -> None:
    """Raise OutputError where ``out`` holds ``report`` already and ``overwrite`` is false."""
    if (out / report).exists() and not overwrite:
        raise OutputError(f"{out / report}: a report is already there; give another out= or overwrite=true")


if __name__ == "__main__":
    main()
