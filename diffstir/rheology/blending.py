"""The Lederer-Roegiers viscosity blending rule (Lederer 1932; Roegiers 1946; reviewed by Zhmud 2014):

    ln η_blend = (φ ln η1 + α (1 − φ) ln η2) / (φ + α (1 − φ)),     α ∈ [0, 1] (empirical),

with φ [1] the volume fraction of fluid 1, the more viscous one. α = 1 is the Arrhenius (log-linear) rule
η1^φ η2^(1−φ); α → 0 leaves η1. Over α ∈ [0, 1] the blend therefore lies in [η1^φ η2^(1−φ), η1], and a measured
blend viscosity η_b inside that range implies

    α = φ ln(η1 / η_b) / ((1 − φ) ln(η_b / η2)).

The paper writes the rule as η1^(αφ) η2^((1−α)(1−φ)), whose exponents do not add up to 1, so its value depends
on the unit of viscosity (Pa·s against mPa·s) and it is not a weighted mean of η1 and η2; diffstir uses the
published form above (docs/mixing.md).
"""

from __future__ import annotations

import math

import numpy as np
import torch


def lederer_roegiers(eta1, eta2, fraction, alpha):
    """η_blend [Pa·s] of fluids of viscosities ``eta1``, ``eta2`` [Pa·s] (numpy arrays or torch tensors) with
    volume fraction ``fraction`` φ [1] of fluid 1 and the empirical ``alpha`` [1]."""
    lib = torch if isinstance(eta1, torch.Tensor) else np
    weight = alpha * (1.0 - fraction)
    return lib.exp((fraction * lib.log(eta1) + weight * lib.log(eta2)) / (fraction + weight))


def blend_range(eta1: float, eta2: float, fraction: float) -> tuple[float, float]:
    """The Lederer-Roegiers blend viscosities [Pa·s] for α = 1 and α = 0: (η1^φ η2^(1−φ), η1)."""
    _check(eta1, eta2, fraction)
    return float(lederer_roegiers(eta1, eta2, fraction, 1.0)), float(eta1)


def implied_alpha(eta_blend: float, eta1: float, eta2: float, fraction: float) -> float:
    """The α [1] for which the rule gives ``eta_blend`` [Pa·s] (module docstring); outside [0, 1] when the blend
    lies outside the rule's range, nan when it is not between η2 and η1."""
    _check(eta1, eta2, fraction)
    if not eta2 < eta_blend < eta1:
        return math.nan
    return fraction * math.log(eta1 / eta_blend) / ((1.0 - fraction) * math.log(eta_blend / eta2))


def _check(eta1: float, eta2: float, fraction: float) -> None:
    if not (eta1 > eta2 > 0):
        raise ValueError(f"mixing.viscosities = [{eta1}, {eta2}] Pa s; expected the more viscous fluid first, both "
                         f"> 0 Pa s")
    if not 0 < fraction < 1:
        raise ValueError(f"mixing.fraction = {fraction}; expected the volume fraction of fluid 1 in (0, 1)")
