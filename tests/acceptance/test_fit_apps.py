"""diffstir-fit (one recording, experiment=behaviour) and diffstir-diagnose on their default configurations, on the
bundled rig recordings (docs/acceptance.md)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from acceptance_commands import example, full_only, ok, run, truth

from diffstir.apps import CONF_DIR
from diffstir.diagnosis.candidates import PHYSICS_CANDIDATES, check_names
from diffstir.lab import Fluid

pytestmark = pytest.mark.acceptance


def truth_viscosity(name: str, shear_rate: float) -> float:
    """The truth law's viscosity [Pa s] of the bundled recording ``name`` at ``shear_rate`` [1/s]."""
    import torch

    fluid = truth(name)["fluid"]
    law = Fluid(name=fluid["name"], density=fluid["density"], law=fluid["law"]).make_law()
    with torch.no_grad():
        return float(law(torch.tensor([shear_rate], dtype=torch.float64)))


@full_only
@pytest.mark.parametrize("name", ["rig_jitter_1khz", "rig_dead_start"])
def test_fit_reads_density_and_viscosity_within_its_intervals(name, tmp_path):
    result = ok(run("diffstir-fit", f"recording={example(name)}", "out=fit", cwd=tmp_path, timeout=1800))
    report = json.loads((tmp_path / "fit" / "report.json").read_text())
    assert (tmp_path / "fit" / "report.md").is_file()
    density = report["density"]
    lo, hi = density["ci95"]
    assert lo <= truth(name)["fluid"]["density"] <= hi
    av = report["apparent_viscosity"]
    lo, hi = av["at_effective_shear_rate_ci95"]
    assert lo <= truth_viscosity(name, av["effective_shear_rate"]) <= hi
    if truth(name)["sensor"]["dead_start"] > 0:
        assert report["windows"]["start"] >= truth(name)["sensor"]["dead_start"] - 0.01
        assert "dead start" in (result.stdout + result.stderr + (tmp_path / "fit" / "report.md").read_text()).lower()


@full_only
@pytest.mark.xfail(strict=True, raises=AssertionError,
                   reason="known open defect: one speed does not identify the Carreau fluid's shape; the selected "
                   "Cross law reads +11.8 % at the stir's shear rate and its interval misses the truth by 2.0 % "
                   "(docs/accuracy.md, The default fit of a 6 s recording; issue 39 plans a stir that does)")
def test_a_six_second_recording_with_a_3d_truth_is_fitted_on_its_first_two_seconds(tmp_path):
    """The default fit of a 6 s recording whose force is the 3-D cup's by finite elements (docs/acceptance.md times
    it): the fit window is conf/fit.yaml's first 2 s, the force scale the slice's corrected one, and the density
    and the truth law's viscosity at the effective shear rate within the report's intervals (the latter holding the
    selection's uncertainty: docs/accuracy.md gives the point's error)."""
    name = "rig_fe3d_6s"
    assert truth(name)["simulator"]["kind"] == "fe3d"
    ok(run("diffstir-fit", f"recording={example(name)}", "out=fit", cwd=tmp_path, timeout=1800))
    report = json.loads((tmp_path / "fit" / "report.json").read_text())
    windows = report["windows"]
    assert windows["end"] - windows["start"] == pytest.approx(2.0, abs=0.02)
    assert report["force_scale"] == "F' h C"
    lo, hi = report["density"]["ci95"]
    assert lo <= truth(name)["fluid"]["density"] <= hi
    av = report["apparent_viscosity"]
    lo, hi = av["at_effective_shear_rate_ci95"]
    assert lo <= truth_viscosity(name, av["effective_shear_rate"]) <= hi


@full_only
def test_behaviour_classifies_three_constant_speed_stirs_at_200_hz(tmp_path):
    recordings = ",".join(example(f"rig_behaviour_{s}") for s in ("slow", "mid", "fast"))
    ok(run("diffstir-fit", "experiment=behaviour", f"recordings=[{recordings}]", "out=behaviour", cwd=tmp_path,
           timeout=7200))  # 25 min on 2 cores (docs/acceptance.md)
    report = json.loads((tmp_path / "behaviour" / "report.json").read_text())
    assert len(report["points"]) >= 3  # one window per speed
    # a Carreau fluid (n = 0.6, lambda = 0.5 s) far past its 2 1/s corner: shear-thinning
    assert report["behaviour"]["class"] == "shear_thinning"


def test_diagnose_runs_its_default_candidates(tmp_path):
    ok(run("diffstir-diagnose", f"recording={example('rig_jitter_1khz')}", "out=diagnosis", cwd=tmp_path,
           timeout=3600))
    diagnosis = json.loads((tmp_path / "diagnosis" / "diagnosis.json").read_text())
    assert diagnosis["verdict"]
    configured = yaml.safe_load((Path(CONF_DIR) / "diagnose.yaml").read_text())["diagnosis"]["candidates"]
    assert {r["effect"] for r in diagnosis["ranking"]} == set(check_names(configured))
    physics = [r for r in diagnosis["ranking"] if r["effect"] in PHYSICS_CANDIDATES and r.get("score") is not None]
    assert physics and all(r["simulations"] > 0 for r in physics)
    assert diagnosis["simulation"]["dx"] == 0.005  # sim: coarse2d, as configured
    assert (tmp_path / "diagnosis" / "diagnosis.md").is_file()
