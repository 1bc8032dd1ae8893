"""diffstir-diagnose: locate where a recording and its fitted simulation disagree, name the missing physics, model
it, and show the fit improve (diagnosis.json, diagnosis.md, plots).

    diffstir-diagnose recording=diffstir/data/examples/carreau_example identification=outputs/carreau \\
        out=outputs/diagnosis
    diffstir-diagnose recording=REC identification=FIT_DIR diagnosis.candidates=[sensor_lag,viscoelasticity] \\
        diagnosis.window=3
"""

from __future__ import annotations

from pathlib import Path

import torch
from hydra.utils import instantiate, to_absolute_path
from omegaconf import DictConfig, OmegaConf

from diffstir.apps import Run, check_processes, command, config_workers
from diffstir.diagnosis import DiagnosisSettings, diagnose
from diffstir.errors import ConfigError, OutputError, check_at_least
from diffstir.fitting import FitSettings
from diffstir.identification import identify
from diffstir.recording import load_recording


@command("diffstir-diagnose", "diagnose")
def main(cfg: DictConfig) -> None:
    check_processes(cfg)
    settings = diagnosis_settings(cfg)
    check_at_least("density", cfg.density, 1.0, "kg/m^3")
    torch.set_num_threads(int(cfg.threads))
    recording = load_recording(to_absolute_path(str(cfg.recording)))
    identification = None if cfg.identification is None else Path(to_absolute_path(str(cfg.identification)))
    if identification is not None and not identification.exists():
        raise ConfigError(f"identification = {cfg.identification}: no such file or directory; give a diffstir-fit "
                          "report.json or its directory, or identification=null to fit the Newtonian law here")
    config = instantiate(cfg.sim)
    workers = config_workers(cfg)
    out = Run.writes(Path(to_absolute_path(str(cfg.out))))
    if (out / "diagnosis.json").exists() and not cfg.overwrite:
        raise OutputError(f"{out / 'diagnosis.json'}: a diagnosis is already there; give another out= or "
                          "overwrite=true")
    if identification is None:
        identification = identify(recording, ["newtonian"], config=config, density=cfg.density, baseline=False,
                                  progress=cfg.progress, size_estimate=False, workers=workers,
                                  fit=FitSettings(window=settings.window, holdout_fraction=0.0,
                                                  max_iterations=settings.identify_iterations))
    result = diagnose(recording, identification, config=config, settings=settings, progress=bool(cfg.progress),
                      workers=workers)
    paths = result.write(out)
    print(f"{result.verdict}: {result.sentence}\nwrote {paths['json']} and {paths['md']}")


def diagnosis_settings(cfg: DictConfig) -> DiagnosisSettings:
    """The ``diagnosis:`` settings, composed on their schema (``DiagnosisSettings``, registered in ``diffstir.apps``),
    as the checked dataclass: a value outside its range or choices is a ConfigError before any simulation."""
    return OmegaConf.to_object(cfg.diagnosis)


if __name__ == "__main__":
    main()
