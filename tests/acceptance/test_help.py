"""Every console script's --help: the app's own page, as a user first meets it (docs/acceptance.md)."""

from __future__ import annotations

import tomllib

import pytest
from acceptance_commands import ROOT, ok, run

pytestmark = pytest.mark.acceptance
SCRIPTS = sorted(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"])


@pytest.mark.parametrize("script", SCRIPTS)
def test_help_shows_the_apps_usage_and_own_options(script, tmp_path):
    page = ok(run(script, "--help", cwd=tmp_path, timeout=120)).stdout
    assert page.startswith(f"usage: {script}") and "powered by Hydra" not in page
    assert "out" in page  # every app writes somewhere, and says where
    assert not any(tmp_path.iterdir())  # asking for help writes nothing
