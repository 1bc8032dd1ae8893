"""diffstir-plan on its default configuration: the paper's rig, its shipped calibration (docs/acceptance.md)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml
from acceptance_commands import ROOT, ok, refused, run

from diffstir.behaviour import JOINT_MODELS
from diffstir.hardware import load_trajectory
from diffstir.lab import stirring_programme

pytestmark = pytest.mark.acceptance


def test_plan_writes_a_programme_that_beats_one_speed_and_the_arm_can_replay(tmp_path):
    ok(run("diffstir-plan", "out=plan", cwd=tmp_path, timeout=600))
    out = tmp_path / "plan"
    report = json.loads((out / "plan.json").read_text())
    plan, single = report["plan"], report["single_speed"]
    speeds = [s["speed"] for s in plan["programme"]["segments"]]
    assert len(speeds) >= 2 and speeds == sorted(speeds)
    assert plan["gain_per_parameter"] > single["gain_per_parameter"]
    # one speed is one point of the flow curve: every law passes through it and ln S = 0, so no pair is told apart
    assert all(d == pytest.approx(0.0, abs=1e-3) for row in single["expected_delta_bic"].values() for d in row.values())
    assert (out / "plan.md").read_text().startswith("# Stirring plan") and (out / "plan.png").stat().st_size > 0
    # the programme as diffstir-synth reads it, and the path as diffstir-record replays it: the same motion
    programme = yaml.safe_load((out / "lab" / "programme" / "planned.yaml").read_text())
    path = load_trajectory(out / "stir_path.csv")
    expected = stirring_programme(programme["segments"], radius=programme["radius"],
                                  ramp_time=programme["ramp_time"], sample_rate=100.0)
    assert path.duration == pytest.approx(sum(s["duration"] for s in programme["segments"]), abs=0.011)
    np.testing.assert_allclose(path.xy, expected.xy[: len(path.t)], atol=1e-6)
    # the shipped programme that the bundled planned example was stirred with is still the default plan's
    shipped = yaml.safe_load((ROOT / "conf" / "lab" / "programme" / "paper_plan.yaml").read_text())
    assert shipped == programme
    again = run("diffstir-plan", "out=plan", cwd=tmp_path, timeout=120)
    assert "overwrite=true" in refused(again)


def test_a_bad_prior_is_refused_in_one_line_before_any_simulation(tmp_path):
    line = refused(run("diffstir-plan", "out=plan", "prior.viscosity=[5,1]", cwd=tmp_path, timeout=120))
    assert "prior.viscosity = [5, 1]; expected [low, high] in Pa s" in line
    assert not (tmp_path / "plan").exists()


def flow_curve_report(points: list[tuple[float, float, float, float]]) -> dict:
    """A flow-curve report.json's fields the sequential mode reads, one recording of 2 s segments: (speed [m/s],
    γ̇ [1/s], η [Pa·s], σ of ln η), and the laws of the analysis's default ``behaviour.joint_models``."""
    return {"joint_fit": {"fitted_to": "points", "laws": {name: {} for name in JOINT_MODELS}},
            "points": [{"window": f"stir@{2 * k + 0.4:g}-{2 * k + 2:g}s", "end": 2.0 * k + 2, "speed": u,
                        "shear_rate": g, "viscosity": eta, "classified": True,
                        "viscosity_ci95": [eta * math.exp(-1.96 * s), eta * math.exp(1.96 * s)]}
                       for k, (u, g, eta, s) in enumerate(points)]}


def test_the_sequential_mode_plans_the_next_stir_of_an_undecided_one(tmp_path):
    # two points a factor 2 apart with 30 % errors: no family is decided, and 4 s of the 8 s budget are left
    (tmp_path / "report.json").write_text(json.dumps(flow_curve_report([(0.02, 1.8, 0.9, 0.3),
                                                                        (0.04, 3.6, 0.8, 0.3)])))
    ok(run("diffstir-plan", "after=report.json", "out=next", cwd=tmp_path, timeout=600))
    step = json.loads((tmp_path / "next" / "next.json").read_text())
    assert not step["decided"] and step["elapsed"] == 4.0
    speed, duration = step["next"]["speed"], step["next"]["duration"]
    assert speed in (0.02, 0.04, 0.08, 0.16)  # 0.01 m/s: a recording's turn of the circle takes 9.4 s, over 4 s
    assert 2.0 <= duration <= 4.0  # the best score per second of stirring among the candidates
    assert step["next"]["rate"] == max(c["rate"] for c in step["candidates"].values())
    assert step["candidates"][f"{speed:g}"] == {"score": step["next"]["score"], "duration": duration,
                                                "rate": step["next"]["rate"]}
    programme = yaml.safe_load((tmp_path / "next" / "lab" / "programme" / "planned.yaml").read_text())
    assert programme["segments"] == [{"speed": speed, "duration": duration}]
    path = load_trajectory(tmp_path / "next" / "stir_path.csv")
    assert path.duration == pytest.approx(duration, abs=0.011)


def test_the_sequential_mode_refuses_a_report_that_is_not_a_flow_curve_in_one_line(tmp_path):
    (tmp_path / "report.json").write_text(json.dumps({"joint_fit": {"fitted_to": "recordings"}, "points": []}))
    line = refused(run("diffstir-plan", "after=report.json", "out=next", cwd=tmp_path, timeout=120))
    assert "joint_fit.fitted_to is not 'points'; expected the report.json of diffstir-fit experiment=flow_curve" in line
    assert not (tmp_path / "next").exists()
