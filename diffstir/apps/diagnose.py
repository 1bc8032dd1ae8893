"""diffstir-diagnose: locate where a recording and its fitted simulation disagree, name the missing physics, model
it, and show the fit improve (diagnosis.json, diagnosis.md, plots).

    diffstir-diagnose recording=diffstir/data/examples/carreau_example identification=outputs/carreau \\
        out=outputs/diagnosis
"""

from __future__ import annotations

from pathlib import Path

import hydra
import torch
from hydra.utils import instantiate, to_absolute_path
from omegaconf import DictConfig

from diffstir.apps import CONF_DIR, config_workers
from diffstir.diagnose import diagnose, write_diagnosis
from diffstir.identify import identify
from diffstir.recording import load_recording


@hydra.main(config_path=CONF_DIR, config_name="diagnose", version_base="1.3")
def main(cfg: DictConfig) -> None:
    torch.set_num_threads(int(cfg.threads))
    out = Path(to_absolute_path(str(cfg.out)))
    recording = load_recording(to_absolute_path(str(cfg.recording)))
    config = instantiate(cfg.sim)
    workers = config_workers(cfg)
    if cfg.identification is None:
        identification = identify(recording, ["newtonian"], config=config, density=cfg.density, baseline=False,
                                  window=cfg.window, holdout_fraction=0.0, max_iterations=cfg.identify_iterations,
                                  progress=cfg.progress, sensor_nuisance=(), size_estimate=False,
                                  workers=workers)
    else:
        identification = to_absolute_path(str(cfg.identification))
    result = diagnose(recording, identification, config=config, window=cfg.window, candidates=list(cfg.candidates),
                      max_iterations=int(cfg.max_iterations), rebuild_time=float(cfg.rebuild_time),
                      progress=bool(cfg.progress), workers=workers)
    paths = write_diagnosis(result, out)
    print(f"{result.verdict}: {result.sentence}\nwrote {paths['json']} and {paths['md']}")


if __name__ == "__main__":
    main()
