"""diffstir-record's sequential mode on its default configuration, with the emulated ADC, arm and gripper (no rig):
stir, analyse, plan, until decided or the budget is spent (docs/acceptance.md)."""

from __future__ import annotations

import json

import pytest
import yaml
from acceptance_commands import ok, refused, run

from diffstir.planning.sequential import StirSoFar
from diffstir.recording import load_recording

pytestmark = pytest.mark.acceptance
EMULATED = ("hardware/adc=emulated", "hardware/arm=replay", "hardware/gripper=emulated", "density.skip=true")


def test_the_sequential_mode_stirs_analyses_and_plans_until_the_budget_is_spent(tmp_path):
    # a 2 s budget in one segment: the first stir (0.02 and 0.08 m/s for 1 s each, a turn of the 15 mm circle)
    # leaves no room for another, so the session is one stir and one analysis (the data shortened, not the analysis)
    done = ok(run("diffstir-record", *EMULATED, "sequential.enabled=true", "plan.budget=2", "plan.max_segments=1",
                  "out=runs", cwd=tmp_path, timeout=900))
    session = tmp_path / "runs" / "run-1"
    meta = yaml.safe_load((session / "session.yaml").read_text())
    assert meta["status"] == "complete" and [s["stir"] for s in meta["sequence"]] == ["stir-1"]
    step = meta["sequence"][0]
    assert [s["speed"] for s in step["programme"]["segments"]] == [0.02, 0.08] and step["next"] is None
    assert step["decided"] or step["candidates"] == {}
    recording = load_recording(session / "stir-1")
    assert recording.complete and recording.name == "run-1-stir-1"
    report = json.loads((session / "analysis-1" / "report.json").read_text())
    assert report["joint_fit"]["fitted_to"] == "points"  # the flow-curve analysis, as diffstir-fit writes it
    assert StirSoFar.from_report(report).elapsed == pytest.approx(step["elapsed"])
    assert json.loads((session / "analysis-1" / "next.json").read_text())["elapsed"] == step["elapsed"]
    assert "stir-1: 0.02, 0.08 m/s; after" in done.stdout and "done: " in done.stdout


@pytest.mark.parametrize("args, message", [
    (["dry_run.mode=profile"], "dry_run.mode = 'profile' runs one programme in air"),
    (["stir.file=old.csv"], "stir.file: the sequential mode plans its own stirs"),
    (["sequential.first=[0.02]"], "sequential.first = [0.02] m/s; expected two or more speeds in (0, 0.25] m/s"),
    (["sensor.resolution=null"], "sensor.resolution = None; the sequential mode plans each stir for the sensor's"),
])
def test_a_sequential_setting_it_cannot_run_is_refused_in_one_line_before_any_device_opens(tmp_path, args,
                                                                                            message):
    line = refused(run("diffstir-record", *EMULATED, "sequential.enabled=true", *args, "out=runs", cwd=tmp_path,
                       timeout=120))
    assert message in line and not (tmp_path / "runs").exists()
