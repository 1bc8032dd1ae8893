"""diffstir-synth with the 3-D finite-element truth on its default configuration (docs/acceptance.md); a file of its
own so that the suite's two processes share the acceptance commands evenly."""

from __future__ import annotations

import json

import pytest
from acceptance_commands import ok, run

from diffstir.recording import load_recording

pytestmark = pytest.mark.acceptance
pytest.importorskip("skfem")  # the validation extra, which the README's test command installs
pytest.importorskip("gmsh")


def test_synth_writes_a_3d_truth_recording_by_finite_elements(tmp_path):
    """``lab/sim=fe3d`` on its defaults (conf/lab/sim/fe3d.yaml), the example's fluid, over a shorter programme in
    a shallower cup (the data, not the configuration): a recording of the rod's 3-D force [N] and its truth file
    naming the finite elements."""
    ok(run("diffstir-synth", "lab/sim=fe3d", "lab.programme.segments=[{speed:0.2,duration:0.7}]",
           "rig.cup.fill_height=0.05", "rig.rod.immersion_depth=0.03", "name=fe3d", "out=lab", cwd=tmp_path,
           timeout=900))
    truth = json.loads((tmp_path / "lab" / "fe3d.truth.json").read_text())
    simulator = truth["simulator"]
    assert simulator["kind"] == "fe3d" and simulator["force_scale"] == "3-D force"
    assert simulator["config"] == {"cell": 0.005, "growth": 3.0, "dt": 0.002}
    # Taylor-Hood: three components on the vertices and edges against one pressure per vertex
    assert simulator["factorisations"] >= 1 and simulator["velocity_dofs"] > 3 * simulator["pressure_dofs"] > 0
    rec = load_recording(tmp_path / "lab" / "fe3d")
    assert rec.t[-1] - rec.t[0] == pytest.approx(0.7, abs=0.011)  # the programme, its ramp included
