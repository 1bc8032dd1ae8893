"""The DiffStir authors' recordings (data/traj.npy, data/force.npy, config/arguments.json) as diffstir recordings."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from diffstir.errors import ConfigError, OutputError
from diffstir.recording import RecordingError, load_recording
from diffstir.recording.diffstir_authors import ImportSettings, fit_circle, import_diffstir_authors

SCENE = {"container_diameter": 0.085, "liquid_height": 0.13, "operator_bottom_height": 0.05,
         "operator_radius": 0.0125, "liquid_density": 1050.0}
CENTRE = (0.31, -0.12)  # m: the cup's axis in the traj frame
RADIUS, OMEGA, RATE, JITTER = 0.015, 6.0, 1000.0, 20e-6  # m, rad/s, Hz, m
DURATION, DEAD = 1.2, 0.3  # s


def write_authors_folder(root: Path, *, vertical: int = 1, scene: dict | None = None, traj=None, force=None,
                         seed: int = 0) -> Path:
    """An authors' folder: a 1 kHz circle about CENTRE with JITTER per axis, the rod's tip level at 0.05 m in
    column ``vertical``, and a one-sided reading that is 0 for the first DEAD s, then 10 mN ± 1 mN."""
    rng = np.random.default_rng(seed)
    n = int(DURATION * RATE)
    t = np.arange(n) / RATE
    xy = np.stack([CENTRE[0] + RADIUS * np.cos(OMEGA * t), CENTRE[1] + RADIUS * np.sin(OMEGA * t)], axis=1)
    xy += rng.normal(0.0, JITTER, xy.shape)
    level = 0.05 + rng.normal(0.0, 1e-6, n)
    columns = [None, None, None]
    columns[vertical] = level
    columns[(vertical + 1) % 3], columns[(vertical + 2) % 3] = xy[:, 0], xy[:, 1]
    reading = np.where(t < DEAD, 0.0, np.maximum(0.0, 0.010 + rng.normal(0.0, 0.001, n)))
    (root / "data").mkdir(parents=True)
    (root / "config").mkdir()
    np.save(root / "data" / "traj.npy", np.stack(columns, axis=1) if traj is None else traj)
    np.save(root / "data" / "force.npy", reading if force is None else force)
    (root / "config" / "arguments.json").write_text(json.dumps({"scene_information": scene or SCENE}))
    return root


@pytest.mark.parametrize("vertical", [0, 1, 2])
def test_import_maps_geometry_finds_the_vertical_column_and_the_cup_axis(tmp_path, vertical):
    source = write_authors_folder(tmp_path / "authors", vertical=vertical)
    imported = import_diffstir_authors(source, tmp_path / "rec")
    rec = load_recording(tmp_path / "rec")
    assert imported.vertical_column == vertical
    assert rec.cup.radius == pytest.approx(0.0425) and rec.cup.fill_height == pytest.approx(0.13)
    assert rec.rod.radius == pytest.approx(0.0125) and rec.rod.immersion_depth == pytest.approx(0.08)
    # the centre of N jittered points is known to JITTER / sqrt(N / 2) (0.8 um); 5 um is six of those
    assert imported.centre == pytest.approx(CENTRE, abs=5e-6)
    assert imported.radius == pytest.approx(RADIUS, abs=5e-6)
    assert imported.circle_rms == pytest.approx(JITTER, rel=0.1)
    np.testing.assert_allclose(np.hypot(rec.x, rec.y), RADIUS, atol=6 * JITTER)
    # x, y follow the vertical column cyclically: the rod turns counter-clockwise seen from above
    turn = np.unwrap(np.arctan2(rec.y, rec.x))
    assert turn[-1] - turn[0] == pytest.approx(OMEGA * (DURATION - 1 / RATE), rel=0.01)
    np.testing.assert_allclose(rec.t, np.arange(rec.t.size) / RATE)
    assert rec.sensor.mode == "tangential" and rec.sensor.one_sided and rec.sensor.sample_rate == RATE
    assert rec.density is None and rec.extra_meta["density_stated"] == 1050.0
    assert imported.dead_start == pytest.approx(DEAD, abs=1.5 / RATE)


def test_fit_circle_is_exact_on_a_circle():
    phi = np.linspace(0.0, 2.0, 50)
    a, b, r, rms = fit_circle(1.0 + 0.2 * np.cos(phi), -3.0 + 0.2 * np.sin(phi))
    assert (a, b, r) == pytest.approx((1.0, -3.0, 0.2), abs=1e-12) and rms < 1e-12


@pytest.mark.parametrize("field, value, message", [
    ("container_diameter", 95.0, r"container_diameter = 95.0; expected m \(in mm\?"),
    ("liquid_density", 1.05, r"liquid_density = 1.05; expected kg/m\^3 .*in g/cm\^3\?"),
    ("operator_bottom_height", 0.2, "operator_bottom_height = 0.2 m is not below liquid_height"),
    ("operator_radius", float("nan"), r"operator_radius = nan; expected a finite number in m"),
])
def test_a_scene_in_other_units_is_refused_naming_file_and_field(tmp_path, field, value, message):
    source = write_authors_folder(tmp_path / "authors", scene={**SCENE, field: value})
    with pytest.raises(RecordingError, match=f"arguments.json: scene_information.{message}"):
        import_diffstir_authors(source, tmp_path / "rec")
    assert not (tmp_path / "rec").exists()


def test_malformed_arrays_are_refused_in_one_line(tmp_path):
    good = write_authors_folder(tmp_path / "good")
    traj, force = np.load(good / "data" / "traj.npy"), np.load(good / "data" / "force.npy")
    nan = traj.copy()
    nan[17, 0] = np.nan
    cases = {
        "nan": (dict(traj=nan), r"traj.npy: row 17 .* non-finite value .* in m"),
        "shape": (dict(traj=traj[:, :2]), r"traj.npy: shape \(1200, 2\); expected \(N, 3\)"),
        "length": (dict(force=force[:-5]), r"force.npy: 1195 readings against 1200 rows"),
        "mm": (dict(traj=traj * 1000), r"traj.npy: a position of .*expected m \(in mm\?\)"),
        "mN": (dict(force=force * 1e4), r"force.npy: a reading of .*in mN or grams\?"),
        "no level": (dict(traj=np.stack([traj[:, 0], traj[:, 2], traj[:, 0] + traj[:, 2]], 1)),
                     "traj.npy: no column stays level"),
    }
    for name, (arrays, message) in cases.items():
        source = write_authors_folder(tmp_path / name, **arrays)
        with pytest.raises(RecordingError, match=message) as error:
            import_diffstir_authors(source, tmp_path / f"{name}-rec")
        assert "\n" not in str(error.value)
        assert not (tmp_path / f"{name}-rec").exists()
    with pytest.raises(RecordingError, match="force.npy: not found"):
        (good / "data" / "force.npy").unlink()
        import_diffstir_authors(good, tmp_path / "rec")


def test_an_existing_out_is_kept_unless_overwrite(tmp_path):
    source = write_authors_folder(tmp_path / "authors")
    out = tmp_path / "rec"
    import_diffstir_authors(source, out)
    before = (out / "stir.csv").read_bytes()
    with pytest.raises(OutputError, match="rec: already exists; pass overwrite=true"):
        import_diffstir_authors(write_authors_folder(tmp_path / "other", seed=1), out)
    assert (out / "stir.csv").read_bytes() == before
    import_diffstir_authors(tmp_path / "other", out, overwrite=True)
    assert (out / "stir.csv").read_bytes() != before


def test_settings_the_files_do_not_state(tmp_path):
    source = write_authors_folder(tmp_path / "authors")
    settings = ImportSettings(sample_rate=500.0, mode="component", axis=(0.0, 1.0), one_sided=True)
    rec = import_diffstir_authors(source, tmp_path / "rec", settings).recording
    assert rec.sensor.mode == "component" and rec.sensor.axis == (0.0, 1.0) and rec.t[1] == pytest.approx(0.002)
    with pytest.raises(ConfigError, match="sensor.axis is null; mode component"):
        ImportSettings(mode="component")
    with pytest.raises(ConfigError, match="sample_rate = -1.0; expected a positive rate in Hz"):
        ImportSettings(sample_rate=-1.0)
    assert math.isclose(ImportSettings().sample_rate, 1000.0)
