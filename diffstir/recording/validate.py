"""Checks that a recording is well formed, physically possible and fine enough to fit a simulation to.

Every message names the file, the field or column, the offending value (with row and time for columns; rows
count data lines from 1, header and comments excluded) and the expected unit.
"""

from __future__ import annotations

import math

import numpy as np

from diffstir.recording.errors import RecordingError
from diffstir.recording.format import (
    COLUMN_UNITS, OPTIONAL_COLUMNS, REQUIRED_COLUMNS, SENSOR_MODES, CupGeometry, DensityMeasurement, Recording,
    RodGeometry, SensorSpec,
)
from diffstir.recording.stirring import MIN_STIR_AMPLITUDE, stirring_frequency

MAX_LENGTH = 1.0  # m: a cup, rod or position beyond this looks like millimetres
MAX_VOLUME = 1.0  # m³: a fill volume beyond this looks like millilitres
AXIS_TOLERANCE = 1e-3  # |‖axis‖ - 1| allowed for a component sensor's axis
FILL_TOLERANCE = 0.02  # relative disagreement of fill_height and fill_volume that is warned about
MIN_SAMPLES_PER_PERIOD = 10  # samples per stirring period, at the median sample spacing
MIN_DURATION = 0.5  # s; a recording must also span one stirring period
MAX_TIME_CONSTANT = 1.0  # s: a stated sensor response time beyond this looks like milliseconds
SAMPLE_RATE_UNIT_RATIO = 100.0  # a declared sample rate this many times off the times' looks like ms or kHz
MAX_GAP_PERIODS = 0.25  # a single gap between samples longer than this many stirring periods is warned about
PLAUSIBLE_DENSITY = (400.0, 3000.0)  # kg/m³: Archimedes densities outside this range are warned about
PLAUSIBLE_TEMPERATURE = (-30.0, 120.0)  # °C
TIME_RESOLUTION = 0.01  # of the median sample spacing: the float64 spacing of the clock's readings must be finer


def _raise(errors: list[str]) -> None:
    """Raise one RecordingError on one line for all of ``errors``, if any."""
    if len(errors) == 1:
        raise RecordingError(errors[0])
    if errors:
        raise RecordingError(f"{len(errors)} problems: " + " ".join(f"({k}) {e};" for k, e in enumerate(errors, 1)))


def _length(errors: list[str], where: str, field: str, value: float | None) -> bool:
    """A positive, finite length [m] that does not look like millimetres; False (with an error) otherwise."""
    if value is None:
        return False
    if not (math.isfinite(value) and value > 0):
        errors.append(f"{where}: field '{field}' = {value!r}; expected a positive length in m")
        return False
    if value > MAX_LENGTH:
        errors.append(f"{where}: field '{field}' = {value!r} m looks like millimetres or centimetres; expected "
                      f"metres (m)")
        return False
    return True


def check_metadata(cup: CupGeometry, rod: RodGeometry, sensor: SensorSpec, density: DensityMeasurement | None,
                   temperature: float | None, where: str) -> list[str]:
    """Raise RecordingError for impossible rig, sensor or density metadata (``where`` names recording.yaml);
    return warnings."""
    errors: list[str] = []
    warnings: list[str] = []

    cup_ok = _length(errors, where, "rig.cup.radius", cup.radius)
    fill_ok = _length(errors, where, "rig.cup.fill_height", cup.fill_height)
    if cup.fill_height is None and cup.fill_volume is None:
        errors.append(f"{where}: field 'rig.cup.fill_height' (m) or 'rig.cup.fill_volume' (m^3) is missing; "
                      f"give one of them")
    if cup.fill_volume is not None:
        if not (math.isfinite(cup.fill_volume) and cup.fill_volume > 0):
            errors.append(f"{where}: field 'rig.cup.fill_volume' = {cup.fill_volume!r}; expected a positive "
                          f"volume in m^3")
        elif cup.fill_volume > MAX_VOLUME:
            errors.append(f"{where}: field 'rig.cup.fill_volume' = {cup.fill_volume!r} m^3 looks like millilitres "
                          f"or mm^3; expected m^3 (738 ml = 7.38e-4 m^3)")
        elif cup_ok:
            from_volume = cup.fill_volume / (math.pi * cup.radius**2)
            if fill_ok and abs(from_volume / cup.fill_height - 1) > FILL_TOLERANCE:
                warnings.append(f"{where}: field 'rig.cup.fill_height' = {cup.fill_height} m disagrees with "
                                f"'rig.cup.fill_volume' = {cup.fill_volume} m^3, which gives {from_volume:.4g} m "
                                f"in a cup of radius {cup.radius} m; using fill_height")
            if cup.fill_height is None and from_volume > MAX_LENGTH:
                errors.append(f"{where}: field 'rig.cup.fill_volume' = {cup.fill_volume!r} m^3 fills a cup of radius "
                              f"{cup.radius} m to {from_volume:.4g} m: looks like millilitres; expected m^3")
            fill_ok = fill_ok or (cup.fill_height is None and from_volume <= MAX_LENGTH)

    rod_ok = _length(errors, where, "rig.rod.radius", rod.radius)
    if cup_ok and rod_ok and rod.radius >= cup.radius:
        errors.append(f"{where}: field 'rig.rod.radius' = {rod.radius} m is not smaller than 'rig.cup.radius' = "
                      f"{cup.radius} m: looks like millimetres or swapped; expected metres (m)")
    depth_ok = _length(errors, where, "rig.rod.immersion_depth", rod.immersion_depth)
    if depth_ok and fill_ok and cup_ok and rod.immersion_depth >= cup.resolved_fill_height():
        errors.append(f"{where}: field 'rig.rod.immersion_depth' = {rod.immersion_depth} m is not smaller than the "
                      f"fill height {cup.resolved_fill_height():.4g} m: the rod would touch the cup's bottom "
                      f"(expected m)")

    if sensor.mode not in SENSOR_MODES:
        errors.append(f"{where}: field 'sensor.mode' = {sensor.mode!r}; expected one of {', '.join(SENSOR_MODES)}")
    if sensor.mode == "component":
        if sensor.axis is None:
            errors.append(f"{where}: field 'sensor.axis' is missing; mode component needs a horizontal unit "
                          f"vector [ax, ay] (dimensionless, cup frame)")
        else:
            norm = math.hypot(*sensor.axis) if len(sensor.axis) == 2 else math.nan
            if not abs(norm - 1.0) <= AXIS_TOLERANCE:
                errors.append(f"{where}: field 'sensor.axis' = {list(sensor.axis)} has length {norm:.6g}; expected "
                              f"a horizontal unit vector (length 1 within {AXIS_TOLERANCE}, dimensionless)")
    elif sensor.axis is not None and sensor.mode in SENSOR_MODES:
        warnings.append(f"{where}: field 'sensor.axis' = {list(sensor.axis)} is ignored in mode {sensor.mode}")
    for field, value, unit in (("resolution", sensor.resolution, "N"), ("sample_rate", sensor.sample_rate, "Hz")):
        if value is not None and not (math.isfinite(value) and value > 0):
            errors.append(f"{where}: field 'sensor.{field}' = {value!r}; expected a positive number in {unit}")
    tau = sensor.time_constant
    if tau is not None and not (math.isfinite(tau) and tau >= 0):
        errors.append(f"{where}: field 'sensor.time_constant' = {tau!r}; expected a response time >= 0 in s")
    elif tau is not None and tau > MAX_TIME_CONSTANT:
        errors.append(f"{where}: field 'sensor.time_constant' = {tau!r} s looks like milliseconds; expected a "
                      f"response time in s (at most {MAX_TIME_CONSTANT:g} s)")

    if density is not None:
        for field, value in (("rod_weight", density.rod_weight), ("immersed_reading", density.immersed_reading)):
            if not math.isfinite(value):
                errors.append(f"{where}: field 'density.{field}' = {value!r}; expected a finite force in N")
        h_ok = _length(errors, where, "density.immersed_depth", density.immersed_depth)
        a = density.rod_cross_section
        a_ok = a is None or (math.isfinite(a) and a > 0)
        if not a_ok:
            errors.append(f"{where}: field 'density.rod_cross_section' = {a!r}; expected a positive area in m^2")
        elif a is not None and cup_ok and a >= math.pi * cup.radius**2:
            errors.append(f"{where}: field 'density.rod_cross_section' = {a!r} m^2 is not smaller than the cup's "
                          f"cross-section: looks like mm^2; expected m^2")
            a_ok = False
        if density.rod_weight <= density.immersed_reading:
            errors.append(f"{where}: field 'density.immersed_reading' = {density.immersed_reading} N is not smaller "
                          f"than 'density.rod_weight' = {density.rod_weight} N: buoyancy G - R must be positive (N)")
        elif h_ok and a_ok and (a is not None or rod_ok):
            rho = density.density(rod.radius)
            if not PLAUSIBLE_DENSITY[0] <= rho <= PLAUSIBLE_DENSITY[1]:
                warnings.append(f"{where}: the density block gives rho = {rho:.4g} kg/m^3, outside the range of "
                                f"household liquids {PLAUSIBLE_DENSITY} kg/m^3; check 'density.*' units (N, m, m^2)")

    if temperature is not None and not PLAUSIBLE_TEMPERATURE[0] <= temperature <= PLAUSIBLE_TEMPERATURE[1]:
        warnings.append(f"{where}: field 'temperature' = {temperature!r} looks like kelvin or Fahrenheit; expected "
                        f"degrees Celsius")
    _raise(errors)
    return warnings


def check_columns_shape(rec: Recording) -> None:
    """Raise RecordingError unless every column is 1-D with the length of ``t``."""
    n = rec.t.size
    for column, values in rec.columns().items():
        if values.ndim != 1 or values.size != n:
            raise RecordingError(f"{rec.source('csv')}: column '{column}' has shape {values.shape}; every column "
                                 f"must be 1-D with the {n} rows of column 't'")


def _row(rec: Recording, i: int) -> str:
    return f"data row {i + 1} (t = {rec.t[i]:.6g} s)"


def _check_values(rec: Recording) -> list[str]:
    """Finite values, strictly increasing t, positions in metres inside the cup."""
    where = rec.source("csv")
    errors: list[str] = []
    warnings: list[str] = []
    for column in REQUIRED_COLUMNS + OPTIONAL_COLUMNS:
        values = getattr(rec, column)
        if values is not None and not np.all(np.isfinite(values)):
            i = int(np.flatnonzero(~np.isfinite(values))[0])
            row = f"data row {i + 1}" if column == "t" else _row(rec, i)
            errors.append(f"{where}: column '{column}' = {values[i]} at {row}; expected finite values in "
                          f"{COLUMN_UNITS[column]}")
    _raise(errors)

    steps = np.diff(rec.t)
    if np.any(steps <= 0):
        i = int(np.flatnonzero(steps <= 0)[0]) + 1
        errors.append(f"{where}: column 't' = {float(rec.t[i] + rec.time_origin)!r} s at data row {i + 1} does not "
                      f"increase on {float(rec.t[i - 1] + rec.time_origin)!r} s at data row {i}; expected strictly "
                      f"increasing times in s")
    elif steps.size:
        clock = abs(rec.time_origin) + float(np.max(np.abs(rec.t)))
        spacing, interval = float(np.spacing(clock)), float(np.median(steps))
        if spacing > TIME_RESOLUTION * interval:
            errors.append(f"{where}: column 't' reads up to {clock:.6g} s, where float64 (the rig's clock) resolves "
                          f"only {spacing:.3g} s, more than {TIME_RESOLUTION:.0%} of the {interval:.3g} s sample "
                          f"spacing; expected times in s from a recent origin (e.g. the recording's start)")

    in_metres = True
    for column in ("x", "y", "z"):
        values = getattr(rec, column)
        if values is not None and values.size and np.max(np.abs(values)) > MAX_LENGTH:
            i = int(np.argmax(np.abs(values)))
            errors.append(f"{where}: column '{column}' = {values[i]} at {_row(rec, i)} looks like millimetres; "
                          f"expected metres (m)")
            in_metres = False
    if in_metres and rec.t.size:
        distance = np.hypot(rec.x, rec.y)
        touching = distance + rec.rod.radius >= rec.cup.radius
        if np.any(touching):
            i = int(np.flatnonzero(touching)[0])
            errors.append(
                f"{where}: columns 'x', 'y' = ({rec.x[i]}, {rec.y[i]}) m at {_row(rec, i)}: the rod touches or "
                f"leaves the cup wall: axis {distance[i]:.6g} m from the cup axis + rod radius {rec.rod.radius} m "
                f">= cup radius {rec.cup.radius} m (largest axis distance {distance.max():.6g} m; "
                f"expected < {rec.cup.radius - rec.rod.radius:.6g} m)")
        if rec.z is not None:
            depth = rec.rod.immersion_depth - rec.z
            fill = rec.cup.resolved_fill_height()
            if np.any(depth >= fill):
                i = int(np.flatnonzero(depth >= fill)[0])
                errors.append(f"{where}: column 'z' = {rec.z[i]} m at {_row(rec, i)}: the rod's tip is "
                              f"{depth[i]:.4g} m deep, reaching the cup's bottom at {fill:.4g} m (z is up positive, m)")
            if np.any(depth <= 0):
                i = int(np.flatnonzero(depth <= 0)[0])
                warnings.append(f"{where}: column 'z' = {rec.z[i]} m at {_row(rec, i)}: the rod's tip is out of "
                                f"the fluid (immersion depth {rec.rod.immersion_depth} m, z up positive, m)")
    _raise(errors)
    return warnings


def _check_stir(rec: Recording) -> tuple[list[str], list[str]]:
    """Whether the recording is long and finely sampled enough to fit: (errors, warnings)."""
    where = rec.source("csv")
    n = rec.t.size
    if n < 2:
        return [f"{where}: {n} data rows; a recording needs at least 2 rows (and {MIN_DURATION} s)"], []
    errors: list[str] = []
    warnings: list[str] = []
    rate = rec.sample_rate_estimate
    f = stirring_frequency(rec.t, rec.x, rec.y)
    if f == 0.0:
        excursion = float(np.max(np.hypot(rec.x - np.mean(rec.x), rec.y - np.mean(rec.y))))
        errors.append(f"{where}: columns 'x', 'y': the rod does not stir (its axis stays within {excursion:.3g} m "
                      f"of its mean position); expected a stir of at least {MIN_STIR_AMPLITUDE * 1e3:g} mm (in m), "
                      f"nothing to fit a viscosity to")
        shortest = MIN_DURATION
    else:
        period = 1.0 / f
        shortest = max(MIN_DURATION, period)
        if rate / f < MIN_SAMPLES_PER_PERIOD:
            errors.append(f"{where}: column 't': sampling at {rate:.4g} Hz (median spacing) gives {rate / f:.3g} "
                          f"samples per stirring period (stirring frequency {f:.3g} Hz estimated from 'x', 'y'); "
                          f"expected at least {MIN_SAMPLES_PER_PERIOD}, i.e. >= {MIN_SAMPLES_PER_PERIOD * f:.4g} Hz")
        gaps = np.diff(rec.t)
        i = int(np.argmax(gaps))
        if gaps[i] > MAX_GAP_PERIODS * period:
            warnings.append(f"{where}: column 't' jumps by {gaps[i]:.4g} s after {_row(rec, i)}, more than "
                            f"{MAX_GAP_PERIODS} of a stirring period ({period:.4g} s)")
    if rec.duration < shortest:
        errors.append(f"{where}: column 't' spans {rec.duration:.4g} s (from {rec.t[0]} s to {rec.t[-1]} s); "
                      f"too short to fit: expected at least {shortest:.4g} s (max of {MIN_DURATION} s and one "
                      f"stirring period)")
    declared = rec.sensor.sample_rate
    if declared is not None and not 1 / SAMPLE_RATE_UNIT_RATIO < rate / declared < SAMPLE_RATE_UNIT_RATIO:
        errors.append(f"{rec.source('yaml')}: field 'sensor.sample_rate' = {declared} Hz, but column 't' in {where} "
                      f"is sampled at {rate:.4g} Hz (median spacing): is t in ms or µs, or the rate in kHz? expected "
                      f"t in s and the rate in Hz")
    elif declared is not None and abs(rate / declared - 1) > 0.2:
        warnings.append(f"{rec.source('yaml')}: field 'sensor.sample_rate' = {declared} Hz, but column 't' in "
                        f"{where} is sampled at {rate:.4g} Hz (median spacing)")
    return errors, warnings


def _check_force(rec: Recording) -> list[str]:
    """Readings the sensor cannot produce: negative values from a one-sided or magnitude sensor."""
    if not rec.force.size or rec.force.min() >= 0 or not (rec.sensor.one_sided or rec.sensor.mode == "magnitude"):
        return []
    i = int(np.argmin(rec.force))
    why = "sensor.one_sided is true" if rec.sensor.one_sided else "sensor.mode is magnitude"
    return [f"{rec.source('csv')}: column 'force' = {rec.force[i]} N at {_row(rec, i)} is negative although {why} "
            f"in {rec.source('yaml')}; expected >= 0 N"]


def validate_recording(rec: Recording) -> list[str]:
    """Raise RecordingError if ``rec`` is malformed, impossible or unfit to fit; return warnings as strings.

    Checks, in order: column shapes; metadata (check_metadata); finite columns, strictly increasing t,
    positions in metres with the rod clear of the wall and the bottom; then fitness: at least
    MIN_SAMPLES_PER_PERIOD samples per stirring period (stirring_frequency) at the median sample spacing, and a
    duration of at least max(MIN_DURATION, one period), a rod that stirs at all, and clock readings that float64
    resolves to TIME_RESOLUTION of the sample spacing. For a partial recording (complete: false) the fitness
    checks only warn, so that whatever a crash left can still be loaded.
    """
    check_columns_shape(rec)
    warnings = check_metadata(rec.cup, rec.rod, rec.sensor, rec.density, rec.temperature, rec.source("yaml"))
    warnings += _check_values(rec)
    errors, stir_warnings = _check_stir(rec)
    if rec.complete:
        _raise(errors)
    else:
        warnings += [f"{e} (partial recording: not raised)" for e in errors]
    return warnings + stir_warnings + _check_force(rec)
