"""diffstir-import on the DiffStir authors' layout, made at run time from the bundled 1 kHz thin-film recording
with a dead start, and diffstir-fit on what it wrote (docs/acceptance.md)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from acceptance_commands import example, full_only, ok, refused, run, truth, write_authors_folder

from diffstir.recording import load_recording

pytestmark = pytest.mark.acceptance
SOURCE = "rig_dead_start"


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    root = tmp_path_factory.mktemp("import")
    source = write_authors_folder(SOURCE, root / "authors")
    result = ok(run("diffstir-import", f"source={source}", "out=rec", cwd=root, timeout=120))
    return root, source, result


def test_import_writes_a_recording_that_reads_like_the_original(imported):
    root, _, result = imported
    original, rec = load_recording(example(SOURCE)), load_recording(root / "rec")
    np.testing.assert_array_equal(rec.force, original.force)
    np.testing.assert_allclose(rec.t, np.arange(rec.t.size) / 1000.0)
    assert (rec.cup, rec.rod) == (original.cup, original.rod)
    # the cup's axis from the circle fit: positions about it within 3 um of the recorded ones (30 um jitter,
    # 1500 samples: the centre is known to 20 um / sqrt(750) = 0.7 um)
    np.testing.assert_allclose(rec.x, original.x, atol=3e-6)
    np.testing.assert_allclose(rec.y, original.y, atol=3e-6)
    dead = truth(SOURCE)["sensor"]["dead_start"]
    stated = float(re.search(r"reads 0 for the first ([0-9.]+) s", result.stdout).group(1))
    assert stated == pytest.approx(dead, abs=0.01)
    assert f"density={truth(SOURCE)['fluid']['density']:g}" in result.stdout


def test_import_refuses_an_existing_out_in_one_line(imported):
    root, source, _ = imported
    before = (root / "rec" / "stir.csv").read_bytes()
    line = refused(run("diffstir-import", f"source={source}", "out=rec", cwd=root, timeout=120))
    assert "already exists" in line and "overwrite=true" in line
    assert (root / "rec" / "stir.csv").read_bytes() == before


def test_import_refuses_a_diameter_in_millimetres_before_writing(imported, tmp_path):
    _, source, _ = imported
    args = json.loads((source / "config" / "arguments.json").read_text())
    args["scene_information"]["container_diameter"] = 85.0
    (source / "config" / "arguments.json").write_text(json.dumps(args))
    try:
        line = refused(run("diffstir-import", f"source={source}", "out=mm", cwd=tmp_path, timeout=120))
    finally:
        args["scene_information"]["container_diameter"] = 0.085
        (source / "config" / "arguments.json").write_text(json.dumps(args))
    assert "arguments.json: scene_information.container_diameter = 85.0; expected m (in mm?" in line
    assert not (tmp_path / "mm").exists()


@full_only
def test_fit_on_the_imported_recording_reports_the_dead_start_and_fits_after_it(imported):
    root, _, result = imported
    density = re.search(r"density=([0-9.]+)", result.stdout).group(1)
    fit = ok(run("diffstir-fit", "recording=rec", "out=fit", f"density={density}", cwd=root, timeout=1800))
    report = json.loads((root / "fit" / "report.json").read_text())
    assert (root / "fit" / "report.md").is_file()
    dead = truth(SOURCE)["sensor"]["dead_start"]
    assert report["windows"]["start"] >= dead - 0.01  # the fit is where the signal is
    assert "dead start" in (fit.stdout + fit.stderr + (root / "fit" / "report.md").read_text()).lower()
