"""diffstir-fit experiment=mixing on its default configuration, on the bundled blend recording (docs/acceptance.md);
a file of its own so that the suite's two processes share the acceptance commands evenly."""

from __future__ import annotations

import json

import pytest
from acceptance_commands import example, ok, run, truth

pytestmark = pytest.mark.acceptance


def test_mixing_tracks_the_blend_between_its_components(tmp_path):
    blend = truth("rig_blend")["fluid"]["blend"]
    eta = [blend["first"]["law"]["params"]["eta"], blend["second"]["law"]["params"]["eta"]]
    ok(run("diffstir-fit", "experiment=mixing", f"recordings=[{example('rig_blend')}]",
           f"mixing.viscosities=[{eta[0]},{eta[1]}]", f"mixing.fraction={blend['fraction']}", "out=mixing",
           cwd=tmp_path, timeout=1800))
    report = json.loads((tmp_path / "mixing" / "report.json").read_text())
    course = report["mixing"]["time_course"]
    assert len(course) >= 4  # 2.4 s, the ramp's 0.1 s off, in the default 0.5 s windows
    assert (tmp_path / "mixing" / "time_course.png").is_file()
