"""diffstir-diagnose: locate where a recording and its fitted simulation disagree, name the missing physics, model
it, and show the fit improve (diagnosis.json, diagnosis.md, plots).

    diffstir-diagnose recording=diffstir/data/examples/carreau_example identification=outputs/carreau \\
        out=outputs/diagnosis
"""

from __future__ import annotations

from pathlib import Path

import torch
from hydra.utils import instantiate, to_absolute_path
from omegaconf import DictConfig

from diffstir.apps import Run, check_processes, command, config_workers
from diffstir.diagnosis import CANDIDATES, diagnose, write_diagnosis
from diffstir.errors import ConfigError, OutputError, check_at_least, check_choices
from diffstir.fitting import FitSettings
from diffstir.identification import identify
from diffstir.recording import load_recording


@command("diffstir-diagnose", "diagnose")
def main(cfg: DictConfig) -> None:
    check_processes(cfg)
    torch.set_num_threads(int(cfg.threads))
    check_choices("candidates", list(cfg.candidates), CANDIDATES)
    check_at_least("max_iterations", cfg.max_iterations, 1)
    check_at_least("identify_iterations", cfg.identify_iterations, 1)
    check_at_least("density", cfg.density, 1.0, "kg/m^3")
    check_at_least("window", cfg.window, 1e-3, "s")
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
                                  fit=FitSettings(window=cfg.window, holdout_fraction=0.0,
                                                  max_iterations=cfg.identify_iterations))
    result = diagnose(recording, identification, config=config, window=cfg.window, candidates=list(cfg.candidates),
                      max_iterations=int(cfg.max_iterations), rebuild_time=float(cfg.rebuild_time),
                      progress=bool(cfg.progress), workers=workers)
    paths = write_diagnosis(result, out)
    print(f"{result.verdict}: {result.sentence}\nwrote {paths['json']} and {paths['md']}")


if __name__ == "__main__":
    main()
