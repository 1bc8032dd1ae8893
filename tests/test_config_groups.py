"""Every app's configuration composes with every option of every config group it uses, and every object the
composed configuration describes is built: a preset that a user can select is one that works."""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import DictConfig, ListConfig, OmegaConf

from diffstir.apps import CONF_DIR, run_folder
from diffstir.apps.synth import lab_setup
from diffstir.behaviour import BehaviourSettings
from diffstir.fitting import FitSettings
from diffstir.mixing import MixingSettings
from diffstir.mpm import COARSE_STAGE, FINE_STAGE

APPS = sorted(path.stem for path in Path(CONF_DIR).glob("*.yaml"))
#: Targets that open a device when built (a serial port, a robot's socket): their settings are bound to the
#: constructor's signature instead.
DEVICE_MODULES = ("diffstir.hardware",)


def composed(app: str, overrides: list[str] = ()) -> DictConfig:
    """``app``'s configuration with ``overrides``, Hydra's own node included."""
    if not OmegaConf.has_resolver("run_folder"):
        OmegaConf.register_new_resolver("run_folder", run_folder)
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return compose(app, overrides=list(overrides), return_hydra_config=True)


def group_choices(app: str) -> list[tuple[str, str]]:
    """(group key as an override names it, option) for every option of every non-Hydra group ``app`` uses."""
    choices = composed(app).hydra.runtime.choices
    pairs = []
    for key in choices:
        if key.startswith("hydra"):
            continue
        folder = Path(CONF_DIR) / key.split("@")[0]
        pairs += [(key, path.stem) for path in sorted(folder.glob("*.yaml"))]
    return pairs


def build(node, where: str) -> int:
    """Build every ``_target_`` node under ``node`` (a device's settings bound to its signature); how many."""
    if isinstance(node, list):
        return sum(build(value, where) for value in node)
    if isinstance(node, DictConfig):
        if "_target_" in node:
            target = node._target_
            if target is None:  # an option that is no object (hardware/gripper=none)
                return 0
            if target.startswith(DEVICE_MODULES):
                module, name = target.rsplit(".", 1)
                cls = getattr(importlib.import_module(module), name)
                settings = {k: v for k, v in OmegaConf.to_container(node, resolve=True).items()
                            if not (k.startswith("_") and k.endswith("_"))}  # Hydra's own keys
                try:
                    inspect.signature(cls).bind(**settings)
                except TypeError as error:
                    raise AssertionError(f"{where}: {target}: {error}") from error
                return 1 + sum(build(value, f"{where}.{key}") for key, value in node.items_ex(resolve=False)
                               if key != "_target_")
            try:
                instantiate(node)
            except Exception as error:
                raise AssertionError(f"{where}: {target}: {error}") from error
            return 1
        return sum(build(value, f"{where}.{key}") for key, value in node.items_ex(resolve=False))
    if isinstance(node, ListConfig):
        return sum(build(node._get_node(i), f"{where}[{i}]") for i in range(len(node)))
    return 0


def app_nodes(cfg: DictConfig) -> list:
    """The app's own top-level nodes, Hydra's left out."""
    return [cfg._get_node(key) for key in cfg if key != "hydra"]


CASES = [(app, key, option) for app in APPS for key, option in group_choices(app)]


def test_every_app_has_config_groups_to_check():
    assert {"fit", "synth", "record", "simulate", "pairs"} <= set(APPS)
    assert {key for app, key, _ in CASES if app == "synth"} >= {"rig", "lab/fluid", "lab/sim", "lab/sensor"}


@pytest.mark.parametrize("app", APPS)
def test_each_apps_defaults_compose_and_build(app):
    build(app_nodes(composed(app)), app)


@pytest.mark.parametrize("app, key, option", CASES, ids=[f"{a}:{k}={o}" for a, k, o in CASES])
def test_each_group_option_composes_and_builds(app, key, option):
    cfg = composed(app, [f"{key}={option}"])
    assert cfg.hydra.runtime.choices[key] == option
    assert build(app_nodes(cfg), app) >= 1
    if app == "synth":  # the lab's fluid, programme, sensor and physics are plain settings the app builds
        setup = lab_setup(cfg)
        assert setup.trajectory.duration > 0 and setup.fluid.density > 0


def test_the_fit_block_composes_on_its_schema_to_its_defaults():
    # conf/fit.yaml's values are those of FitSettings(), which identify() uses when given none: one default
    settings = OmegaConf.to_object(composed("fit").fit)
    assert isinstance(settings, FitSettings)
    assert settings == FitSettings()


def test_the_behaviour_block_composes_on_its_schema_to_its_defaults():
    settings = OmegaConf.to_object(composed("fit", ["experiment=behaviour"]).behaviour)
    assert isinstance(settings, BehaviourSettings)
    assert settings == BehaviourSettings()


def test_the_fit_stages_in_python_are_the_fit_presets():
    # the README's and the API's FINE_STAGE and COARSE_STAGE are conf/sim/slice2d.yaml and coarse2d.yaml
    cfg = composed("fit")
    assert instantiate(cfg.sim) == FINE_STAGE
    assert instantiate(cfg.coarse) == COARSE_STAGE


def test_the_mixing_block_composes_on_its_schema_to_its_defaults():
    cfg = composed("fit", ["experiment=mixing", "mixing.viscosities=[1.0,0.1]", "mixing.fraction=0.5"])
    settings = OmegaConf.to_object(cfg.mixing)
    assert isinstance(settings, MixingSettings)
    assert settings == MixingSettings(viscosities=[1.0, 0.1], fraction=0.5)
