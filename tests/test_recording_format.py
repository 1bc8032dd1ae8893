"""Reading and writing recordings: every field and column of diffstir-recording/1 survives a round trip."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import yaml

from diffstir.recording import (
    CupGeometry, DensityMeasurement, Recording, RecordingError, RecordingWarning, RodGeometry, SensorSpec,
    load_recording, save_recording,
)

CUP = CupGeometry(radius=0.0425, fill_height=0.130)
ROD = RodGeometry(radius=0.0125, immersion_depth=0.080)


def stir(sensor: SensorSpec, *, rate: float = 200.0, duration: float = 3.0, **kwargs) -> Recording:
    """A rod circling 15 mm off the cup axis at 1 Hz; force positive, so every sensor mode accepts it."""
    t = np.arange(0.0, duration + 0.5 / rate, 1.0 / rate)
    phase = 2 * math.pi * t
    kwargs.setdefault("cup", CUP)
    kwargs.setdefault("rod", ROD)
    kwargs.setdefault("density", None)
    return Recording(sensor=sensor, t=t, x=0.015 * np.cos(phase), y=0.015 * np.sin(phase),
                     force=0.03 + 0.01 * np.sin(phase), **kwargs)


def load_quietly(path):
    """load_recording, failing the test on any warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return load_recording(path)


SENSORS = [
    SensorSpec("component", axis=(0.6, 0.8), resolution=0.005, sample_rate=200.0, time_constant=0.02),
    SensorSpec("tangential"),
    SensorSpec("magnitude", one_sided=True, resolution=0.01),
]
DENSITIES = [
    None,
    DensityMeasurement(rod_weight=0.6, immersed_reading=0.215, immersed_depth=0.080),
    DensityMeasurement(rod_weight=0.6, immersed_reading=0.215, immersed_depth=0.080, rod_cross_section=4.909e-4),
]
CUPS = [CupGeometry(0.0425, fill_height=0.130), CupGeometry(0.0425, fill_volume=7.38e-4),
        CupGeometry(0.0425, fill_height=0.130, fill_volume=7.38e-4)]


@pytest.mark.parametrize("sensor", SENSORS, ids=lambda s: s.mode)
@pytest.mark.parametrize("density", DENSITIES, ids=["no-density", "density", "density+A"])
@pytest.mark.parametrize("cup", CUPS, ids=["fill_height", "fill_volume", "both"])
def test_every_field_round_trips(tmp_path, sensor, density, cup):
    rec = stir(sensor, cup=cup, density=density, name="castor-oil-run-3", fluid="castor oil", temperature=22.5)
    n = rec.t.size
    rec.z = np.linspace(0.0, 1e-3, n)
    rec.force_x = np.cos(np.arange(n)) * 0.02
    rec.force_y = np.sin(np.arange(n)) * 0.02
    rec.raw = np.arange(n, dtype=float) * 7

    back = load_quietly(save_recording(rec, tmp_path / "rec"))

    for field in ("cup", "rod", "sensor", "density", "name", "fluid", "temperature", "complete", "partial_reason"):
        assert getattr(back, field) == getattr(rec, field), field
    for column in ("t", "x", "y", "force", "z", "force_x", "force_y", "raw"):
        np.testing.assert_array_equal(getattr(back, column), getattr(rec, column), err_msg=column)
        assert getattr(back, column).dtype == np.float64
    assert back.path == tmp_path / "rec"
    assert back.extra_meta == {} and back.extra_columns == {}


def test_optional_columns_absent_stay_none(tmp_path):
    back = load_quietly(save_recording(stir(SensorSpec("tangential")), tmp_path / "rec"))
    assert back.z is None and back.force_x is None and back.force_y is None and back.raw is None
    assert back.name is None and back.fluid is None and back.temperature is None and back.density is None


def test_fill_volume_resolves_to_height():
    assert CupGeometry(0.0425, fill_volume=7.38e-4).resolved_fill_height() == pytest.approx(
        7.38e-4 / (math.pi * 0.0425**2), rel=1e-15)
    assert CupGeometry(0.0425, fill_height=0.1, fill_volume=7.38e-4).resolved_fill_height() == 0.1


def test_the_spec_example_yaml_reads_verbatim(tmp_path):
    (tmp_path / "recording.yaml").write_text("""\
format: diffstir-recording/1      # required, exactly this string
name: castor-oil-run-3            # optional, free text
fluid: castor oil                 # optional label; never holds the ground-truth parameters
temperature: 22.5                 # optional, degrees Celsius
rig:
  cup:
    radius: 0.0425                # required, m, inner radius of the cylindrical cup
    fill_height: 0.130            # m, depth of the fluid at rest (give this or fill_volume)
    fill_volume: 7.38e-4          # m^3, alternative to fill_height
  rod:
    radius: 0.0125                # required, m, the rod is a vertical cylinder
    immersion_depth: 0.080        # required, m, depth of the rod's tip below the free surface at rest
sensor:
  mode: tangential                # required: component | tangential | magnitude
  axis: [1.0, 0.0]                # required when mode is component: horizontal unit vector, cup frame
  one_sided: false                # optional, default false
  resolution: 0.005               # optional, N: smallest force step the sensor resolves
  sample_rate: 200                # optional, Hz, nominal
density:                          # optional: Archimedes measurement with the same rod
  rod_weight: 0.0302              # N, G: the rod's weight held vertical in air
  immersed_reading: 0.0105        # N, R
  immersed_depth: 0.080           # m, h
  rod_cross_section: 4.909e-4     # m^2, optional, default pi * rod.radius^2
""")
    (tmp_path / "stir.csv").write_text("t,x,y,force\n0.000,0.0300,0.0000,0.0000\n0.005,0.0300,0.0003,0.0011\n"
                                       "0.010,0.0300,0.0006,0.0023\n")
    rec = load_recording(tmp_path, validate=False)
    assert rec.cup == CupGeometry(0.0425, 0.130, 7.38e-4)
    assert rec.rod == RodGeometry(0.0125, 0.080)
    assert rec.sensor == SensorSpec("tangential", (1.0, 0.0), False, 0.005, 200.0)
    assert rec.density == DensityMeasurement(0.0302, 0.0105, 0.080, 4.909e-4)
    assert (rec.name, rec.fluid, rec.temperature, rec.complete) == ("castor-oil-run-3", "castor oil", 22.5, True)
    np.testing.assert_array_equal(rec.y, [0.0, 0.0003, 0.0006])


def test_unknown_fields_and_columns_are_kept_with_a_warning_and_saved_again(tmp_path):
    src = save_recording(stir(SensorSpec("tangential")), tmp_path / "new")
    meta = yaml.safe_load((src / "recording.yaml").read_text())
    meta["operator"] = "bob"
    meta["rig"]["cup"]["material"] = "PET"
    meta["sensor"]["calibration"] = {"gain": 1.02, "date": "2024-05-01"}
    (src / "recording.yaml").write_text(yaml.safe_dump(meta))
    lines = (src / "stir.csv").read_text().splitlines()
    header = [i for i, line in enumerate(lines) if not line.startswith("#")][0]
    lines[header] += ",phase,torque_z"
    for i in range(header + 1, len(lines)):
        lines[i] += f",{'stir' if (i - header) % 2 else 'rest'},{i * 0.001}"
    (src / "stir.csv").write_text("\n".join(lines) + "\n")

    with pytest.warns(RecordingWarning) as caught:
        rec = load_recording(src)
    messages = " ".join(str(w.message) for w in caught)
    for name in ("operator", "rig.cup.material", "sensor.calibration", "phase", "torque_z"):
        assert name in messages
    assert rec.extra_meta == {"operator": "bob", "rig": {"cup": {"material": "PET"}},
                              "sensor": {"calibration": {"gain": 1.02, "date": "2024-05-01"}}}
    assert rec.extra_columns["phase"][:2].tolist() == ["stir", "rest"]
    assert rec.extra_columns["torque_z"].dtype == np.float64

    with pytest.warns(RecordingWarning):
        again = load_recording(save_recording(rec, tmp_path / "copy"))
    assert again.extra_meta == rec.extra_meta
    for name, values in rec.extra_columns.items():
        np.testing.assert_array_equal(again.extra_columns[name], values)


def test_extra_fields_for_a_missing_section_are_refused(tmp_path):
    rec = stir(SensorSpec("tangential"), extra_meta={"density": {"thermometer": "PT100"}})
    with pytest.raises(RecordingError, match="extra_meta holds fields under 'density'"):
        save_recording(rec, tmp_path / "rec")
    assert not (tmp_path / "rec").exists()


def test_columns_of_the_wrong_shape_are_refused(tmp_path):
    rec = stir(SensorSpec("tangential"))
    rec.force = np.stack([rec.force, rec.force], -1)
    with pytest.raises(RecordingError, match=r"column 'force' has shape \(601, 2\); every column must be 1-D"):
        save_recording(rec, tmp_path / "rec")


def test_comments_blank_lines_and_any_column_order(tmp_path):
    ref = stir(SensorSpec("tangential"))
    path = save_recording(ref, tmp_path / "rec")
    rows = ["# written by hand", "force , y,t,x", "  # a comment with leading blanks", ""]
    for i, (t, x, y, f) in enumerate(zip(ref.t, ref.x, ref.y, ref.force)):
        rows.append(f"{float(f)!r},{float(y)!r}, {float(t)!r},{float(x)!r}")
        if i == 10:
            rows += ["# the robot paused here", ""]
    (path / "stir.csv").write_text("\n".join(rows) + "\n# trailing comment\n")
    rec = load_quietly(path)
    for column in ("t", "x", "y", "force"):
        np.testing.assert_array_equal(getattr(rec, column), getattr(ref, column))


def test_numbers_yaml_reads_as_text_are_parsed(tmp_path):
    path = save_recording(stir(SensorSpec("tangential")), tmp_path / "rec")
    text = (path / "recording.yaml").read_text().replace("immersion_depth: 0.08", "immersion_depth: 8e-2")
    (path / "recording.yaml").write_text(text)
    assert yaml.safe_load(text)["rig"]["rod"]["immersion_depth"] == "8e-2"  # YAML 1.1 needs a dot for a float
    assert load_quietly(path).rod.immersion_depth == 0.08


def test_load_accepts_the_yaml_or_csv_path(tmp_path):
    path = save_recording(stir(SensorSpec("tangential")), tmp_path / "rec")
    assert load_quietly(path / "recording.yaml").t.size == load_quietly(path / "stir.csv").t.size == 601


def test_save_never_overwrites_unless_asked_and_only_a_recording(tmp_path):
    first, second = stir(SensorSpec("tangential")), stir(SensorSpec("magnitude"))
    path = save_recording(first, tmp_path / "rec")
    before = {p.name: p.read_bytes() for p in path.iterdir()}
    with pytest.raises(FileExistsError, match="overwrite"):
        save_recording(second, path)
    assert {p.name: p.read_bytes() for p in path.iterdir()} == before

    save_recording(second, path, overwrite=True)
    assert load_quietly(path).sensor.mode == "magnitude"

    other = tmp_path / "notes"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="not a recording"):
        save_recording(first, other, overwrite=True)
    assert (other / "keep.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes", "rec"]  # no temporary directories left


def test_velocity_is_exact_on_quadratics_with_uneven_steps():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.002, 0.008, 200))
    rec = stir(SensorSpec("tangential"))
    rec.t, rec.x, rec.y, rec.force = t, 0.01 + 0.02 * t - 0.003 * t**2, -0.004 * t, np.zeros_like(t)
    v = rec.velocity()
    # exact up to rounding, eps |x| / dt ~ 1e-14 m/s
    np.testing.assert_allclose(v[1:-1, 0], 0.02 - 0.006 * t[1:-1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(v[:, 1], -0.004, rtol=0, atol=1e-12)  # rounding: eps * |x| / dt ~ 1e-14 m/s
    assert rec.duration == pytest.approx(t[-1] - t[0])
    assert 1 / 0.008 < rec.sample_rate_estimate < 1 / 0.002
