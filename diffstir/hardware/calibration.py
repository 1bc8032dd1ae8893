"""Force calibration of a thin-film resistive sensor (RP-C18.3-ST) read through a voltage divider and an ADC.

Circuit: Vcc -- sensor R_s -- node -- R_ref -- GND; the ADC reads the node, so

    V = counts * volts_per_count,    V = Vcc R_ref / (R_s + R_ref),    G = 1 / R_s = V / (R_ref (Vcc - V)).

Sensor law: a force-sensing resistor's conductance is roughly proportional to the force, so F = a G + b
(a [N/S], b [N]).

Fit: known masses m_i loaded on the sensor give F_i = m_i g exactly, while G_i is measured with noise, so the
line is fitted the classical calibration way: G = c F + d by least squares (weights 1 / s_G,i^2 when each
point's spread is known, the covariance scaled by the reduced chi-square), then inverted, a = 1/c, b = -d/c,
with the covariance of (a, b) by first-order error propagation. Intervals use Student's t with n - 2 degrees
of freedom.

The calibration file is YAML: ``format: diffstir-force-calibration``, ``version: 1``, sensor serial, date,
divider, coefficients with covariance, residual and the points themselves.
"""

from __future__ import annotations

import datetime
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import yaml
from scipy import stats

from diffstir.hardware.adc import ADC

FORMAT = "diffstir-force-calibration"
VERSION = 1
GRAVITY = 9.81  # m/s^2, as in the recording format


@dataclass(frozen=True)
class Divider:
    """The read-out circuit: ``supply_voltage`` Vcc [V], ``reference_resistance`` R_ref [ohm] between the ADC
    input and ground, ADC scale ``volts_per_count`` [V] (ADS1115 at +-4.096 V: 125e-6)."""

    supply_voltage: float
    reference_resistance: float
    volts_per_count: float

    def conductance(self, counts) -> np.ndarray:
        """Sensor conductance G [S] = V / (R_ref (Vcc - V)); NaN where V >= Vcc (the divider saturates)."""
        v = np.asarray(counts, dtype=np.float64) * self.volts_per_count
        with np.errstate(divide="ignore", invalid="ignore"):
            g = v / (self.reference_resistance * (self.supply_voltage - v))
        return np.where(v < self.supply_voltage, g, np.nan)

    def counts(self, conductance) -> np.ndarray:
        """The reading [counts, not rounded] for a sensor conductance [S]: V = Vcc R_ref G / (1 + R_ref G)."""
        rg = self.reference_resistance * np.asarray(conductance, dtype=np.float64)
        return self.supply_voltage * rg / (1.0 + rg) / self.volts_per_count


@dataclass(frozen=True)
class CalibrationPoint:
    """A known ``mass`` [kg] resting on the sensor, the mean reading ``counts``, its standard deviation
    ``counts_std`` (None if unknown) over ``samples`` readings."""

    mass: float
    counts: float
    counts_std: float | None = None
    samples: int = 1


@dataclass(frozen=True)
class Calibration:
    """F = slope G + intercept, with G from ``divider``.

    Attributes:
        divider: the read-out circuit.
        slope: a [N/S].
        intercept: b [N].
        covariance: 2x2 covariance of (slope, intercept) [N²/S², N²/S; N²/S, N²].
        dof: degrees of freedom of the fit (points - 2); 0 for a nominal calibration.
        residual_rms: root mean square of F_i - (a G_i + b) over the points [N].
        points: the measurements the fit used.
        sensor_serial: the sensor this calibration belongs to.
        date: ISO 8601 date of the measurement.
        gravity: g used for F = m g [m/s²].
    """

    divider: Divider
    slope: float
    intercept: float
    covariance: tuple[tuple[float, float], tuple[float, float]] = ((0.0, 0.0), (0.0, 0.0))
    dof: int = 0
    residual_rms: float = 0.0
    points: tuple[CalibrationPoint, ...] = ()
    sensor_serial: str = "unknown"
    date: str = field(default_factory=lambda: datetime.date.today().isoformat())
    gravity: float = GRAVITY

    def force(self, counts) -> np.ndarray:
        """Force [N] for readings [counts]: a G(counts) + b; NaN where the divider saturates."""
        return self.slope * self.divider.conductance(counts) + self.intercept

    def counts(self, force) -> np.ndarray:
        """The reading [counts, not rounded] that ``force`` [N] produces: the inverse of ``force``."""
        return self.divider.counts((np.asarray(force, dtype=np.float64) - self.intercept) / self.slope)

    @property
    def stderr(self) -> tuple[float, float]:
        """Standard errors of (slope [N/S], intercept [N])."""
        return math.sqrt(self.covariance[0][0]), math.sqrt(self.covariance[1][1])

    def confidence_intervals(self, level: float = 0.95) -> dict[str, tuple[float, float]]:
        """Two-sided intervals of slope and intercept at ``level``, Student's t with ``dof`` degrees of freedom."""
        if self.dof < 1:
            raise ValueError(f"calibration of sensor {self.sensor_serial!r} has no residual degrees of freedom "
                             "(fewer than 3 points or a nominal calibration); no interval")
        k = stats.t.ppf(0.5 + level / 2, self.dof)
        (sa, sb) = self.stderr
        return {"slope": (self.slope - k * sa, self.slope + k * sa),
                "intercept": (self.intercept - k * sb, self.intercept + k * sb)}

    def to_dict(self) -> dict:
        """The calibration file's content."""
        return {
            "format": FORMAT, "version": VERSION, "sensor_serial": self.sensor_serial, "date": self.date,
            "model": "F = slope * G + intercept; G = V / (R_ref (Vcc - V)); V = counts * volts_per_count",
            "gravity": self.gravity, "divider": asdict(self.divider), "slope": self.slope,
            "intercept": self.intercept, "covariance": [list(map(float, row)) for row in self.covariance],
            "dof": self.dof, "residual_rms": self.residual_rms, "points": [asdict(p) for p in self.points],
        }

    def save(self, path: str | os.PathLike) -> Path:
        """Write the calibration file; refuses to overwrite an existing file."""
        path = Path(path)
        if path.exists():
            raise FileExistsError(f"calibration file {path} exists; choose a new name (calibrations are never "
                                  "overwritten)")
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(yaml.safe_dump(self.to_dict(), sort_keys=False))
        os.replace(tmp, path)
        return path


def load_calibration(path: str | os.PathLike) -> Calibration:
    """Read a calibration file, checking its format and version."""
    path = Path(path)
    data = yaml.safe_load(path.read_text())
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        got = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise ValueError(f"{path}: not a force calibration file: format is {got!r}, expected {FORMAT!r}")
    if data.get("version") != VERSION:
        raise ValueError(f"{path}: calibration file version {data.get('version')!r}; this diffstir reads "
                         f"version {VERSION} (a newer file needs a newer diffstir)")
    try:
        return Calibration(
            divider=Divider(**data["divider"]), slope=float(data["slope"]), intercept=float(data["intercept"]),
            covariance=tuple(tuple(float(v) for v in row) for row in data["covariance"]),
            dof=int(data["dof"]), residual_rms=float(data["residual_rms"]),
            points=tuple(CalibrationPoint(**p) for p in data["points"]), sensor_serial=str(data["sensor_serial"]),
            date=str(data["date"]), gravity=float(data["gravity"]))
    except (KeyError, TypeError) as exc:
        raise ValueError(f"{path}: calibration file version {VERSION} is missing or has a malformed field: "
                         f"{exc}") from exc


def fit_calibration(points, divider: Divider, *, sensor_serial: str, date: str | None = None,
                    gravity: float = GRAVITY) -> Calibration:
    """Fit F = a G + b to known masses (see the module docstring for the method); needs 3 points or more."""
    points = tuple(points)
    if len(points) < 3:
        raise ValueError(f"calibration of sensor {sensor_serial!r}: {len(points)} points; need at least 3 masses "
                         "(including zero) to fit a line and estimate its uncertainty")
    f = np.array([p.mass for p in points]) * gravity
    g = divider.conductance([p.counts for p in points])
    if not np.all(np.isfinite(g)):
        raise ValueError(f"calibration of sensor {sensor_serial!r}: a reading saturates the divider "
                         f"(V >= Vcc = {divider.supply_voltage} V); use a larger reference resistor")
    if all(p.counts_std is not None for p in points):
        # s_G = dG/dcounts * s_counts / sqrt(samples), dG/dV = Vcc / (R_ref (Vcc - V)^2); quantisation adds 1/12
        v = np.array([p.counts for p in points]) * divider.volts_per_count
        dg_dcounts = divider.volts_per_count * divider.supply_voltage / (
            divider.reference_resistance * (divider.supply_voltage - v) ** 2)
        sigma = dg_dcounts * np.array([math.sqrt((p.counts_std**2 + 1 / 12) / p.samples) for p in points])
    else:
        sigma = np.ones_like(g)
    x = np.stack([f, np.ones_like(f)], axis=1) / sigma[:, None]
    (c, d), *_ = np.linalg.lstsq(x, g / sigma, rcond=None)
    dof = len(points) - 2
    chi2 = float(np.sum(((g - (c * f + d)) / sigma) ** 2))
    cov_cd = np.linalg.inv(x.T @ x) * chi2 / dof
    jac = np.array([[-1.0 / c**2, 0.0], [d / c**2, -1.0 / c]])
    cov_ab = jac @ cov_cd @ jac.T
    a, b = 1.0 / c, -d / c
    residual = float(np.sqrt(np.mean((f - (a * g + b)) ** 2)))
    return Calibration(divider, float(a), float(b), tuple(map(tuple, cov_ab.tolist())), dof, residual, points,
                       sensor_serial, date or datetime.date.today().isoformat(), gravity)


def measure_point(adc: ADC, mass: float, *, duration: float = 2.0) -> CalibrationPoint:
    """Stream ``duration`` [s] from ``adc`` with ``mass`` [kg] resting on the sensor; mean and spread."""
    adc.start()
    try:
        counts = []
        end = time.monotonic() + duration
        while time.monotonic() < end:
            counts.append(adc.read().counts)
    finally:
        adc.stop()
    return CalibrationPoint(mass, float(np.mean(counts)), float(np.std(counts, ddof=1)) if len(counts) > 1
                            else None, len(counts))
