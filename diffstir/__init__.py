"""diffstir: identify a fluid by stirring it.

A differentiable MLS-MPM stirring simulator in PyTorch, non-Newtonian rheology laws as ``nn.Module``s, and the
analyses built on them. All quantities are SI (m, s, kg, N, Pa, Pa·s).

    from diffstir import identify, load_recording
    from diffstir.mpm import COARSE_STAGE, FINE_STAGE

    result = identify(load_recording("diffstir/data/examples/carreau_example"), config=FINE_STAGE,
                      coarse=COARSE_STAGE)
    result.summary()["selected"]

The names below are loaded on first use, so that ``import diffstir.recording`` (a recording's checks) does not import
torch, the simulator and the analyses.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: The public API: each name and the module that defines it.
_HOMES = {
    "simulate": "diffstir.mpm",
    "StirringSimulator": "diffstir.mpm",
    "SimConfig": "diffstir.mpm",
    "Rig": "diffstir.rig",
    "load_recording": "diffstir.recording",
    "identify": "diffstir.identification",
    "diagnose": "diffstir.diagnosis",
    "characterise": "diffstir.behaviour",
    "analyse_mixing": "diffstir.mixing",
    "plan": "diffstir.planning",
    "Newtonian": "diffstir.rheology",
    "PowerLaw": "diffstir.rheology",
    "Carreau": "diffstir.rheology",
    "Cross": "diffstir.rheology",
    "HerschelBulkley": "diffstir.rheology",
    "Bingham": "diffstir.rheology",
    "Tabulated": "diffstir.rheology",
}

__all__ = ["__version__", *_HOMES]


def __getattr__(name: str):
    if name in _HOMES:
        value = getattr(importlib.import_module(_HOMES[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'diffstir' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_HOMES))
