"""diffstir-fit: identify the fluid in a recording and write report.json, report.md, plots and TensorBoard logs.

    diffstir-fit recording=examples/carreau_example out=outputs/carreau
    python -m diffstir.fit recording=examples/carreau_example model=[newtonian,carreau]
"""

from __future__ import annotations

from pathlib import Path

import hydra
import torch
from hydra.utils import instantiate, to_absolute_path
from omegaconf import DictConfig, OmegaConf

from diffstir.apps import CONF_DIR
from diffstir.identify import identify
from diffstir.identify.report import write_report
from diffstir.recording import load_recording


@hydra.main(config_path=CONF_DIR, config_name="fit", version_base="1.3")
def main(cfg: DictConfig) -> None:
    torch.set_num_threads(int(cfg.threads))
    out = Path(to_absolute_path(str(cfg.out)))
    out.mkdir(parents=True, exist_ok=True)
    recording = load_recording(to_absolute_path(str(cfg.recording)))
    result = identify(
        recording, list(cfg.model), config=instantiate(cfg.sim), density=cfg.density, baseline=cfg.baseline,
        window=cfg.fit.window, holdout_fraction=cfg.fit.holdout_fraction, max_iterations=cfg.fit.max_iterations,
        optimizer=cfg.fit.optimizer, selection=cfg.fit.selection, checkpoint=out / "checkpoint.json",
        progress=cfg.progress, log_dir=out / "tensorboard",
        coarse=instantiate(cfg.coarse) if cfg.get("coarse") else None, fine_iterations=cfg.fit.fine_iterations,
    )
    (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    paths = write_report(result, out)
    av = result.apparent_viscosity(result.selection["selected"])
    print(f"{result.selection['selected']}: {av['at_effective_shear_rate']:.4g} Pa·s at "
          f"{av['effective_shear_rate']:.3g} 1/s; wrote {paths['json']} and {paths['md']}")


if __name__ == "__main__":
    main()
