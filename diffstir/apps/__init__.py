"""Command-line applications; the only modules that import Hydra."""

from pathlib import Path

#: The project's Hydra configs (the repository's top-level conf/), as an absolute path so that the apps find them
#: whether started as console scripts, with python -m, or from another working directory.
CONF_DIR = str(Path(__file__).resolve().parents[2] / "conf")

