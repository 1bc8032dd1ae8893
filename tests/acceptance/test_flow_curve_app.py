"""diffstir-fit experiment=flow_curve, the README's first command: a planned programme's recording read by
whole-programme Newtonian rungs, the laws fitted to its points (docs/flow-curve.md)."""

from __future__ import annotations

import json
import math
import shlex

import pytest
import torch
from acceptance_commands import EXAMPLES, ROOT, example, full_only, ok, run, truth

from diffstir.fitting import PROGRAMME_SIMULATIONS
from diffstir.lab import Fluid

pytestmark = pytest.mark.acceptance


def truth_slope(name: str, shear_rates: list[float]) -> float:
    """The chord d ln η / d ln γ̇ [1] of the truth law of the bundled recording ``name`` between the slowest and
    the fastest of ``shear_rates`` [1/s]."""
    fluid = truth(name)["fluid"]
    law = Fluid(name=fluid["name"], density=fluid["density"], law=fluid["law"]).make_law()
    lo, hi = min(shear_rates), max(shear_rates)
    with torch.no_grad():
        eta = law(torch.tensor([lo, hi], dtype=torch.float64))
    return float(torch.log(eta[1] / eta[0])) / math.log(hi / lo)


def check_report(report: dict, name: str) -> None:
    """One point per planned speed, the laws fitted to them, and the class of the Carreau truth (n = 0.6,
    λ = 0.5 s) over the plan's 0.9-14 1/s, where its viscosity halves: shear-thinning, with the points' slope
    interval holding the truth's chord, and each identified parameter of the truth's law holding its value."""
    assert len(report["points"]) == 4
    assert report["joint_fit"]["fitted_to"] == "points"
    assert report["programmes"][0]["simulations"] <= PROGRAMME_SIMULATIONS
    b = report["behaviour"]
    assert b["class"] == "shear_thinning"
    lo, hi = b["slope_ci95"]
    assert lo <= truth_slope(name, [p["shear_rate"] for p in report["points"]]) <= hi
    law = truth(name)["fluid"]["law"]
    fitted = report["joint_fit"]["laws"][law["name"]]
    for parameter, value in law["params"].items():
        if fitted["identifiable"][parameter]:  # a profile interval (docs/flow-curve.md, step 5)
            assert fitted["ci95"][parameter][0] <= value <= fitted["ci95"][parameter][1]


def test_a_shortened_planned_recording_is_shear_thinning(tmp_path):
    name = "rig_planned_short"  # the plan's four speeds, 0.8 s each
    ok(run("diffstir-fit", "experiment=flow_curve", f"recordings=[{example(name)}]", "out=flow", cwd=tmp_path,
           timeout=3600))
    out = tmp_path / "flow"
    check_report(json.loads((out / "report.json").read_text()), name)
    assert "fitted to the points' flow curve" in (out / "report.md").read_text()
    assert (out / "flow_curve.png").stat().st_size > 0 and (out / "viscosity_vs_speed.png").stat().st_size > 0
    # the sequential mode on that report: the stir is decided shear-thinning, so no stir follows
    ok(run("diffstir-plan", "after=flow/report.json", "out=next", cwd=tmp_path, timeout=600))
    step = json.loads((tmp_path / "next" / "next.json").read_text())
    assert step["decided"] and step["family"] == "shear_thinning" and step["next"] is None
    behaviour = json.loads((out / "report.json").read_text())["behaviour"]  # judged by the report's own laws
    assert step["family"] == behaviour["class"] and step["confidence"] == pytest.approx(behaviour["confidence"])
    assert step["elapsed"] == pytest.approx(3.2, abs=0.02)  # the four 0.8 s segments
    assert not (tmp_path / "next" / "stir_path.csv").exists()


@full_only
def test_the_readmes_first_command_names_the_bundled_fluids_family(tmp_path):
    first = (ROOT / "README.md").read_text(encoding="utf-8").split("```bash\n")[1].splitlines()[0]
    command = shlex.split(first.split("&&")[1])
    assert command[:2] == ["diffstir-fit", "experiment=flow_curve"]
    recording = next(a for a in command if a.startswith("recordings="))
    name = recording.strip("]").rsplit("/", 1)[1]
    ok(run(*command[:1], *[a.replace("diffstir/data/examples/", f"{EXAMPLES}/") for a in command[1:]],
           cwd=tmp_path, timeout=1800))  # 5 min on 2 cores (docs/flow-curve.md)
    check_report(json.loads((tmp_path / "outputs" / "example" / "report.json").read_text()), name)
