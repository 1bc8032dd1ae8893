"""Command-line applications; the only modules that import Hydra."""

from pathlib import Path

from omegaconf import DictConfig

from diffstir.parallel import default_workers

#: The project's Hydra configs (the repository's top-level conf/), as an absolute path so that the apps find them
#: whether started as console scripts, with python -m, or from another working directory.
CONF_DIR = str(Path(__file__).resolve().parents[2] / "conf")


def config_workers(cfg: DictConfig) -> int:
    """The config's ``workers``: processes for fits side by side (null: one per CPU, one on a GPU)."""
    return default_workers(cfg.sim.device) if cfg.workers is None else int(cfg.workers)
