"""The recording format, version 1: what a recording holds, as dataclasses (docs/recording-format.md).

All quantities are SI: lengths in m, times in s, forces in N, volumes in m³, temperature in °C.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from diffstir.recording.errors import RecordingError

FORMAT = "diffstir-recording/1"
YAML_NAME = "recording.yaml"
CSV_NAME = "stir.csv"
SENSOR_MODES = ("component", "tangential", "magnitude")
REQUIRED_COLUMNS = ("t", "x", "y", "force")
OPTIONAL_COLUMNS = ("z", "force_x", "force_y", "raw")
COLUMN_UNITS = {"t": "s", "x": "m", "y": "m", "force": "N", "z": "m", "force_x": "N", "force_y": "N",
                "raw": "sensor counts"}
GRAVITY = 9.81  # m/s², the value of the spec and the paper


@dataclass(frozen=True)
class CupGeometry:
    """A cylindrical cup: inner ``radius`` [m], and the fluid's depth at rest as ``fill_height`` [m] or
    ``fill_volume`` [m³] (fill_height = fill_volume / (pi radius²))."""

    radius: float
    fill_height: float | None = None
    fill_volume: float | None = None

    def resolved_fill_height(self) -> float:
        """Depth of the fluid at rest [m]: ``fill_height`` if given, else fill_volume / (pi radius²)."""
        if self.fill_height is not None:
            return float(self.fill_height)
        if self.fill_volume is not None:
            return float(self.fill_volume) / (math.pi * self.radius**2)
        raise RecordingError("rig.cup: neither fill_height (m) nor fill_volume (m^3) is given")


@dataclass(frozen=True)
class RodGeometry:
    """A vertical cylindrical rod: ``radius`` [m], tip ``immersion_depth`` [m] below the free surface at rest."""

    radius: float
    immersion_depth: float


@dataclass(frozen=True)
class SensorSpec:
    """What the ``force`` column means: ``mode`` (component: F·axis, tangential: F·(-v/|v|), magnitude: |F|),
    ``axis`` (horizontal unit vector, cup frame, component mode only), ``one_sided`` (column holds max(0, value)),
    ``resolution`` [N], nominal ``sample_rate`` [Hz], ``time_constant`` [s], the sensor's first-order
    response time τ as calibrated (τ dy/dt = x − y; None: not stated, taken as instantaneous), and ``noise``
    [N], the standard deviation (1 σ) of one reading as stated for the sensor (None: not stated)."""

    mode: Literal["component", "tangential", "magnitude"]
    axis: tuple[float, float] | None = None
    one_sided: bool = False
    resolution: float | None = None
    sample_rate: float | None = None
    time_constant: float | None = None
    noise: float | None = None


@dataclass(frozen=True)
class DensityMeasurement:
    """Archimedes measurement with the stirring rod: weight in air ``rod_weight`` G [N], axial reading immersed
    at rest ``immersed_reading`` R [N], ``immersed_depth`` h [m], optional ``rod_cross_section`` A [m²]
    (default pi rod.radius²). rho = (G - R) / (A h g). Where G or R was read repeatedly, ``rod_weight_readings``
    and ``immersed_readings`` [N] hold the readings and ``rod_weight`` and ``immersed_reading`` their means."""

    rod_weight: float
    immersed_reading: float
    immersed_depth: float
    rod_cross_section: float | None = None
    rod_weight_readings: tuple[float, ...] | None = None
    immersed_readings: tuple[float, ...] | None = None

    @classmethod
    def of_readings(cls, rod_weight: float | list[float], immersed_reading: float | list[float],
                    immersed_depth: float, rod_cross_section: float | None = None) -> "DensityMeasurement":
        """The measurement of one reading or a list of repeated readings [N] of G and of R (their means)."""
        def split(value):
            if isinstance(value, (list, tuple, np.ndarray)):
                readings = tuple(float(v) for v in value)
                return (float(np.mean(readings)) if readings else math.nan), readings
            return float(value), None
        (g, g_readings), (r, r_readings) = split(rod_weight), split(immersed_reading)
        return cls(g, r, float(immersed_depth), rod_cross_section, g_readings, r_readings)

    def cross_section(self, rod_radius: float | None) -> float:
        """A [m²]: ``rod_cross_section`` if given, else pi rod_radius² (``rod_radius`` in m)."""
        if self.rod_cross_section is not None:
            return float(self.rod_cross_section)
        if rod_radius is None:
            raise RecordingError("density: rod_cross_section (m^2) is not given, so the rod radius (m) is needed")
        return math.pi * float(rod_radius) ** 2

    def density(self, rod_radius: float | None, g: float = GRAVITY) -> float:
        """Archimedes: rho = (G - R) / (A h g) [kg/m³], A from ``cross_section(rod_radius)``, g in m/s²."""
        return (self.rod_weight - self.immersed_reading) / (self.cross_section(rod_radius) * self.immersed_depth * g)


def _column(values, name: str) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.float64) if values is not None else None


@dataclass
class Recording:
    """One stirring recording: rig, sensor, optional density measurement, and the time series.

    Columns are float64 1-D arrays of one length: ``t`` [s], ``x``, ``y`` [m] (rod axis, cup frame), ``force`` [N]
    (as ``sensor`` defines it), and optionally ``z`` [m], ``force_x``, ``force_y`` [N], ``raw`` [counts].
    ``time_origin`` [s] is the rig clock's reading at the first sample: ``load_recording`` counts ``t`` from it
    (t[0] = 0), so that times keep their resolution whatever the clock read.
    ``complete`` is False for a recording cut short (crash, Ctrl-C), with ``partial_reason``. Fields and
    columns this version does not know are kept in ``extra_meta`` (nested like the yaml) and ``extra_columns``.
    """

    cup: CupGeometry
    rod: RodGeometry
    sensor: SensorSpec
    density: DensityMeasurement | None
    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    force: np.ndarray
    z: np.ndarray | None = None
    force_x: np.ndarray | None = None
    force_y: np.ndarray | None = None
    raw: np.ndarray | None = None
    name: str | None = None
    fluid: str | None = None
    temperature: float | None = None
    time_origin: float = 0.0
    complete: bool = True
    partial_reason: str | None = None
    extra_meta: dict = field(default_factory=dict)
    extra_columns: dict[str, np.ndarray] = field(default_factory=dict)
    path: Path | None = None
    _velocity: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in REQUIRED_COLUMNS + OPTIONAL_COLUMNS:
            setattr(self, name, _column(getattr(self, name), name))
        self.extra_columns = {k: np.asarray(v) for k, v in self.extra_columns.items()}
        if self.path is not None:
            self.path = Path(self.path)

    def columns(self) -> dict[str, np.ndarray]:
        """All columns present, required first, then optional, then unknown ones, by name."""
        out = {name: getattr(self, name) for name in REQUIRED_COLUMNS + OPTIONAL_COLUMNS
               if getattr(self, name) is not None}
        out.update(self.extra_columns)
        return out

    def velocity(self) -> np.ndarray:
        """Rod axis velocity [m/s], shape (N, 2), at the samples: the derivative of the rod path as the arm moved,
        each coordinate's GCV smoothing spline (``diffstir.recording.smoothing``), so that position jitter and
        rounding do not reach the speed or the tangential sensor's direction. Computed once per path."""
        if self.t.size < 2:
            raise RecordingError(f"{self.source('csv')}: velocity needs at least 2 rows, got {self.t.size}")
        key = hash((self.t.tobytes(), self.x.tobytes(), self.y.tobytes()))
        if self._velocity is None or self._velocity[0] != key:
            from diffstir.recording.smoothing import smooth_path

            path = smooth_path(self.t, np.stack([self.x, self.y], axis=-1))
            self._velocity = (key, path.velocity(self.t))
        return self._velocity[1].copy()

    @property
    def duration(self) -> float:
        """t[-1] - t[0] [s] (0 for fewer than 2 rows)."""
        return float(self.t[-1] - self.t[0]) if self.t.size >= 2 else 0.0

    @property
    def sample_rate_estimate(self) -> float:
        """1 / median(diff t) [Hz] (nan for fewer than 2 rows)."""
        return 1.0 / float(np.median(np.diff(self.t))) if self.t.size >= 2 else math.nan

    def source(self, which: Literal["yaml", "csv"]) -> str:
        """Where this recording's metadata (``"yaml"``) or time series (``"csv"``) lives, for messages."""
        if self.path is None:
            label = f"recording {self.name!r}" if self.name else "recording"
            return f"<unsaved {label}> {YAML_NAME if which == 'yaml' else CSV_NAME}"
        return str(self.path / (YAML_NAME if which == "yaml" else CSV_NAME))
