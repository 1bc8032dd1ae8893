"""Fluid density by Archimedes' principle with the stirring rod, with a first-order uncertainty budget.

rho = (G - R) / (A h g): rod weight in air G [N], axial reading with the rod held still and immersed R [N],
rod cross-section A [m²], immersed length h [m], g = 9.81 m/s². See docs/density.md.

Each reading's standard uncertainty is its resolution / sqrt(12) (the error of a reading rounded to a step of
one resolution is uniform over one step) unless an explicit standard uncertainty is given. The readings are
taken as independent; a common calibration gain error of the force sensor is not included (it scales rho by
the same factor), a common offset cancels in G - R.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from diffstir.recording.errors import RecordingError
from diffstir.recording.format import GRAVITY, DensityMeasurement, Recording

FORCE_RESOLUTION = 0.005  # N: the paper's force sensor (RP-C18.3-ST) resolves 0.005 N
DEPTH_RESOLUTION = 1e-4  # m: the paper's ruler reads 0.1 mm
Z95 = 1.959963984540054  # two-sided 95 % quantile of the standard normal


@dataclass(frozen=True)
class DensityEstimate:
    """Density ``value`` [kg/m³], its standard uncertainty ``std`` [kg/m³], the normal-approximation interval
    ``ci95`` = value ± 1.96 std [kg/m³], and ``contributions``: each input's share of the variance (sums to 1),
    keyed rod_weight, immersed_reading, immersed_depth, rod_cross_section."""

    value: float
    std: float
    ci95: tuple[float, float]
    contributions: dict[str, float]

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
                     depth_std: float | None = None, g: float = GRAVITY) -> DensityEstimate:
    """Archimedes density of ``m`` with first-order (linear) uncertainty propagation.

    rho = (G - R) / (A h g), A = m.rod_cross_section or pi rod_radius² [m²].
    var(rho) = rho² [(u_G² + u_R²) / (G - R)² + (u_h / h)² + (u_A / A)²], with
    u_G = u_R = force_std or force_resolution / sqrt(12) [N], u_h = depth_std or depth_resolution / sqrt(12) [m],
    u_A / A = 2 radius_uncertainty / r [-] (radius_uncertainty: the rod radius's standard uncertainty [m];
    r = rod_radius, or sqrt(A / pi) for a given cross-section). The 95 % interval is value ± 1.96 std.
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
                              ("depth_std", depth_std, "m")):
        _non_negative(name, value, unit)
    area = m.cross_section(rod_radius)
    if not (math.isfinite(area) and area > 0):
        raise RecordingError(f"estimate_density: density.rod_cross_section = {area!r}; expected a positive area "
                             f"in m^2")

    buoyancy = m.rod_weight - m.immersed_reading
    rho = buoyancy / (area * m.immersed_depth * g)
    u_force = force_std if force_std is not None else resolution_std(force_resolution)
    u_depth = depth_std if depth_std is not None else resolution_std(depth_resolution)
    radius = rod_radius if rod_radius is not None else math.sqrt(area / math.pi)
    u_area_rel = 0.0 if radius_uncertainty is None else 2.0 * radius_uncertainty / radius
    variances = {  # (d rho / d input)² u_input²
        "rod_weight": (rho * u_force / buoyancy) ** 2,
        "immersed_reading": (rho * u_force / buoyancy) ** 2,
        "immersed_depth": (rho * u_depth / m.immersed_depth) ** 2,
        "rod_cross_section": (rho * u_area_rel) ** 2,
    }
    variance = sum(variances.values())
    std = math.sqrt(variance)
    contributions = {k: (v / variance if variance > 0 else 0.0) for k, v in variances.items()}
    return DensityEstimate(rho, std, (rho - Z95 * std, rho + Z95 * std), contributions)


def estimate_recording_density(rec: Recording, **kwargs) -> DensityEstimate:
    """estimate_density of ``rec.density`` with the rod radius of ``rec.rod`` and, unless ``force_resolution``
    or ``force_std`` is given, the force resolution of ``rec.sensor`` (falling back to FORCE_RESOLUTION)."""
    if rec.density is None:
        raise RecordingError(f"{rec.source('yaml')}: section 'density' is missing; no Archimedes measurement "
                             f"(rod_weight N, immersed_reading N, immersed_depth m)")
    if rec.sensor.resolution is not None and "force_resolution" not in kwargs and "force_std" not in kwargs:
        kwargs["force_resolution"] = rec.sensor.resolution
    kwargs.setdefault("rod_radius", rec.rod.radius)
    try:
        return estimate_density(rec.density, **kwargs)
    except RecordingError as exc:
        raise RecordingError(f"{rec.source('yaml')}: {exc}") from None
