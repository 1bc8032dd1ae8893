"""Every app's configuration composes with every option of every config group it uses, and every object the
composed configuration describes is built: a preset that a user can select is one that works."""

from __future__ import annotations

import functools
import importlib
import inspect
import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import DictConfig, ListConfig, OmegaConf

from diffstir.apps import CONF_DIR, SCHEMAS, run_folder
from diffstir.apps.synth import lab_setup
from diffstir.behaviour import BehaviourSettings
from diffstir.diagnosis import DiagnosisSettings
from diffstir.errors import ConfigError
from diffstir.fitting import FitSettings
from diffstir.hardware import DensitySettings, DryRunSettings, GripSettings, SensorSettings, StirSettings
from diffstir.mixing import MixingSettings
from diffstir.mpm import COARSE_STAGE, FINE_STAGE
from diffstir.rectifier.pairs import PairDesign, design_from_mapping
from diffstir.rectifier.settings import DesignSettings, ModelSettings, SplitSettings, TrainSettings

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
        if node._is_none():  # a schema's optional block left null (pairs.design.physics)
            return 0
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


def settings(node) -> list:
    """The checked dataclass of every node under ``node`` composed on a schema of ``SCHEMAS`` (``__post_init__``
    runs its checks); a block with a value still to be given on the command line (``???``) is left out."""
    if isinstance(node, list):
        return [s for value in node for s in settings(value)]
    if not isinstance(node, DictConfig) or node._is_none() or node._is_missing():
        return []
    if OmegaConf.get_type(node) in SCHEMAS.values():
        return [] if OmegaConf.missing_keys(node) else [OmegaConf.to_object(node)]
    return [s for key in node for s in settings(node._get_node(key))]


def app_nodes(cfg: DictConfig) -> list:
    """The app's own top-level nodes, Hydra's left out."""
    return [cfg._get_node(key) for key in cfg if key != "hydra"]


CASES = [(app, key, option) for app in APPS for key, option in group_choices(app)]


def test_every_app_has_config_groups_to_check():
    assert {"fit", "synth", "record", "simulate", "pairs"} <= set(APPS)
    assert {key for app, key, _ in CASES if app == "synth"} >= {"rig", "lab/fluid", "lab/sim", "lab/sensor"}


#: How many nodes of each app's defaults are composed on a schema.
SCHEMA_NODES = {"diagnose": 1, "fit": 1, "import": 0, "pairs": 1, "plan": 0, "rectifier": 3, "record": 5,
                "simulate": 0, "synth": 0}


@pytest.mark.parametrize("app", APPS)
def test_each_apps_defaults_compose_and_build(app):
    cfg = composed(app)
    build(app_nodes(cfg), app)
    assert len(settings(app_nodes(cfg))) == SCHEMA_NODES[app]


@pytest.mark.parametrize("app, key, option", CASES, ids=[f"{a}:{k}={o}" for a, k, o in CASES])
def test_each_group_option_composes_and_builds(app, key, option):
    cfg = composed(app, [f"{key}={option}"])
    assert cfg.hydra.runtime.choices[key] == option
    assert build(app_nodes(cfg), app) >= 1
    settings(app_nodes(cfg))  # every block on a schema is built, its checks passed
    if app == "synth":  # the lab's fluid, programme, sensor and physics are plain settings the app builds
        setup = lab_setup(cfg)
        assert setup.trajectory.duration > 0 and setup.fluid.density > 0


def test_a_lab_group_missing_a_setting_is_refused_naming_the_group_and_the_setting():
    cfg = composed("synth", ["~lab.programme.radius"])
    with pytest.raises(ConfigError, match=r"^lab/programme: no setting 'radius'"):
        lab_setup(cfg)


def test_the_fit_block_composes_on_its_schema_to_its_defaults():
    # conf/fit.yaml's values are those of FitSettings(), which identify() uses when given none: one default
    settings = OmegaConf.to_object(composed("fit").fit)
    assert isinstance(settings, FitSettings)
    assert settings == FitSettings()


def test_the_behaviour_block_composes_on_its_schema_to_its_defaults():
    settings = OmegaConf.to_object(composed("fit", ["experiment=behaviour"]).behaviour)
    assert isinstance(settings, BehaviourSettings)
    assert settings == BehaviourSettings()
    # experiment=flow_curve is the same experiment with its cheaper analysis and every other default kept
    flow_curve = OmegaConf.to_object(composed("fit", ["experiment=flow_curve"]).behaviour)
    assert flow_curve == BehaviourSettings(analysis="flow_curve")
    assert composed("fit", ["experiment=flow_curve"]).sim == composed("fit", ["experiment=behaviour"]).sim


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


#: (app, node, schema) of every block in conf/ composed on a schema whose defaults are the block's values.
BLOCKS = [("diagnose", "diagnosis", DiagnosisSettings), ("rectifier", "model", ModelSettings),
          ("rectifier", "train", TrainSettings), ("rectifier", "split", SplitSettings),
          ("record", "sensor", SensorSettings), ("record", "grip", GripSettings), ("record", "dry_run", DryRunSettings),
          ("record", "density", DensitySettings), ("record", "stir", StirSettings)]


@pytest.mark.parametrize("app, node, schema", BLOCKS, ids=[f"{a}:{n}" for a, n, _ in BLOCKS])
def test_each_block_composes_on_its_schema_to_its_defaults(app, node, schema):
    # the values in conf/ are those of the dataclass the library uses when given none: one default
    settings = OmegaConf.to_object(composed(app)[node])
    assert isinstance(settings, schema)
    assert settings == schema()


def test_every_schema_is_composed_by_a_config():
    text = "".join(path.read_text(encoding="utf-8") for path in Path(CONF_DIR).rglob("*.yaml"))
    assert all(f"{name}@" in text for name in SCHEMAS), [name for name in SCHEMAS if f"{name}@" not in text]


@pytest.mark.parametrize("design", sorted(p.stem for p in (Path(CONF_DIR) / "pairs" / "design").glob("*.yaml")))
def test_each_pair_design_composes_on_its_schema_to_the_same_design(design):
    # the schema changes no value, so the design's digest (what its shards are written under) stays the same
    cfg = composed("pairs", [f"pairs/design={design}"])
    settings = OmegaConf.to_object(cfg.pairs.design)
    assert isinstance(settings, DesignSettings)
    built = settings.design()
    assert isinstance(built, PairDesign)
    assert built == design_from_mapping(OmegaConf.to_container(cfg.pairs.design, resolve=True))
    if design == "paper":  # the shipped pairs were made under it
        manifest = json.loads((Path(CONF_DIR).parent / "checkpoints" / "rectifier" / "manifest.json").read_text())
        assert built.digest() == manifest["design_digest"]


@pytest.mark.parametrize("schema, changes, message", [
    (DiagnosisSettings, {"candidates": ["nonsense"]}, "diagnosis.candidates: unknown nonsense; choose from sensor_lag"),
    (DiagnosisSettings, {"window": 1e-4}, "diagnosis.window = 0.0001 s; expected at least 0.001 s"),
    (ModelSettings, {"activation": "nonsense"}, "model.activation = 'nonsense'; choose from tanh, relu, silu"),
    (ModelSettings, {"inputs": ["mean_stirring_speed"]}, "model.residual = true corrects the preliminary"),
    (SplitSettings, {"val_fraction": 0.5, "test_fraction": 0.5}, "split.val_fraction + split.test_fraction = 1"),
    (TrainSettings, {"batch_size": 0}, "train.batch_size = 0; expected a whole number of at least 1"),
    (GripSettings, {"force_percent": 5}, "grip.force_percent = 5 %; expected 20 to 100 %"),
    (DryRunSettings, {"mode": "wet"}, "dry_run.mode = 'wet'; choose from mean, profile"),
    (SensorSettings, {"mode": "component", "axis": None}, "sensor.axis = null; sensor.mode = component needs"),
    (DensitySettings, {"rod_weight": 0.1, "immersed_reading": 0.2}, "density.rod_weight = 0.1 N is not more than"),
    (StirSettings, {"ramp_time": 9.0}, "stir.ramp_time = 9.0 s; expected a time in s from 0 to less than"),
    (functools.partial(DesignSettings, programmes=[{"radius": 0.012, "speed": 0.05}], densities=[1000.0]),
     {"laws": {"bingham": 1.0}}, "pairs.design.laws: unknown bingham; choose from carreau, cross"),
])
def test_a_value_outside_its_range_or_choices_is_refused_with_the_valid_ones(schema, changes, message):
    with pytest.raises(ConfigError) as refused:
        schema(**changes)
    assert str(refused.value).startswith(message)
