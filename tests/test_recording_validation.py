"""Validation: each error names the file, the field or column, the value and the unit; warnings do not raise."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from diffstir.recording import (
    CupGeometry, DensityMeasurement, Recording, RecordingError, RecordingWarning, RodGeometry, SensorSpec,
    load_recording, save_recording, stirring_frequency, validate_recording,
)


def stir(*, rate=200.0, duration=3.0, freq=1.0, radius=0.015, sensor=SensorSpec("tangential"), **kwargs):
    """A rod circling ``radius`` [m] off the cup axis at ``freq`` [Hz]: valid unless the arguments make it not."""
    t = np.arange(0.0, duration + 0.5 / rate, 1.0 / rate)
    phase = 2 * math.pi * freq * t
    kwargs.setdefault("cup", CupGeometry(0.0425, fill_height=0.130))
    kwargs.setdefault("rod", RodGeometry(0.0125, 0.080))
    kwargs.setdefault("density", None)
    return Recording(sensor=sensor, t=t, x=radius * np.cos(phase), y=radius * np.sin(phase),
                     force=0.03 + 0.01 * np.sin(phase), **kwargs)


def write(tmp_path: Path, rec: Recording) -> Path:
    """Save ``rec`` without validating it (save_recording checks only shapes)."""
    return save_recording(rec, tmp_path / "rec")


def edit_yaml(path: Path, change) -> Path:
    meta = yaml.safe_load((path / "recording.yaml").read_text())
    change(meta)
    (path / "recording.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    return path


def edit_cell(path: Path, column: str, row: int, text: str) -> Path:
    """Replace the cell of ``column`` in data row ``row`` (from 1) of stir.csv by ``text``."""
    lines = (path / "stir.csv").read_text().splitlines()
    data = [i for i, line in enumerate(lines) if not line.startswith("#")]
    header = lines[data[0]].split(",")
    cells = lines[data[row]].split(",")
    cells[header.index(column)] = text
    lines[data[row]] = ",".join(cells)
    (path / "stir.csv").write_text("\n".join(lines) + "\n")
    return path


def drop_column(path: Path, column: str) -> Path:
    lines = (path / "stir.csv").read_text().splitlines()
    rows = [line.split(",") for line in lines if not line.startswith("#")]
    k = rows[0].index(column)
    (path / "stir.csv").write_text("\n".join(",".join(r[:k] + r[k + 1:]) for r in rows) + "\n")
    return path


def load_error(path: Path, file: str, *fragments: str) -> str:
    """Load ``path``, expecting a RecordingError whose message names ``file`` of the recording and ``fragments``."""
    with pytest.raises(RecordingError) as info:
        load_recording(path)
    message = str(info.value)
    assert str(path / file) in message, message
    for fragment in fragments:
        assert fragment in message, f"{fragment!r} not in {message!r}"
    return message


# -- recording.yaml ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("value", [None, "diffstir-recording/2", "diffstir-recording/1.0"])
def test_format_must_be_exactly_version_1(tmp_path, value):
    path = edit_yaml(write(tmp_path, stir()), lambda m: m.update(format=value) if value else m.pop("format"))
    load_error(path, "recording.yaml", "'format'", "diffstir-recording/1")


@pytest.mark.parametrize("field", ["rig.cup.radius", "rig.rod.radius", "rig.rod.immersion_depth", "sensor.mode",
                                   "density.rod_weight", "density.immersed_depth", "rig", "sensor"])
def test_missing_required_field(tmp_path, field):
    rec = stir(density=DensityMeasurement(0.6, 0.215, 0.08))
    *parents, key = field.split(".")

    def drop(meta):
        for parent in parents:
            meta = meta[parent]
        del meta[key]

    load_error(edit_yaml(write(tmp_path, rec), drop), "recording.yaml", f"'{field}'", "missing")


def test_missing_fill_height_and_volume(tmp_path):
    path = edit_yaml(write(tmp_path, stir()), lambda m: m["rig"]["cup"].pop("fill_height"))
    load_error(path, "recording.yaml", "'rig.cup.fill_height'", "'rig.cup.fill_volume'", "missing")


def test_field_with_a_unit_is_not_a_number(tmp_path):
    path = edit_yaml(write(tmp_path, stir()), lambda m: m["rig"]["rod"].update(radius="12.5 mm"))
    load_error(path, "recording.yaml", "'rig.rod.radius'", "'12.5 mm'", "m")


@pytest.mark.parametrize("field, value", [("rig.cup.radius", 42.5), ("rig.rod.radius", 12.5),
                                          ("rig.cup.fill_height", 130.0), ("rig.rod.immersion_depth", 80.0)])
def test_lengths_that_look_like_millimetres(tmp_path, field, value):
    rec = stir()
    section, part, key = field.split(".")
    path = edit_yaml(write(tmp_path, rec), lambda m: m[section][part].update({key: value}))
    load_error(path, "recording.yaml", f"'{field}' = {value}", "looks like millimetres", "metres (m)")


def test_rod_wider_than_cup_looks_like_millimetres(tmp_path):
    path = edit_yaml(write(tmp_path, stir()), lambda m: m["rig"]["rod"].update(radius=0.05))
    load_error(path, "recording.yaml", "'rig.rod.radius' = 0.05", "'rig.cup.radius' = 0.0425",
               "looks like millimetres")


def test_fill_volume_in_millilitres(tmp_path):
    path = edit_yaml(write(tmp_path, stir(cup=CupGeometry(0.0425, fill_volume=7.38e-4))),
                     lambda m: m["rig"]["cup"].update(fill_volume=738.0))
    load_error(path, "recording.yaml", "'rig.cup.fill_volume' = 738.0", "millilitres", "m^3")


def test_immersion_depth_reaching_the_bottom(tmp_path):
    path = edit_yaml(write(tmp_path, stir()), lambda m: m["rig"]["rod"].update(immersion_depth=0.13))
    load_error(path, "recording.yaml", "'rig.rod.immersion_depth' = 0.13", "fill height 0.13", "bottom")


@pytest.mark.parametrize("sensor, fragments", [
    ({"mode": "tangental"}, ["'sensor.mode' = 'tangental'", "component, tangential, magnitude"]),
    ({"mode": "component"}, ["'sensor.axis' is missing", "unit vector"]),
    ({"mode": "component", "axis": [1.0, 1.0]}, ["'sensor.axis' = [1.0, 1.0]", "length 1.41421", "unit vector"]),
    ({"mode": "component", "axis": [1.0]}, ["'sensor.axis' = [1.0]", "two numbers"]),
    ({"mode": "tangential", "one_sided": "yes"}, ["'sensor.one_sided' = 'yes'", "true or false"]),
    ({"mode": "tangential", "resolution": -0.005}, ["'sensor.resolution' = -0.005", "N"]),
    ({"mode": "tangential", "time_constant": -0.02}, ["'sensor.time_constant' = -0.02", "response time", "in s"]),
    ({"mode": "tangential", "time_constant": "20 ms"}, ["'sensor.time_constant'", "20 ms", "s"]),
])
def test_bad_sensor(tmp_path, sensor, fragments):
    path = edit_yaml(write(tmp_path, stir()), lambda m: m.update(sensor=sensor))
    load_error(path, "recording.yaml", *fragments)


def test_density_reading_not_below_weight(tmp_path):
    path = write(tmp_path, stir(density=DensityMeasurement(0.2, 0.25, 0.08)))
    load_error(path, "recording.yaml", "'density.immersed_reading' = 0.25 N", "'density.rod_weight' = 0.2 N")


def test_yaml_syntax_error(tmp_path):
    path = write(tmp_path, stir())
    (path / "recording.yaml").write_text("format: [diffstir-recording/1\n")
    load_error(path, "recording.yaml", "not valid YAML")


# -- stir.csv ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("column", ["t", "x", "y", "force"])
def test_missing_required_column(tmp_path, column):
    load_error(drop_column(write(tmp_path, stir()), column), "stir.csv", f"'{column}'", "missing")


def test_time_not_increasing(tmp_path):
    path = edit_cell(write(tmp_path, stir()), "t", 101, "0.495")
    load_error(path, "stir.csv", "column 't' = 0.495 s at data row 101", "0.495 s at data row 100",
               "strictly increasing")


@pytest.mark.parametrize("column, value", [("t", "nan"), ("x", "nan"), ("y", "inf"), ("force", "-inf"),
                                           ("z", "nan"), ("force_x", "inf")])
def test_non_finite_value(tmp_path, column, value):
    rec = stir()
    rec.z, rec.force_x = np.zeros_like(rec.t), np.zeros_like(rec.t)
    path = edit_cell(write(tmp_path, rec), column, 42, value)
    where = "data row 42" if column == "t" else "data row 42 (t = 0.205 s)"
    load_error(path, "stir.csv", f"column '{column}' = {float(value)} at {where}", "finite")


def test_value_that_is_not_a_number(tmp_path):
    path = edit_cell(write(tmp_path, stir()), "force", 7, "0.03N")
    load_error(path, "stir.csv", "line 9", "column 'force' = '0.03N'", "expected N")  # 1 comment + header


def test_row_with_missing_values(tmp_path):
    path = write(tmp_path, stir())
    lines = (path / "stir.csv").read_text().split("\n")
    lines[8] = "0.035,0.015,0.001"
    (path / "stir.csv").write_text("\n".join(lines))
    load_error(path, "stir.csv", "line 9", "3 values for the 4 columns")


def test_rod_touching_the_wall(tmp_path):
    path = write(tmp_path, stir(radius=0.0305))  # 0.0305 + 0.0125 = 0.043 m > 0.0425 m
    load_error(path, "stir.csv", "columns 'x', 'y'", "data row 1 (t = 0 s)", "touches", "cup radius 0.0425 m")


def test_rod_touching_the_wall_at_a_later_time(tmp_path):
    rec = stir()
    rec.x = rec.x + np.where(rec.t > 1.0, 0.02, 0.0)
    message = load_error(write(tmp_path, rec), "stir.csv", "columns 'x', 'y'", "touches")
    assert "data row 202 (t = 1.005 s)" in message


def test_positions_in_millimetres(tmp_path):
    rec = stir()
    rec.x, rec.y = rec.x * 1000, rec.y * 1000
    load_error(write(tmp_path, rec), "stir.csv", "column 'x' = 15.0", "looks like millimetres", "metres (m)")


def test_rod_tip_reaching_the_bottom_through_z(tmp_path):
    rec = stir()
    rec.z = np.where(rec.t > 2.0, -0.06, 0.0)
    load_error(write(tmp_path, rec), "stir.csv", "column 'z' = -0.06 m", "t = 2.005 s", "bottom")


def test_sample_rate_too_low_for_the_stir(tmp_path):
    path = write(tmp_path, stir(rate=15.0, freq=2.0, duration=3.0))  # 7.5 samples per period
    message = load_error(path, "stir.csv", "column 't'", "15 Hz", "samples per stirring period", "at least 10")
    # measuring the path along chords under-estimates f by sin(pi / 7.5) / (pi / 7.5) = 0.971
    assert float(message.split(" gives ")[1].split()[0]) == pytest.approx(7.5 / 0.971, rel=0.01)


@pytest.mark.parametrize("duration, freq", [(0.3, 4.0), (0.8, 1.0)])
def test_too_short_to_fit(tmp_path, duration, freq):
    path = write(tmp_path, stir(duration=duration, freq=freq))
    load_error(path, "stir.csv", "column 't'", f"spans {duration:g} s", "too short")


def test_a_rod_that_does_not_stir_is_refused(tmp_path):
    """A 0.5 mm circle: the axis stays within 1 mm of its mean position, nothing to fit a viscosity to."""
    load_error(write(tmp_path, stir(radius=0.0005)), "stir.csv", "columns 'x', 'y'", "does not stir",
               "0.000501 m", "1 mm (in m)")


def test_several_problems_are_reported_together(tmp_path):
    rec = stir(cup=CupGeometry(42.5, fill_height=130.0), rod=RodGeometry(12.5, 80.0))
    message = load_error(write(tmp_path, rec), "recording.yaml", "4 problems")
    for field in ("rig.cup.radius", "rig.cup.fill_height", "rig.rod.radius", "rig.rod.immersion_depth"):
        assert field in message


def test_in_memory_recording_names_itself():
    rec = stir(cup=CupGeometry(42.5, fill_height=0.13), name="run-3")
    with pytest.raises(RecordingError, match=r"<unsaved recording 'run-3'> recording.yaml: field 'rig.cup.radius'"):
        validate_recording(rec)


# -- warnings, and partial recordings ---------------------------------------------------------------------------

def test_a_partial_recording_too_short_to_fit_still_loads(tmp_path):
    rec = stir(duration=0.2)
    rec.complete, rec.partial_reason = False, "KeyboardInterrupt()"
    with pytest.warns(RecordingWarning) as caught:
        back = load_recording(write(tmp_path, rec))
    messages = [str(w.message) for w in caught]
    assert any("PARTIAL recording" in m and "KeyboardInterrupt()" in m for m in messages)
    assert any("too short" in m and "partial recording: not raised" in m for m in messages)
    assert back.t.size == rec.t.size


@pytest.mark.parametrize("change, fragment", [
    (dict(cup=CupGeometry(0.0425, fill_height=0.10, fill_volume=7.38e-4)), "disagrees with 'rig.cup.fill_volume'"),
    (dict(sensor=SensorSpec("tangential", axis=(1.0, 0.0))), "'sensor.axis' = [1.0, 0.0] is ignored"),
    (dict(density=DensityMeasurement(0.0302, 0.0105, 0.080, 4.909e-4)), "rho = 51.13 kg/m^3"),  # the spec's example
    (dict(temperature=295.6), "'temperature' = 295.6 looks like kelvin"),
    (dict(sensor=SensorSpec("tangential", sample_rate=1000.0)), "'sensor.sample_rate' = 1000.0 Hz"),
])
def test_warnings(tmp_path, change, fragment):
    path = write(tmp_path, stir(**change))
    with pytest.warns(RecordingWarning, match=None) as caught:
        load_recording(path)
    assert any(fragment in str(w.message) for w in caught), [str(w.message) for w in caught]


def test_negative_reading_from_a_one_sided_sensor_warns(tmp_path):
    rec = stir(sensor=SensorSpec("tangential", one_sided=True))
    rec.force = rec.force - 0.035
    expected = r"column 'force' = -0.015.* N at data row 151 \(t = 0.75 s\) is negative although sensor.one_sided"
    with pytest.warns(RecordingWarning, match=expected):
        load_recording(write(tmp_path, rec))


def test_a_gap_in_the_samples_warns(tmp_path):
    rec = stir()
    keep = (rec.t < 1.0) | (rec.t > 1.4)
    rec.t, rec.x, rec.y, rec.force = rec.t[keep], rec.x[keep], rec.y[keep], rec.force[keep]
    with pytest.warns(RecordingWarning, match=r"column 't' jumps by 0.405 s after data row 200 \(t = 0.995 s\)"):
        load_recording(write(tmp_path, rec))


# -- the stirring frequency behind the sampling rule -----------------------------------------------------------

@pytest.mark.parametrize("shape", ["circle", "off-centre circle", "stroke"])
@pytest.mark.parametrize("periods, tolerance", [(5.0, 1e-4), (5.2, 0.03)])
def test_stirring_frequency(shape, periods, tolerance):
    """Exact (to the chord error (pi / 770)² / 6 at 1 kHz) over whole periods; a partial period biases the centre
    and the mean speed, by 1.4 % for the stroke at 5.2 periods."""
    t = np.linspace(0.0, periods / 1.3, int(1000 * periods / 1.3) + 1)
    phase = 2 * math.pi * 1.3 * t
    if shape == "stroke":
        x, y = 0.02 * np.sin(phase), np.zeros_like(t)
    else:
        x, y = 0.01 * np.cos(phase), 0.01 * np.sin(phase)
        if shape == "off-centre circle":
            x = x + 0.01
    assert stirring_frequency(t, x, y) == pytest.approx(1.3, rel=tolerance)


def test_a_still_rod_with_position_noise_does_not_stir():
    rng = np.random.default_rng(1)
    t = np.linspace(0.0, 2.0, 2001)
    assert stirring_frequency(t, 0.01 + 2e-5 * rng.standard_normal(t.size), 2e-5 * rng.standard_normal(t.size)) == 0
