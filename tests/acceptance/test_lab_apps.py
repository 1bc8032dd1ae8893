"""diffstir-simulate and diffstir-synth on their default configurations (docs/acceptance.md)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from acceptance_commands import EXAMPLES, ok, refused, run

from diffstir.recording import load_recording

pytestmark = pytest.mark.acceptance


def test_simulate_writes_the_force(tmp_path):
    ok(run("diffstir-simulate", "out=sim", cwd=tmp_path, timeout=600))
    assert (tmp_path / "sim" / "force.csv").is_file() and (tmp_path / "sim" / "force.png").is_file()


def test_synth_writes_the_bundled_example_and_refuses_to_overwrite_it_before_simulating(tmp_path):
    ok(run("diffstir-synth", "out=lab", cwd=tmp_path, timeout=900))
    rec = load_recording(tmp_path / "lab" / "carreau_example")
    shipped = load_recording(EXAMPLES / "carreau_example")
    # the bundled example's settings and seed make the shipped recording (2.5 s at 100 Hz), up to one step of the
    # sensor's resolution where another machine's rounding moves the force across a step
    truth = json.loads((tmp_path / "lab" / "carreau_example.truth.json").read_text())
    assert truth["seed"] == 0 and rec.t.size == shipped.t.size == 250
    np.testing.assert_allclose(rec.force, shipped.force, rtol=0, atol=truth["sensor"]["resolution"] * 1.001)
    before = (tmp_path / "lab" / "carreau_example" / "stir.csv").read_bytes()
    again = run("diffstir-synth", "out=lab", cwd=tmp_path, timeout=60)  # refused before any simulation
    assert "overwrite=true" in refused(again)
    assert (tmp_path / "lab" / "carreau_example" / "stir.csv").read_bytes() == before

