"""The streaming writer: what a clean close, an exception, an abandoned writer and a SIGKILL leave on disk."""

from __future__ import annotations

import gc
import math
import os
import signal
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from diffstir.recording import (
    CupGeometry, DensityMeasurement, RecordingError, RecordingWarning, RecordingWriter, RodGeometry, SensorSpec,
    load_recording,
)

REPO = Path(__file__).resolve().parents[1]
RIG = dict(cup=CupGeometry(0.0425, fill_height=0.130), rod=RodGeometry(0.0125, 0.080),
           sensor=SensorSpec("tangential", resolution=0.005, sample_rate=200.0))


def row(i: int) -> dict:
    """Row i of a 1 Hz circle sampled at 200 Hz; every value is a function of i, so rows can be checked."""
    t = i / 200.0
    return dict(t=t, x=0.015 * math.cos(2 * math.pi * t), y=0.015 * math.sin(2 * math.pi * t),
                force=0.03 + 0.001 * (i % 7))


def assert_rows(rec, n: int) -> None:
    """``rec`` holds exactly rows 0 .. n-1."""
    assert rec.t.size == n
    for column in ("t", "x", "y", "force"):
        np.testing.assert_array_equal(getattr(rec, column), [row(i)[column] for i in range(n)], err_msg=column)


def metadata(path: Path) -> dict:
    return yaml.safe_load((path / "recording.yaml").read_text())


def load_warned(path: Path) -> tuple:
    """load_recording, and the messages of the RecordingWarnings it emitted."""
    with pytest.warns(RecordingWarning) as caught:
        rec = load_recording(path)
    return rec, [str(w.message) for w in caught]


def load_partial(path: Path):
    """load_recording of a partial recording: it must say so."""
    rec, messages = load_warned(path)
    assert any("PARTIAL recording" in m for m in messages), messages
    return rec


def test_clean_write_is_complete_and_loads_without_warnings(tmp_path):
    path = tmp_path / "run"
    with RecordingWriter(path, **RIG, name="run", fluid="water", temperature=21.0,
                         optional_columns=("z", "force_x", "force_y", "raw")) as w:
        assert metadata(path)["complete"] is False and metadata(path)["partial_reason"] == "in progress"
        for i in range(600):
            w.append(**row(i), z=-1e-5 * i, force_x=0.01, force_y=-0.02, raw=float(i))
        w.set_density(DensityMeasurement(0.6, 0.215, 0.08))
    meta = metadata(path)
    assert meta["complete"] is True and "partial_reason" not in meta
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = load_recording(path)
    assert_rows(rec, 600)
    np.testing.assert_array_equal(rec.raw, np.arange(600.0))
    np.testing.assert_array_equal(rec.z, -1e-5 * np.arange(600))
    assert rec.density == DensityMeasurement(0.6, 0.215, 0.08)
    assert (rec.name, rec.fluid, rec.temperature, rec.complete) == ("run", "water", 21.0, True)


def test_a_recording_in_progress_loads_as_partial_with_every_flushed_row(tmp_path):
    w = RecordingWriter(tmp_path / "run", **RIG, flush_interval=0.0)
    for i in range(100):
        w.append(**row(i))
    assert w.rows_flushed == w.rows_written == 100  # flush_interval 0: every row is fsynced
    w.set_density(DensityMeasurement(0.6, 0.215, 0.08))
    rec = load_partial(w.path)
    assert_rows(rec, 100)
    assert rec.partial_reason == "in progress" and rec.density.rod_weight == 0.6
    w.close()


def test_rows_are_flushed_by_wall_time(tmp_path):
    w = RecordingWriter(tmp_path / "run", **RIG, flush_interval=3600.0)
    for i in range(50):
        w.append(**row(i))
    assert (w.rows_written, w.rows_flushed) == (50, 0)
    w.close()
    assert w.rows_flushed == 50


def test_an_exception_inside_with_closes_partial_and_propagates(tmp_path):
    path = tmp_path / "run"
    with pytest.raises(ZeroDivisionError):
        with RecordingWriter(path, **RIG, flush_interval=3600.0) as w:
            for i in range(120):
                w.append(**row(i))
            1 / 0
    meta = metadata(path)
    assert meta["complete"] is False
    assert meta["partial_reason"] == "ZeroDivisionError('division by zero')"
    assert_rows(load_partial(path), 120)  # close() flushed the rows written since the last flush


def test_an_abandoned_writer_is_flushed_and_marked_partial(tmp_path):
    w = RecordingWriter(tmp_path / "run", **RIG, flush_interval=3600.0)
    for i in range(80):
        w.append(**row(i))
    path = w.path
    del w
    gc.collect()
    assert "never closed" in metadata(path)["partial_reason"]
    assert_rows(load_partial(path), 80)


CHILD = textwrap.dedent("""
    import math, sys, time
    from diffstir.recording import CupGeometry, RecordingWriter, RodGeometry, SensorSpec
    w = RecordingWriter(sys.argv[1], cup=CupGeometry(0.0425, fill_height=0.130), rod=RodGeometry(0.0125, 0.080),
                        sensor=SensorSpec("tangential"), optional_columns=("raw",), flush_interval=0.02)
    flushed = 0
    for i in range(int(sys.argv[2])):
        t = i / 200.0
        w.append(t=t, x=0.015 * math.cos(2 * math.pi * t), y=0.015 * math.sin(2 * math.pi * t),
                 force=0.03 + 0.001 * (i % 7), raw=float(i) * 1e6)  # long lines, so buffers split lines
        if w.rows_flushed != flushed:
            flushed = w.rows_flushed
            print(flushed, flush=True)
        time.sleep(0.0002)
    print("torch imported:", "torch" in sys.modules)  # a recorder does not need torch
""")


def test_sigkill_leaves_a_loadable_recording_with_every_row_flushed_before_the_kill(tmp_path):
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    path = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    child = subprocess.Popen([sys.executable, str(script), str(path), str(10**6)], stdout=subprocess.PIPE, text=True,
                             env=env)
    try:
        reported = 0
        while reported < 1000:
            line = child.stdout.readline()
            assert line, f"the child writer died early (exit code {child.poll()})"
            reported = int(line)
        child.send_signal(signal.SIGKILL)
    finally:
        child.kill()
        child.wait(timeout=30)
    assert child.returncode == -signal.SIGKILL
    rec = load_partial(path)
    assert rec.partial_reason == "in progress"
    assert rec.t.size >= reported
    assert_rows(rec, rec.t.size)
    np.testing.assert_array_equal(rec.raw, np.arange(rec.t.size) * 1e6)


def test_a_program_that_exits_without_close_leaves_every_row(tmp_path):
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    path = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(REPO))
    done = subprocess.run([sys.executable, str(script), str(path), "321"], env=env, check=True, capture_output=True,
                          text=True)
    assert done.stdout.endswith("torch imported: False\n")
    assert "never closed" in metadata(path)["partial_reason"]
    assert_rows(load_partial(path), 321)


def test_flush_forces_rows_to_disk(tmp_path):
    with RecordingWriter(tmp_path / "run", **RIG, flush_interval=3600.0) as w:
        for i in range(10):
            w.append(**row(i))
        w.flush()
        assert w.rows_flushed == 10
        assert (w.path / "stir.csv").read_text().count("\n") == 12  # comment, header, 10 rows


def test_a_truncated_last_line_is_dropped_with_a_warning(tmp_path):
    w = RecordingWriter(tmp_path / "run", **RIG)
    for i in range(200):
        w.append(**row(i))
    w.flush()
    with open(w.path / "stir.csv", "a") as f:
        f.write("1.005,0.0149")  # a crash in the middle of a row: no newline
    rec, messages = load_warned(w.path)
    assert any("dropped the last line '1.005,0.0149'" in m for m in messages), messages
    assert_rows(rec, 200)


def test_a_truncated_last_line_that_parses_is_still_dropped_from_a_partial_recording(tmp_path):
    w = RecordingWriter(tmp_path / "run", **RIG)
    for i in range(200):
        w.append(**row(i))
    w.flush()
    with open(w.path / "stir.csv", "a") as f:
        f.write("1.005,0.0149,0.0004,0.03")  # could be a cut-off 0.0149xxx: not trusted
    rec, messages = load_warned(w.path)
    assert any("dropped the last line" in m for m in messages), messages
    assert_rows(rec, 200)


def test_a_complete_file_without_final_newline_keeps_its_last_line(tmp_path):
    with RecordingWriter(tmp_path / "run", **RIG) as w:
        for i in range(300):
            w.append(**row(i))
    csv = w.path / "stir.csv"
    text = csv.read_text()
    csv.write_text(text.rstrip("\n"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert_rows(load_recording(w.path), 300)
    csv.write_text(text + "1.5,0.01")  # but a line that does not parse is dropped
    with pytest.warns(RecordingWarning, match="dropped the last line '1.5,0.01'"):
        assert_rows(load_recording(w.path), 300)


def test_the_writer_never_overwrites(tmp_path):
    existing = tmp_path / "run"
    existing.mkdir()
    (existing / "notes.txt").write_text("mine")
    empty = tmp_path / "empty"
    empty.mkdir()
    for path in (existing, empty):
        with pytest.raises(FileExistsError, match="never overwrites"):
            RecordingWriter(path, **RIG)
    assert (existing / "notes.txt").read_text() == "mine" and list(empty.iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "run"]


def test_bad_rows_are_refused_and_nothing_is_written(tmp_path):
    w = RecordingWriter(tmp_path / "run", **RIG, optional_columns=("z",), flush_interval=0.0)
    w.append(**row(0), z=0.0)
    bad = [
        (dict(row(0), z=0.0), r"column 't' = 0.0 s at data row 2 does not increase on the previous 0.0 s"),
        (dict(row(1), z=float("nan")), r"column 'z' = nan at data row 2 \(t = 0.005 s\); expected a finite"),
        (dict(row(1), z="12 mm"), r"column 'z' = '12 mm' at data row 2 is not a number; expected m"),
        (row(1), r"optional columns \[\]; this writer's are \['z'\]"),
        (dict(row(1), z=0.0, raw=1.0), r"optional columns \['raw', 'z'\]"),
    ]
    for values, message in bad:
        with pytest.raises(RecordingError, match=message):
            w.append(**values)
    w.close()
    with pytest.raises(RecordingError, match="closed"):
        w.append(**row(1), z=0.0)
    assert (w.path / "stir.csv").read_text().count("\n") == 3  # comment, header, one row


def test_metadata_is_checked_before_anything_is_written(tmp_path):
    with pytest.raises(RecordingError, match=r"run/recording.yaml: field 'rig.cup.radius' = 42.5 m looks like mill"):
        RecordingWriter(tmp_path / "run", **dict(RIG, cup=CupGeometry(42.5, fill_height=0.13)))
    assert not (tmp_path / "run").exists()
    with RecordingWriter(tmp_path / "ok", **RIG) as w:
        with pytest.raises(RecordingError, match="'density.immersed_reading' = 0.7 N is not smaller"):
            w.set_density(DensityMeasurement(0.6, 0.7, 0.08))
        assert "density" not in metadata(w.path)
