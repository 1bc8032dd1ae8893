"""How a fluid's behaviour is classified: the ``behaviour:`` settings of ``diffstir-fit experiment=behaviour``
(conf/experiment/behaviour.yaml) as one checked dataclass.

``BehaviourSettings()`` holds the experiment's defaults; ``characterise(recordings, config=...,
settings=BehaviourSettings(replicates=50))`` changes one. The apps register it with Hydra's ConfigStore as the
schema of the ``behaviour`` node; a value outside its range or choices is refused when the settings are built,
before any simulation, in one line that names the setting and lists the valid values.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import ConfigError, check_choice, check_choices, is_number, is_whole
from ..fitting import INERTIAL_FORCE_ERROR, MODEL_FORCE_ERROR, PAUSE_SPEED, THICKEST_RUNG, checked_model_error
from ..rheology import LAWS

#: Laws fitted to all speeds at once by default.
JOINT_MODELS = ("newtonian", "power_law", "carreau", "cross", "herschel_bulkley")
#: What the slope test reads (``classify``, 1 and 4): the per-speed points, the joint power law's index, or the two
#: combined (the points alone where the power law was not fitted jointly).
SLOPE_TESTS = ("combined", "points", "joint_index")
#: How the windows and laws are read: each window and each law fitted through the simulator, or the windows read by
#: whole-programme simulations and the laws fitted to their flow curve (``flow_laws``).
ANALYSES = ("simulated", "flow_curve")


@dataclass
class BehaviourSettings:
    """The behaviour experiment's settings (docs/behaviour.md).

    Attributes:
        analysis: ``"simulated"`` (each window's Newtonian fit and each joint law through the simulator) or
            ``"flow_curve"`` (each recording's windows read by simulations of its whole programme, the laws fitted
            to their points and the class that of the law they select, ``flow_laws``; ``iterations`` and
            ``joint_iterations`` unused, ``slope_test`` only without ``joint_models``).
        iterations: Gauss-Newton iterations of each speed window's Newtonian fit.
        speed_tolerance: the relative speed change that still counts as one speed [1]
            (``fitting.speed_windows``).
        min_window: the shortest constant-speed window [s].
        pause_speed: slower than this the rod is held still, not stirring [m/s].
        joint_models: laws fitted to all speeds at once (empty: no joint fit), of ``diffstir.rheology.LAWS``.
        joint_iterations: Gauss-Newton iterations of each joint fit.
        replicates: bootstrap replicates of the class's confidence.
        seed: the bootstrap's random numbers.
        model_error: σ_m, the relative 1-σ error of the fitting simulation's force [1], in every window's interval
            and the joint laws' covariances (``fitting.COARSE_FORCE_ERROR`` for ``conf/sim/coarse2d.yaml``).
        inertial_error: σ_i, the relative 1-σ error of its inertial part [1], in the same intervals.
        thickest_rung: with ``analysis = "flow_curve"``, the most viscous Newtonian rung [Pa·s]; rungs above the
            simulator's ``viscosity_cap`` are simulated with the implicit shear stress (``fitting.programme``).
        slope_test: ``"combined"`` (the points' slope and the joint power law's n − 1, their error scaled by their
            disagreement), ``"points"`` or ``"joint_index"`` (needs the power law in ``joint_models``).
    """

    analysis: str = "simulated"
    iterations: int = 3
    speed_tolerance: float = 0.05
    min_window: float = 0.3
    pause_speed: float = PAUSE_SPEED
    joint_models: list[str] = field(default_factory=lambda: list(JOINT_MODELS))
    joint_iterations: int = 5
    replicates: int = 200
    seed: int = 0
    model_error: float = MODEL_FORCE_ERROR
    inertial_error: float = INERTIAL_FORCE_ERROR
    thickest_rung: float = THICKEST_RUNG
    slope_test: str = "combined"

    def __post_init__(self) -> None:
        self.joint_models = list(self.joint_models)
        for name, low in (("iterations", 1), ("joint_iterations", 1), ("replicates", 1), ("seed", 0)):
            value = getattr(self, name)
            if not is_whole(value, low):
                raise ConfigError(f"behaviour.{name} = {value!r}; expected a whole number of at least {low}")
        for name, unit in (("speed_tolerance", "1"), ("min_window", "s"), ("pause_speed", "m/s"),
                           ("thickest_rung", "Pa s")):
            value = getattr(self, name)
            if not (is_number(value) and value > 0):
                raise ConfigError(f"behaviour.{name} = {value!r} {unit}; expected a positive number in {unit}")
        check_choices("behaviour.joint_models", self.joint_models, sorted(LAWS))
        check_choice("behaviour.slope_test", self.slope_test, SLOPE_TESTS)
        check_choice("behaviour.analysis", self.analysis, ANALYSES)
        if self.slope_test == "joint_index" and "power_law" not in self.joint_models:
            raise ConfigError("behaviour.slope_test = 'joint_index' reads the joint power law's index; add power_law "
                              f"to behaviour.joint_models (got {self.joint_models})")
        if self.slope_test == "joint_index" and self.analysis == "flow_curve":
            raise ConfigError("behaviour.slope_test = 'joint_index' reads the index of a law fitted through the "
                              "simulator, which behaviour.analysis = flow_curve does not fit (its class is the law "
                              "the points select); use slope_test=points or combined")
        checked_model_error(self.model_error, "behaviour.model_error")
        checked_model_error(self.inertial_error, "behaviour.inertial_error")
