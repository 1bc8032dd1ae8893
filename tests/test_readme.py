"""The README's Python example runs as written: the simulator part for real, the fit up to its call, whose
arguments must bind to ``identify``'s signature (the fit itself is the acceptance suite's and the benchmarks')."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest
import torch

import diffstir
from diffstir.mpm import COARSE_STAGE, FINE_STAGE

ROOT = Path(__file__).resolve().parents[1]


class FitCalled(Exception):
    """Raised by the stand-in for ``identify`` once its arguments bound."""


def readme_example() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## Using the simulator from your own code"):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_readmes_python_example_runs(monkeypatch):
    real = diffstir.identify
    bound = {}

    def identify(*args, **kwargs):
        bound.update(inspect.signature(real).bind(*args, **kwargs).arguments)
        raise FitCalled

    monkeypatch.setattr(diffstir, "identify", identify)
    monkeypatch.chdir(ROOT)
    namespace: dict = {}
    with pytest.raises(FitCalled):
        exec(compile(readme_example(), "README.md", "exec"), namespace)
    law, result = namespace["law"], namespace["result"]
    assert result.force.shape[1] == 2 and torch.isfinite(result.force).all()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in law.parameters())
    assert bound["recording"].name == "carreau_example"
    assert bound["config"] == FINE_STAGE and bound["coarse"] == COARSE_STAGE
