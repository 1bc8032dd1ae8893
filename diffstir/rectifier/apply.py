"""Applying a trained rectifier to an identification's preliminary estimate, without silent extrapolation.

The refined viscosity is given only when the recording resolves viscosity, the preliminary estimate was made with
the simulator numerics the rectifier was trained on (``SimConfig.numerics``: resolution, sound speed, FLIP share,
volume relaxation), the rectifier lowers the error on its held-out fluids (``training.held_out_verdict``, saved
with the checkpoint), and every input lies inside the training range; otherwise the value is null and ``note``
says why.
"""

from __future__ import annotations

from pathlib import Path

import torch

from ..mpm.config import FORMER_NUMERICS, NUMERICS
from .model import Rectifier
from .training import RectifierModule


def load_rectifier(path: str | Path) -> tuple[Rectifier, dict]:
    """The rectifier of a Lightning checkpoint written by ``diffstir-train-rectifier``, and its metadata."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no rectifier checkpoint (train one with diffstir-train-rectifier, or set "
                                "rectifier.checkpoint=null to skip refinement)")
    module = RectifierModule.load_from_checkpoint(str(path), map_location="cpu", weights_only=True)
    return module.rectifier.eval(), dict(module.hparams.metadata or {})


def refine(rectifier: Rectifier, metadata: dict, preliminary: dict, density: float, checkpoint: str) -> dict:
    """The report's ``apparent_viscosity.refined``: {value [Pa·s] or None, preliminary, inputs, note, ...}.

    ``preliminary`` is ``Identification.preliminary``; ``density`` [kg/m³] the density estimate."""
    available = {"mean_stirring_speed": preliminary["mean_stirring_speed"],
                 "preliminary_viscosity": preliminary["viscosity"], "density_estimate": density}
    inputs = {name: available[name] for name in rectifier.inputs}
    out = {"value": None, "unit": "Pa s", "preliminary": preliminary["viscosity"], "inputs": inputs,
           "checkpoint": checkpoint, "note": ""}
    trained = {**FORMER_NUMERICS, **metadata.get("estimator", {})}
    used = {**FORMER_NUMERICS, **preliminary["estimator"]}
    mismatched = [k for k in NUMERICS if trained.get(k) != used.get(k)]
    if mismatched:
        made = ", ".join(f"{k}={used.get(k)}" for k in mismatched)
        taught = ", ".join(f"{k}={trained.get(k)}" for k in mismatched)
        out["note"] = (f"not refined: the preliminary estimate was made with {made}, the rectifier was trained on "
                       f"{taught}")
        return out
    if not preliminary["resolves"]:
        out["note"] = "not refined: the force does not resolve viscosity (not identifiable from this recording)"
        return out
    verdict = metadata.get("held_out")
    if verdict is None:
        out["note"] = ("not refined: the checkpoint records no held-out verdict; retrain it with "
                       "diffstir-train-rectifier to get one")
        return out
    if not verdict["applies"]:
        out["note"] = f"not refined: the rectifier {verdict['reason']}"
        return out
    x = torch.tensor([list(inputs.values())], dtype=torch.float32)
    outside = rectifier.outside_range(x[0])
    if outside:
        out["note"] = "not refined (no extrapolation): " + "; ".join(outside)
        return out
    with torch.no_grad():
        out["value"] = float(rectifier(x)[0])
    out["note"] = "refined by the rectifier"
    return out
