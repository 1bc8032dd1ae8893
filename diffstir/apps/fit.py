"""diffstir-fit: identify the fluid in a recording and write report.json, report.md, plots and TensorBoard logs.

    diffstir-fit recording=diffstir/data/examples/carreau_example out=outputs/carreau
    python -m diffstir.fit recording=diffstir/data/examples/carreau_example model=[newtonian,carreau]
    diffstir-fit experiment=behaviour recordings=[rec/slow,rec/fast] out=outputs/behaviour    # docs/behaviour.md
    diffstir-fit experiment=mixing recordings=[rec/blend] mixing.viscosities=[1.0,0.1] mixing.fraction=0.5
"""

from __future__ import annotations

from pathlib import Path

import hydra
import torch
from hydra.utils import instantiate, to_absolute_path
from omegaconf import DictConfig, OmegaConf

from diffstir.apps import CONF_DIR, config_workers
from diffstir.behaviour import characterise, write_behaviour_report
from diffstir.identify import identify
from diffstir.identify.report import write_report
from diffstir.mixing import analyse_mixing, write_mixing_report
from diffstir.recording import load_recording


@hydra.main(config_path=CONF_DIR, config_name="fit", version_base="1.3")
def main(cfg: DictConfig) -> None:
    torch.set_num_threads(int(cfg.threads))
    if "behaviour" in cfg:
        return behaviour(cfg)
    if "mixing" in cfg:
        return mixing(cfg)
    out = Path(to_absolute_path(str(cfg.out)))
    out.mkdir(parents=True, exist_ok=True)
    recording = load_recording(to_absolute_path(str(cfg.recording)))
    result = identify(
        recording, list(cfg.model), config=instantiate(cfg.sim), density=cfg.density, baseline=cfg.baseline,
        window=cfg.fit.window, holdout_fraction=cfg.fit.holdout_fraction, max_iterations=cfg.fit.max_iterations,
        optimizer=cfg.fit.optimizer, selection=cfg.fit.selection, checkpoint=out / "checkpoint.json",
        progress=cfg.progress, log_dir=out / "tensorboard",
        coarse=instantiate(cfg.coarse) if cfg.get("coarse") else None, fine_iterations=cfg.fit.fine_iterations,
        sensor_nuisance=tuple(cfg.fit.sensor_nuisance), model_error=cfg.fit.model_error,
        workers=config_workers(cfg),
    )
    if cfg.rectifier.checkpoint:
        result.refined = refined_viscosity(result, str(cfg.rectifier.checkpoint))
    (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    paths = write_report(result, out)
    av = result.apparent_viscosity(result.selection["selected"])
    print(f"{result.selection['selected']}: {av['at_effective_shear_rate']:.4g} Pa·s at "
          f"{av['effective_shear_rate']:.3g} 1/s; wrote {paths['json']} and {paths['md']}")
    if cfg.diagnose:
        diagnose_if_poor(result, cfg, out)


def diagnose_if_poor(result, cfg: DictConfig, out: Path) -> None:
    """``diagnose=true``: when the selected fit's residual is larger than the noise and structured, name the
    missing physics on the coarse (or the fit's) resolution into ``out/diagnosis/`` (docs/diagnosis.md)."""
    from diffstir.diagnose import diagnose, needs_diagnosis, write_diagnosis

    check = needs_diagnosis(result)
    if not check["needed"]:
        print(f"residual within the noise (RSS/(N σ²) = {check['excess']:.2f}, lag-1 autocorrelation "
              f"{check['autocorrelation']:.2f}); no diagnosis needed")
        return
    config = instantiate(cfg.coarse) if cfg.get("coarse") else instantiate(cfg.sim)
    diag = diagnose(result.recording, result, config=config, window=cfg.fit.window, progress=cfg.progress,
                    workers=config_workers(cfg))
    paths = write_diagnosis(diag, out / "diagnosis")
    print(f"diagnosis: {diag.verdict}; wrote {paths['json']}\n{diag.sentence}")


def refined_viscosity(result, checkpoint: str) -> dict:
    """The rectifier's refinement of ``result``'s preliminary viscosity (docs/rectifier.md)."""
    from diffstir.rectifier.apply import load_rectifier, refine

    path = Path(to_absolute_path(checkpoint))
    if not path.exists() and not Path(checkpoint).is_absolute():
        path = Path(CONF_DIR).parent / checkpoint
    rectifier, metadata = load_rectifier(path)
    return refine(rectifier, metadata, result.preliminary, result.density["value"], str(path))


def behaviour(cfg: DictConfig) -> None:
    """``experiment=behaviour``: classify the fluid of ``recordings`` (docs/behaviour.md)."""
    out = Path(to_absolute_path(str(cfg.out)))
    out.mkdir(parents=True, exist_ok=True)
    b = cfg.behaviour
    result = characterise([load_recording(to_absolute_path(str(r))) for r in cfg.recordings],
                          config=instantiate(cfg.sim), density=cfg.density, iterations=b.iterations,
                          joint_models=list(b.joint_models), joint_iterations=b.joint_iterations,
                          speed_tolerance=b.speed_tolerance, min_window=b.min_window, pause_speed=b.pause_speed,
                          replicates=b.replicates, seed=b.seed, model_error=b.model_error,
                          slope_test=b.slope_test, workers=config_workers(cfg))
    (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    paths = write_behaviour_report(result, out)
    b = result.summary()["behaviour"]
    print(f"{b['class']} (confidence {b['confidence']:.2f}; slope {b['slope']:.3f}, 95 % CI {b['slope_ci95'][0]:.3f} "
          f"to {b['slope_ci95'][1]:.3f}, from the {b['slope_source']}); wrote {paths['json']}")


def mixing(cfg: DictConfig) -> None:
    """``experiment=mixing``: the viscosity's time course of one recording of a blend (docs/mixing.md)."""
    if len(cfg.recordings) != 1:
        raise ValueError(f"recordings = {list(cfg.recordings)}; experiment=mixing analyses one recording")
    out = Path(to_absolute_path(str(cfg.out)))
    out.mkdir(parents=True, exist_ok=True)
    m = cfg.mixing
    result = analyse_mixing(load_recording(to_absolute_path(str(cfg.recordings[0]))), config=instantiate(cfg.sim),
                            viscosities=tuple(m.viscosities), fraction=m.fraction, window=m.window,
                            density=cfg.density, iterations=m.iterations, model_error=m.model_error)
    (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    paths = write_mixing_report(result, out)
    a = result.approach
    ci = a.homogeneity_interval
    interval = f" (95 % CI {ci[0]:.3g}-{ci[1]:.3g} s)" if ci else ""
    print(f"blend {a.plateau:.4g} Pa·s (95 % CI {a.plateau_ci95[0]:.4g}-{a.plateau_ci95[1]:.4g}), homogeneous after "
          f"{a.homogeneity_time:.3g} s{interval}; wrote {paths['json']}")


if __name__ == "__main__":
    main()
