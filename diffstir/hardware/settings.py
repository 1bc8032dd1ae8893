"""A recording session's settings as checked dataclasses: the ``sensor:``, ``grip:``, ``dry_run:``, ``density:``
and ``stir:`` blocks of ``diffstir-record`` (conf/record.yaml). SI units: m, s, N, Hz; the grip in % of the
gripper's maximum force.

The apps register them with Hydra's ConfigStore as the schemas of those nodes, so a misspelt key or a value of the
wrong type is refused when the command line is composed, and a value outside its range or choices when the settings
are built, before any device is opened: one line that names the setting and lists the valid values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from diffstir.errors import ConfigError, check_choice, is_number
from diffstir.recording.format import SENSOR_MODES
from diffstir.recording.validate import AXIS_TOLERANCE, MAX_TIME_CONSTANT

#: What a dry run records: the rod held still in air (mean) or the stirring programme run in air (profile).
DRY_RUN_MODES = ("mean", "profile")
#: The gripper's force [% of its maximum] that it accepts (the AG-95's range).
GRIP_FORCE_PERCENT = (20.0, 100.0)


@dataclass
class SensorSettings:
    """What the recording's force column means (``recording.SensorSpec``, docs/recording-format.md).

    Attributes:
        mode: one of ``recording.SENSOR_MODES``.
        axis: the horizontal unit vector [1] (cup frame) a force on the rod presses the sensor along (component
            mode; None otherwise).
        one_sided: the reading is max(0, value).
        resolution: the reading's step [N] (None: not stated).
        sample_rate: the nominal sample rate [Hz] (None: not stated).
        time_constant: the sensor's first-order response time [s] from a step test (None: not stated).
        noise: the standard deviation (1 σ) of one reading [N] as stated for the sensor (None: not stated).
    """

    mode: str = "component"
    axis: list[float] | None = field(default_factory=lambda: [1.0, 0.0])
    one_sided: bool = False
    resolution: float | None = 0.005
    sample_rate: float | None = 200.0
    time_constant: float | None = None
    noise: float | None = None

    def __post_init__(self) -> None:
        check_choice("sensor.mode", self.mode, SENSOR_MODES)
        if self.axis is not None:
            self.axis = [float(a) for a in self.axis]
            if len(self.axis) != 2 or not abs(math.hypot(*self.axis) - 1.0) <= AXIS_TOLERANCE:
                raise ConfigError(f"sensor.axis = {self.axis}; expected a horizontal unit vector [ax, ay] (length 1 "
                                  f"within {AXIS_TOLERANCE}, dimensionless)")
        if self.mode == "component" and self.axis is None:
            raise ConfigError("sensor.axis = null; sensor.mode = component needs a horizontal unit vector [ax, ay]")
        for name, unit in (("resolution", "N"), ("sample_rate", "Hz"), ("noise", "N")):
            value = getattr(self, name)
            if value is not None and not (is_number(value) and value > 0):
                raise ConfigError(f"sensor.{name} = {value!r} {unit}; expected a positive number in {unit}, or null")
        tau = self.time_constant
        if tau is not None and not (is_number(tau) and 0 <= tau <= MAX_TIME_CONSTANT):
            raise ConfigError(f"sensor.time_constant = {tau!r} s; expected a response time in s from 0 to "
                              f"{MAX_TIME_CONSTANT:g} s, or null")


@dataclass
class GripSettings:
    """How the gripper holds the rod.

    Attributes:
        force_percent: the grip's force [%] of the gripper's maximum, in ``GRIP_FORCE_PERCENT``.
        timeout: the longest wait [s] for initialising and for closing on the rod.
    """

    force_percent: float = 50.0
    timeout: float = 10.0

    def __post_init__(self) -> None:
        low, high = GRIP_FORCE_PERCENT
        if not (is_number(self.force_percent) and low <= self.force_percent <= high):
            raise ConfigError(f"grip.force_percent = {self.force_percent!r} %; expected {low:g} to {high:g} % of the "
                              "gripper's maximum force")
        _positive("grip.timeout", self.timeout, "s")


@dataclass
class DryRunSettings:
    """The dry run, whose reading is the baseline subtracted from the stir's.

    Attributes:
        mode: one of ``DRY_RUN_MODES``.
        duration: how long the rod is held still [s] (mean mode; profile mode lasts as long as the programme).
        lift: how far the rod is raised above its immersed pose [m], out of the fluid.
    """

    mode: str = "mean"
    duration: float = 2.0
    lift: float = 0.10

    def __post_init__(self) -> None:
        check_choice("dry_run.mode", self.mode, DRY_RUN_MODES)
        _positive("dry_run.duration", self.duration, "s")
        _positive("dry_run.lift", self.lift, "m")


@dataclass
class DensitySettings:
    """The Archimedes density measurement, ρ = (G − R) / (A h g) (``recording.DensityMeasurement``).

    Attributes:
        skip: no density measurement.
        rod_weight: G [N], the rod held vertical in air (None: asked for when interactive).
        immersed_reading: R [N], the axial reading immersed at rest (None: asked for when interactive).
        immersed_depth: h [m] (None: the rig's rod immersion depth).
        rod_cross_section: A [m²] (None: π r² of the rig's rod).
    """

    skip: bool = False
    rod_weight: float | None = None
    immersed_reading: float | None = None
    immersed_depth: float | None = None
    rod_cross_section: float | None = None

    def __post_init__(self) -> None:
        for name in ("rod_weight", "immersed_reading"):
            value = getattr(self, name)
            if value is not None and not is_number(value):
                raise ConfigError(f"density.{name} = {value!r} N; expected a finite force in N, or null")
        for name, unit in (("immersed_depth", "m"), ("rod_cross_section", "m^2")):
            if getattr(self, name) is not None:
                _positive(f"density.{name}", getattr(self, name), unit)
        if None not in (self.rod_weight, self.immersed_reading) and not self.rod_weight > self.immersed_reading:
            raise ConfigError(f"density.rod_weight = {self.rod_weight} N is not more than density.immersed_reading = "
                              f"{self.immersed_reading} N; expected G > R (the fluid's buoyancy lifts the rod)")


@dataclass
class StirSettings:
    """The stirring programme: a trajectory file, or a circle of the rod's axis about the cup's.

    Attributes:
        file: a CSV trajectory (t, x, y[, z]) to replay instead of the circle (None: the circle).
        radius: the circle's radius [m].
        rev_per_s: revolutions per second [1/s] (the speed 2π radius rev_per_s unless ``speed`` is given).
        speed: the tangential speed [m/s] (None: from ``rev_per_s``).
        duration: how long the rod stirs [s].
        ramp_time: the smooth start [s], shorter than ``duration``.
        clockwise: stir clockwise seen from above.
    """

    file: str | None = None
    radius: float = 0.02
    rev_per_s: float = 0.5
    speed: float | None = None
    duration: float = 8.0
    ramp_time: float = 0.5
    clockwise: bool = False

    def __post_init__(self) -> None:
        _positive("stir.radius", self.radius, "m")
        _positive("stir.rev_per_s", self.rev_per_s, "1/s")
        if self.speed is not None:
            _positive("stir.speed", self.speed, "m/s")
        _positive("stir.duration", self.duration, "s")
        if not (is_number(self.ramp_time) and 0 <= self.ramp_time < self.duration):
            raise ConfigError(f"stir.ramp_time = {self.ramp_time!r} s; expected a time in s from 0 to less than "
                              f"stir.duration = {self.duration} s")


def _positive(setting: str, value, unit: str) -> None:
    if not (is_number(value) and value > 0):
        raise ConfigError(f"{setting} = {value!r} {unit}; expected a positive number in {unit}")
