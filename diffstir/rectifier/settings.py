"""The rectifier's settings as checked dataclasses: the ``model:``, ``train:`` and ``split:`` blocks of
``diffstir-train-rectifier`` (conf/rectifier.yaml) and the ``pairs/design`` group of ``diffstir-pairs``
(conf/pairs/design/).

The apps register them with Hydra's ConfigStore as the schemas of those nodes, so a misspelt key or a value of the
wrong type is refused when the command line is composed, and a value outside its range or choices when the settings
are built, before any training or simulation: one line that names the setting and lists the valid values.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from ..errors import ConfigError, check_choice, check_choices, is_number, is_whole
from .model import ACTIVATIONS, INPUT_UNITS
from .pairs import PairDesign, design_from_mapping

#: Lightning accelerators the trainer runs on (``device``).
ACCELERATORS = ("cpu", "gpu", "auto")


@dataclass
class ModelSettings:
    """The network (``Rectifier``, docs/rectifier.md).

    Attributes:
        inputs: a training pair's fields the network reads, of ``model.INPUT_UNITS`` (SI: m/s, Pa s, kg/m^3).
        hidden: the hidden layers' widths (empty: a linear map of the standardised inputs).
        activation: the hidden layers' activation, of ``model.ACTIVATIONS``.
        residual: learn ln(η_ref / η_p), the correction to the preliminary viscosity (needs it among the inputs),
            not ln η_ref as the paper.
    """

    inputs: list[str] = field(default_factory=lambda: ["mean_stirring_speed", "preliminary_viscosity"])
    hidden: list[int] = field(default_factory=lambda: [8])
    activation: str = "tanh"
    residual: bool = True

    def __post_init__(self) -> None:
        self.inputs, self.hidden = list(self.inputs), list(self.hidden)
        if not self.inputs or len(set(self.inputs)) != len(self.inputs):
            raise ConfigError(f"model.inputs = {self.inputs}; expected distinct names from "
                              f"{', '.join(INPUT_UNITS)}")
        check_choices("model.inputs", self.inputs, list(INPUT_UNITS))
        if not all(is_whole(width, 1) for width in self.hidden):
            raise ConfigError(f"model.hidden = {self.hidden}; expected layer widths, whole numbers of at least 1")
        check_choice("model.activation", self.activation, list(ACTIVATIONS))
        if self.residual and "preliminary_viscosity" not in self.inputs:
            raise ConfigError(f"model.residual = true corrects the preliminary viscosity; add preliminary_viscosity "
                              f"to model.inputs (got {self.inputs})")


@dataclass
class TrainSettings:
    """Adam on the training fluids (``training.train``).

    Attributes:
        learning_rate: Adam's step size [1].
        epochs: passes over the training pairs, at most.
        batch_size: pairs per step.
        early_stopping: stop when the validation loss has not improved for ``patience`` epochs.
        patience: epochs without improvement before early stopping.
        seed: the weights' and the batches' random numbers.
    """

    learning_rate: float = 0.01
    epochs: int = 50
    batch_size: int = 64
    early_stopping: bool = False
    patience: int = 10
    seed: int = 0

    def __post_init__(self) -> None:
        if not (is_number(self.learning_rate) and self.learning_rate > 0):
            raise ConfigError(f"train.learning_rate = {self.learning_rate!r}; expected a positive step size")
        for name, low in (("epochs", 1), ("batch_size", 1), ("patience", 1), ("seed", 0)):
            if not is_whole(getattr(self, name), low):
                raise ConfigError(f"train.{name} = {getattr(self, name)!r}; expected a whole number of at least "
                                  f"{low}")


@dataclass
class SplitSettings:
    """The split of the pairs by fluid (``training.PairData``): test fluids are never seen in training.

    Attributes:
        val_fraction: the fluids that validate [1], in (0, 1).
        test_fraction: the fluids held out for the test [1], in (0, 1), with ``val_fraction`` less than 1.
        seed: the random numbers that draw them.
    """

    val_fraction: float = 0.1
    test_fraction: float = 0.2
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("val_fraction", "test_fraction"):
            value = getattr(self, name)
            if not (is_number(value) and 0.0 < value < 1.0):
                raise ConfigError(f"split.{name} = {value!r}; expected a fraction of the fluids in (0, 1)")
        if self.val_fraction + self.test_fraction >= 1.0:
            raise ConfigError(f"split.val_fraction + split.test_fraction = {self.val_fraction + self.test_fraction:g};"
                              " expected less than 1, leaving fluids to train on")
        if not is_whole(self.seed, 0):
            raise ConfigError(f"split.seed = {self.seed!r}; expected a whole number of at least 0")


@dataclass
class DesignSettings:
    """What the pair set spans (``pairs.PairDesign``, whose checks it runs): a ``pairs/design`` preset.

    Attributes:
        programmes: circles the rod stirs on, each {radius [m], speed [m/s]}.
        densities: fluid densities [kg/m³].
        duration: recording length [s].
        ramp_time: speed ramp at the start [s].
        fluids_per_shard: truth simulations per (programme, density) group.
        sensors_per_fluid: sensor models per truth simulation.
        viscosity: [low, high], the reference viscosity's range [Pa·s].
        laws: probability of each law family [1].
        sensor: the drawn sensor models' fields (``lab.SensorModel``): [low, high], {mean, std} or a fixed value.
        physics: hidden physics of every truth simulation (``lab.HiddenPhysicsSpec``; None: none).
        window: the fit window of ``identify`` [s].
        holdout_fraction: its held-out fraction [1].
        seed: root of every random number.
    """

    programmes: list[dict[str, float]]
    densities: list[float]
    duration: float = 2.0
    ramp_time: float = 0.2
    fluids_per_shard: int = 10
    sensors_per_fluid: int = 10
    viscosity: list[float] = field(default_factory=lambda: [1e-3, 10.0])
    laws: dict[str, float] = field(default_factory=lambda: {"newtonian": 1.0})
    sensor: dict[str, Any] = field(default_factory=dict)
    physics: dict[str, Any] | None = None
    window: float = 2.0
    holdout_fraction: float = 0.25
    seed: int = 0

    def __post_init__(self) -> None:
        if len(self.viscosity) != 2:
            raise ConfigError(f"pairs.design.viscosity = {list(self.viscosity)}; expected [low, high] in Pa s")
        self.design()

    def design(self) -> PairDesign:
        """The checked ``PairDesign``."""
        return design_from_mapping(asdict(self))
