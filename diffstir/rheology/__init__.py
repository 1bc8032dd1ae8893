"""Rheology: generalized Newtonian viscosity laws as ``nn.Module``s, flow-curve fitting, and the blending rule of
two fluids' viscosities.

All quantities are SI: shear rate [1/s], shear stress [Pa], viscosity [Pa·s].
"""

from diffstir.rheology.blending import blend_range, implied_alpha, lederer_roegiers
from diffstir.rheology.flow_curve import (
    FlowCurve,
    FlowCurveFit,
    bundled_flow_curves,
    fit_flow_curve,
    load_flow_curves,
    rank_laws,
)
from diffstir.rheology.laws import (
    LAWS,
    Bingham,
    Carreau,
    Cross,
    HerschelBulkley,
    Newtonian,
    PowerLaw,
    RegularisedLaw,
    RheologyLaw,
    Tabulated,
    has_yield_stress,
    make_law,
    within_bounds,
)

__all__ = [
    "LAWS",
    "Bingham",
    "Carreau",
    "Cross",
    "FlowCurve",
    "FlowCurveFit",
    "HerschelBulkley",
    "Newtonian",
    "PowerLaw",
    "RegularisedLaw",
    "RheologyLaw",
    "Tabulated",
    "blend_range",
    "bundled_flow_curves",
    "fit_flow_curve",
    "load_flow_curves",
    "has_yield_stress",
    "implied_alpha",
    "lederer_roegiers",
    "make_law",
    "rank_laws",
    "within_bounds",
]
