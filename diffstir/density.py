"""Fluid density by Archimedes' principle with the stirring rod, with a first-order uncertainty budget.

rho = (G - R) / (A h g): rod weight in air G [N], axial reading with the rod held still and immersed R [N],
rod cross-section A [m²], immersed length h [m], g = 9.81 m/s². See docs/density.md.

The force readings' standard uncertainty u_F [N] comes from the first of (``uncertainty_source``):

* ``force_std``: given explicitly;
* ``readings``: G or R read repeatedly (``DensityMeasurement.rod_weight_readings``, ``immersed_readings``): the
  pooled standard deviation s of the readings about their means, ν = Σ (n_i − 1) degrees of freedom, u = s / sqrt(n)
  for a mean of n readings, and the interval's factor Student's t_{0.975, ν} instead of 1.96;
* ``quiet_stretch``: the standard deviation of the ``force`` column where the rod rests before or after it stirs
  (``rest_force_noise``), one reading's scatter;
* ``sensor.noise``: the sensor's stated 1-σ noise [N] per reading;
* ``resolution``: the resolution / sqrt(12) (the error of a reading rounded to a step of one resolution is uniform
  over one step),

never below resolution / sqrt(12): readings that agree to the last step do not resolve their noise. The readings
are taken as independent; a common calibration gain error of the force sensor is not included (it scales rho by
the same factor), a common offset cancels in G - R.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from diffstir.recording.errors import RecordingError
from diffstir.recording.format import GRAVITY, DensityMeasurement, Recording
from diffstir.recording.smoothing import smooth_path

#: m/s: a rod slower than this rests (``diffstir.fitting.windows.PAUSE_SPEED``).
REST_SPEED = 1e-3
#: Fewest samples of a quiet stretch whose scatter stands for a reading's noise.
REST_SAMPLES = 20
FORCE_RESOLUTION = 0.005  # N: the paper's force sensor (RP-C18.3-ST) resolves 0.005 N
DEPTH_RESOLUTION = 1e-4  # m: the paper's ruler reads 0.1 mm
Z95 = 1.959963984540054  # two-sided 95 % quantile of the standard normal


@dataclass(frozen=True)
class DensityEstimate:
    """Density ``value`` [kg/m³], its standard uncertainty ``std`` [kg/m³], the normal-approximation interval
    ``ci95`` = value ± k std [kg/m³] (k = 1.96, or Student's t of the readings' degrees of freedom),
    ``contributions``: each input's share of the variance (sums to 1), keyed rod_weight, immersed_reading,
    immersed_depth, rod_cross_section, and ``uncertainty_source``: where the force readings' uncertainty comes
    from (force_std, readings, quiet_stretch, sensor.noise or resolution; see the module docstring)."""

    value: float
    std: float
    ci95: tuple[float, float]
    contributions: dict[str, float]
    uncertainty_source: str = "resolution"

    @property
    def relative_std(self) -> float:
        """std / value (dimensionless)."""
        return self.std / self.value


def resolution_std(resolution: float) -> float:
    """Standard uncertainty of a reading quantised to steps of ``resolution``: resolution / sqrt(12) (same unit)."""
    return resolution / math.sqrt(12.0)


def _non_negative(name: str, value: float | None, unit: str) -> None:
    if value is not None and not (math.isfinite(value) and value >= 0):
        raise RecordingError(f"estimate_density: {name} = {value!r}; expected a non-negative number in {unit}")


def estimate_density(m: DensityMeasurement, *, rod_radius: float | None = None,
                     force_resolution: float = FORCE_RESOLUTION, depth_resolution: float = DEPTH_RESOLUTION,
                     radius_uncertainty: float | None = None, force_std: float | None = None,
                     depth_std: float | None = None, g: float = GRAVITY, rest_noise: float | None = None,
                     sensor_noise: float | None = None) -> DensityEstimate:
    """Archimedes density of ``m`` with first-order (linear) uncertainty propagation.

    rho = (G - R) / (A h g), A = m.rod_cross_section or pi rod_radius² [m²].
    var(rho) = rho² [(u_G² + u_R²) / (G - R)² + (u_h / h)² + (u_A / A)²], with u_G, u_R [N] from the first of
    ``force_std``, the repeated readings' scatter, ``rest_noise`` [N] (a quiet stretch's scatter),
    ``sensor_noise`` [N] and ``force_resolution`` / sqrt(12) (module docstring), u_h = depth_std or
    depth_resolution / sqrt(12) [m], u_A / A = 2 radius_uncertainty / r [-] (radius_uncertainty: the rod radius's
    standard uncertainty [m]; r = rod_radius, or sqrt(A / pi) for a given cross-section). The 95 % interval is
    value ± k std, k = t_{0.975, ν} for ν degrees of freedom of repeated readings, else 1.96.
    """
    for name, value in (("density.rod_weight", m.rod_weight), ("density.immersed_reading", m.immersed_reading)):
        if not math.isfinite(value):
            raise RecordingError(f"estimate_density: {name} = {value!r}; expected a finite force in N")
    if not (math.isfinite(m.immersed_depth) and m.immersed_depth > 0):
        raise RecordingError(f"estimate_density: density.immersed_depth = {m.immersed_depth!r}; expected a "
                             f"positive length in m")
    if not m.rod_weight > m.immersed_reading:
        raise RecordingError(f"estimate_density: density.immersed_reading = {m.immersed_reading!r} N is not smaller "
                             f"than density.rod_weight = {m.rod_weight!r} N; the buoyancy G - R must be positive (N)")
    if rod_radius is not None and not (math.isfinite(rod_radius) and rod_radius > 0):
        raise RecordingError(f"estimate_density: rod_radius = {rod_radius!r}; expected a positive length in m")
    for name, value, unit in (("force_resolution", force_resolution, "N"), ("depth_resolution", depth_resolution, "m"),
                              ("radius_uncertainty", radius_uncertainty, "m"), ("force_std", force_std, "N"),
                              ("depth_std", depth_std, "m"), ("rest_noise", rest_noise, "N"),
                              ("sensor.noise", sensor_noise, "N (1 sigma)")):
        _non_negative(name, value, unit)
    area = m.cross_section(rod_radius)
    if not (math.isfinite(area) and area > 0):
        raise RecordingError(f"estimate_density: density.rod_cross_section = {area!r}; expected a positive area "
                             f"in m^2")

    buoyancy = m.rod_weight - m.immersed_reading
    rho = buoyancy / (area * m.immersed_depth * g)
    (u_weight, u_reading), source, factor = _force_uncertainty(m, force_resolution, force_std, rest_noise,
                                                              sensor_noise)
    u_depth = depth_std if depth_std is not None else resolution_std(depth_resolution)
    radius = rod_radius if rod_radius is not None else math.sqrt(area / math.pi)
    u_area_rel = 0.0 if radius_uncertainty is None else 2.0 * radius_uncertainty / radius
    variances = {  # (d rho / d input)² u_input²
        "rod_weight": (rho * u_weight / buoyancy) ** 2,
        "immersed_reading": (rho * u_reading / buoyancy) ** 2,
        "immersed_depth": (rho * u_depth / m.immersed_depth) ** 2,
        "rod_cross_section": (rho * u_area_rel) ** 2,
    }
    variance = sum(variances.values())
    std = math.sqrt(variance)
    contributions = {k: (v / variance if variance > 0 else 0.0) for k, v in variances.items()}
    return DensityEstimate(rho, std, (rho - factor * std, rho + factor * std), contributions, source)


def _force_uncertainty(m: DensityMeasurement, resolution: float, force_std: float | None, rest_noise: float | None,
                       sensor_noise: float | None) -> tuple[tuple[float, float], str, float]:
    """(u_G, u_R) [N], their source and the 95 % coverage factor (see the module docstring)."""
    floor = resolution_std(resolution)
    if force_std is not None:
        return (force_std, force_std), "force_std", Z95
    repeated = [np.asarray(r) for r in (m.rod_weight_readings, m.immersed_readings) if r is not None and len(r) > 1]
    dof = sum(r.size - 1 for r in repeated)
    if dof > 0:
        pooled = math.sqrt(sum(float(np.sum((r - r.mean()) ** 2)) for r in repeated) / dof)
        counts = [len(r) if r is not None else 1 for r in (m.rod_weight_readings, m.immersed_readings)]
        u = tuple(max(pooled / math.sqrt(n), floor) for n in counts)
        return u, "readings", float(stats.t.ppf(0.975, dof))
    for value, source in ((rest_noise, "quiet_stretch"), (sensor_noise, "sensor.noise")):
        if value is not None and value > 0:
            return (max(value, floor),) * 2, source, Z95
    return (floor, floor), "resolution", Z95


def rest_force_noise(rec: Recording) -> float | None:
    """Standard deviation [N] of ``rec.force`` where the rod rests (its smoothed speed, ``smooth_path``, below
    REST_SPEED) before it first moves or after it last moves, over the longer such stretch of at least
    REST_SAMPLES samples; None when there is none or its force is constant (a one-sided sensor reading zero)."""
    if rec.t.size < REST_SAMPLES:
        return None
    moving = smooth_path(rec.t, np.stack([rec.x, rec.y], axis=-1)).speed(rec.t) >= REST_SPEED
    stretches = []
    for order in (slice(None), slice(None, None, -1)):
        first = np.flatnonzero(moving[order])
        stretches.append(rec.force[order][:int(first[0]) if first.size else rec.t.size])
    quiet = max(stretches, key=len)
    if quiet.size < REST_SAMPLES or np.ptp(quiet) == 0:
        return None
    return float(np.std(quiet, ddof=1))


def estimate_recording_density(rec: Recording, **kwargs) -> DensityEstimate:
    """estimate_density of ``rec.density`` with the rod radius of ``rec.rod``, the scatter of the force where the
    rod rests (``rest_force_noise``), the sensor's stated noise and, unless ``force_resolution`` or ``force_std``
    is given, the force resolution of ``rec.sensor`` (falling back to FORCE_RESOLUTION)."""
    if rec.density is None:
        raise RecordingError(f"{rec.source('yaml')}: section 'density' is missing; no Archimedes measurement "
                             f"(rod_weight N, immersed_reading N, immersed_depth m)")
    if rec.sensor.resolution is not None and "force_resolution" not in kwargs and "force_std" not in kwargs:
        kwargs["force_resolution"] = rec.sensor.resolution
    kwargs.setdefault("rod_radius", rec.rod.radius)
    kwargs.setdefault("rest_noise", rest_force_noise(rec))
    kwargs.setdefault("sensor_noise", rec.sensor.noise)
    try:
        return estimate_density(rec.density, **kwargs)
    except RecordingError as exc:
        raise RecordingError(f"{rec.source('yaml')}: {exc}") from None


def density_estimate(recording: Recording, density: float | None) -> dict:
    """The fluid's density [kg/m³] with its 95 % interval: Archimedes from the recording's density block, or
    ``density`` from the config when the recording has none."""
    if recording.density is not None:
        est = estimate_recording_density(recording)
        return {"value": est.value, "ci95": list(est.ci95), "unit": "kg/m^3", "source": "archimedes",
                "uncertainty_source": est.uncertainty_source}
    return configured_density(density, f"{recording.source('yaml')}: no density block")


def configured_density(density: float | None, missing: str) -> dict:
    """The config's ``density`` [kg/m³] as a density report, for recordings without a density block (``missing``
    says which, for the error when none is configured either)."""
    if density is None:
        raise RecordingError(f"{missing}, and no density (kg/m^3) was given; set density=... in the config")
    if not 100.0 <= density <= 25000.0:
        raise ValueError(f"density = {density} kg/m^3 is not a liquid's density in kg/m^3")
    return {"value": float(density), "ci95": None, "unit": "kg/m^3", "source": "config"}


def combined_density(recordings: list[Recording], density: float | None) -> dict:
    """The inverse-variance weighted mean of the recordings' Archimedes densities [kg/m³] with its 95 % interval,
    or ``density`` [kg/m³] when no recording has a density block."""
    estimates = [estimate_recording_density(r) for r in recordings if r.density is not None]
    if estimates:
        w = np.array([1.0 / e.std**2 for e in estimates])
        value = float(np.sum(w * [e.value for e in estimates]) / w.sum())
        std = float(1.0 / math.sqrt(w.sum()))
        return {"value": value, "ci95": [value - 1.96 * std, value + 1.96 * std], "unit": "kg/m^3",
                "source": f"archimedes ({len(estimates)} recordings)"}
    return configured_density(density, f"{recordings[0].source('yaml')}: no recording has a density block")
