"""Force calibration: the divider, the fit from known weights and its intervals, the versioned file."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from diffstir.hardware import (
    Calibration, CalibrationPoint, Divider, SerialADC, fit_calibration, load_calibration, measure_point,
)
from diffstir.hardware.emulators import nominal_calibration

DIVIDER = Divider(supply_voltage=3.3, reference_resistance=10e3, volts_per_count=125e-6)
TRUE = Calibration(DIVIDER, slope=5e4, intercept=0.1)
MASSES = np.array([0.0, 0.02, 0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0])  # kg


def _points(rng, noise=3.0, creep=6.0, samples=200) -> list[CalibrationPoint]:
    """Readings of known masses: white noise per reading plus a per-point offset (creep, placement)."""
    points = []
    for m in MASSES:
        raw = np.round(TRUE.counts(m * 9.81) + rng.normal(0, creep) + rng.normal(0, noise, samples))
        points.append(CalibrationPoint(float(m), float(raw.mean()), float(raw.std(ddof=1)), samples))
    return points


def test_divider_round_trip_and_saturation():
    g = np.array([0.0, 1e-6, 1e-4, 1e-3])  # S
    assert DIVIDER.conductance(DIVIDER.counts(g)) == pytest.approx(g, rel=1e-12, abs=1e-18)
    full = DIVIDER.supply_voltage / DIVIDER.volts_per_count
    assert np.isnan(DIVIDER.conductance(full)) and np.isnan(TRUE.force(full + 10))


def test_fit_recovers_coefficients_within_their_intervals():
    cal = fit_calibration(_points(np.random.default_rng(1)), DIVIDER, sensor_serial="RP-C18.3-ST #7")
    ci = cal.confidence_intervals(0.95)
    assert ci["slope"][0] < TRUE.slope < ci["slope"][1]
    assert ci["intercept"][0] < TRUE.intercept < ci["intercept"][1]
    assert cal.dof == len(MASSES) - 2 and 0 < cal.residual_rms < 0.02
    assert cal.force(TRUE.counts(2.0)) == pytest.approx(2.0, abs=3 * cal.residual_rms)


def test_interval_coverage_is_nominal():
    rng = np.random.default_rng(2)
    hits = np.zeros(2)
    trials = 300
    for _ in range(trials):
        ci = fit_calibration(_points(rng, samples=50), DIVIDER, sensor_serial="x").confidence_intervals(0.9)
        hits += [ci["slope"][0] < TRUE.slope < ci["slope"][1], ci["intercept"][0] < TRUE.intercept < ci["intercept"][1]]
    coverage = hits / trials
    assert np.all(np.abs(coverage - 0.9) < 4 * np.sqrt(0.9 * 0.1 / trials)), coverage


def test_fit_needs_three_points():
    with pytest.raises(ValueError, match="need at least 3 masses"):
        fit_calibration(_points(np.random.default_rng(0))[:2], DIVIDER, sensor_serial="x")


def test_file_round_trip_and_no_overwrite(tmp_path):
    cal = fit_calibration(_points(np.random.default_rng(3)), DIVIDER, sensor_serial="RP-C18.3-ST #7",
                          date="2024-05-01")
    path = cal.save(tmp_path / "cal.yaml")
    assert load_calibration(path) == cal
    text = yaml.safe_load(path.read_text())
    assert (text["format"], text["version"], text["sensor_serial"]) == ("diffstir-force-calibration", 1,
                                                                        "RP-C18.3-ST #7")
    with pytest.raises(FileExistsError, match="never overwritten"):
        cal.save(path)


def test_load_checks_format_and_version(tmp_path):
    data = nominal_calibration().to_dict()
    newer = tmp_path / "newer.yaml"
    newer.write_text(yaml.safe_dump({**data, "version": 2}))
    with pytest.raises(ValueError, match=r"newer.yaml: calibration file version 2; this diffstir reads version 1"):
        load_calibration(newer)
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump({**data, "format": "diffstir-recording/1"}))
    with pytest.raises(ValueError, match="not a force calibration file"):
        load_calibration(other)
    broken = tmp_path / "broken.yaml"
    broken.write_text(yaml.safe_dump({k: v for k, v in data.items() if k != "slope"}))
    with pytest.raises(ValueError, match="'slope'"):
        load_calibration(broken)


@pytest.mark.timeout(10)
def test_measure_point_on_the_emulator(adc_emulator):
    truth = nominal_calibration()
    emulator = adc_emulator(sample_rate=500, force=lambda t: 0.2 * 9.81, noise=2.0)
    with SerialADC(emulator.port) as adc:
        point = measure_point(adc, 0.2, duration=0.3)
    assert point.mass == 0.2 and point.samples > 100
    assert point.counts == pytest.approx(float(truth.counts(0.2 * 9.81)), abs=1.0)
    assert point.counts_std == pytest.approx(2.0, rel=0.3)
