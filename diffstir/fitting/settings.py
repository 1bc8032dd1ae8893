"""How a recording is fitted: the ``fit:`` settings of ``diffstir-fit`` (conf/fit.yaml) as one checked dataclass.

``FitSettings()`` holds the command's defaults; ``identify(recording, config=..., fit=FitSettings(window=None))``
changes one. The apps register it with Hydra's ConfigStore as the schema of the ``fit`` node, so a misspelt key or
a value of the wrong type is refused when the command line is composed, and a value outside its range or choices
when the settings are built, before any simulation: one line that names the setting and lists the valid values.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import ConfigError, check_choice, check_choices, is_number, is_whole
from .nuisance import NUISANCES
from .optimise import OPTIMIZERS
from .selection import CRITERIA
from .uncertainty import INERTIAL_FORCE_ERROR, MODEL_FORCE_ERROR, checked_model_error


@dataclass
class FitSettings:
    """The fit's settings (docs/identification.md).

    Attributes:
        window: fit the first ``window`` seconds of the recording [s] (None: all of it).
        holdout_fraction: the last fraction of the window held out of the fit [1], in [0, 1).
        max_iterations: Gauss-Newton iterations (``lm``) or Adam steps (``adam``) per law on the coarse stage, or on
            the only stage.
        fine_iterations: the most simulations per law on the fine stage after the coarse one, besides the
            parameters' forward differences at its start there (two more instead for a one-parameter law, which
            reuses the coarse Jacobian); a fit stops sooner once it has converged (``optimise.CONVERGED_STEP``).
        optimizer: ``"lm"`` (trust-region Gauss-Newton on the soft-L1 cost) or ``"adam"`` (the paper's).
        selection: ``"bic"``, ``"holdout"`` or ``"loss"`` (the paper's lowest loss) (``selection``).
        sensor_nuisance: sensor parameters profiled out of every fit, of ``"lag"`` and ``"offset"`` (needs ``lm``).
        model_error: σ_m, the relative 1-σ error of the fine stage's simulated force [1], in every interval.
        inertial_error: σ_i, the relative 1-σ error of the part of that force that does not scale with the fluid's
            stress [1], in every interval.
        slice_correction: a 2-D fit reads F'_2D h C, C the slice's correction for the recording's rig (False:
            F'_2D h, the paper's extruded slice).
    """

    window: float | None = 2.0
    holdout_fraction: float = 0.25
    max_iterations: int = 6
    fine_iterations: int = 3
    optimizer: str = "lm"
    selection: str = "bic"
    sensor_nuisance: list[str] = field(default_factory=list)
    model_error: float = MODEL_FORCE_ERROR
    inertial_error: float = INERTIAL_FORCE_ERROR
    slice_correction: bool = True

    def __post_init__(self) -> None:
        self.sensor_nuisance = list(self.sensor_nuisance)
        if self.window is not None and not (is_number(self.window) and self.window > 0.0):
            raise ConfigError(f"fit.window = {self.window!r} s; expected a positive duration in s, or null (all of "
                              "the recording)")
        if not (is_number(self.holdout_fraction) and 0.0 <= self.holdout_fraction < 1.0):
            raise ConfigError(f"fit.holdout_fraction = {self.holdout_fraction!r}; expected a fraction of the window "
                              "in [0, 1)")
        for name, low in (("max_iterations", 1), ("fine_iterations", 0)):
            value = getattr(self, name)
            if not is_whole(value, low):
                raise ConfigError(f"fit.{name} = {value!r}; expected a whole number of at least {low}")
        check_choice("fit.optimizer", self.optimizer, OPTIMIZERS)
        check_choice("fit.selection", self.selection, CRITERIA)
        check_choices("fit.sensor_nuisance", self.sensor_nuisance, NUISANCES)
        checked_model_error(self.model_error, "fit.model_error")
        checked_model_error(self.inertial_error, "fit.inertial_error")
        if not isinstance(self.slice_correction, bool):
            raise ConfigError(f"fit.slice_correction = {self.slice_correction!r}; expected true or false")
        if self.sensor_nuisance and self.optimizer != "lm":
            raise ConfigError(f"fit.sensor_nuisance = {self.sensor_nuisance} needs fit.optimizer = lm (got "
                              f"{self.optimizer!r})")
        if self.selection == "holdout" and not self.holdout_fraction:
            raise ConfigError("fit.selection = 'holdout' needs held-out samples; set fit.holdout_fraction > 0 (a "
                              "fraction of the window, 1)")
