"""Mixing analysis: the apparent viscosity of two fluids being stirred together, over time, its plateau and the
Lederer-Roegiers blending rule (the paper's Fig. 6). See docs/mixing.md.
"""

from .analysis import Mixing, analyse_mixing, write_mixing_report
from .rule import blend_range, implied_alpha, lederer_roegiers
from .track import Approach, fit_approach, time_windows, track_viscosity

__all__ = ["Approach", "Mixing", "analyse_mixing", "blend_range", "fit_approach", "implied_alpha",
           "lederer_roegiers", "time_windows", "track_viscosity", "write_mixing_report"]
