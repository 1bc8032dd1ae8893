"""Mixing analysis of one recording (the paper's Fig. 6): the viscosity's time course with its band, the time to
homogeneity, and the blend viscosity against the Lederer-Roegiers range.

    result = analyse_mixing(load_recording("rec/syrup_water"), config=COARSE_STAGE,
                            settings=MixingSettings(viscosities=[1.0, 0.1], fraction=0.5))
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..density import combined_density
from ..fitting import ViscosityPoint
from ..mpm import SimConfig
from ..recording import Recording
from ..report_files import Report
from ..rheology.blending import blend_range, implied_alpha
from .report import markdown, plot_all
from .settings import MixingSettings
from .track import Approach, fit_approach, time_windows, track_viscosity


@dataclass
class Mixing(Report):
    """What :func:`analyse_mixing` found: ``summary()`` (report.json, SI units), ``report()`` (report.md),
    ``plots(out)`` (time_course.png), ``write(out)`` all of them."""

    density: dict
    points: list[ViscosityPoint]
    approach: Approach
    viscosities: tuple[float, float]
    fraction: float
    seconds: float

    @property
    def times(self) -> np.ndarray:
        """The windows' mid-times [s]."""
        return np.array([0.5 * (p.window.start + p.window.end) for p in self.points])

    def summary(self) -> dict:
        eta1, eta2 = self.viscosities
        low, high = blend_range(eta1, eta2, self.fraction)
        a = self.approach
        approach = a.summary()
        alpha = [implied_alpha(v, eta1, eta2, self.fraction) for v in (a.plateau, *a.plateau_ci95)]
        return {"mixing": {
            "time_course": [{"time": float(t), **p.summary()} for t, p in zip(self.times, self.points)],
            "approach": approach,
            "blend_viscosity": a.plateau, "blend_viscosity_ci95": list(a.plateau_ci95),
            "homogeneity_time": a.homogeneity_time,
            "homogeneity_time_ci95": approach["homogeneity_time_ci95"],
            "lederer_roegiers": {"viscosities": [eta1, eta2], "fraction": self.fraction,
                                 "range": [low, high], "range_alpha": [1.0, 0.0],
                                 "blend_in_range": bool(low <= a.plateau <= high),
                                 "implied_alpha": None if np.isnan(alpha[0]) else alpha[0],
                                 "implied_alpha_ci95": [None if np.isnan(v) else v for v in sorted(alpha[1:])],
                                 "rule": "ln eta = (phi ln eta1 + alpha (1 - phi) ln eta2) / (phi + alpha (1 - phi))"},
            "units": {"time": "s", "viscosity": "Pa s", "homogeneity_time": "s"}},
            "density": self.density, "seconds": self.seconds}

    def report(self) -> str:
        """report.md: the blend's viscosity, the time to homogeneity, the Lederer-Roegiers range, the course."""
        return markdown(self.summary())

    def plots(self, out: Path) -> dict[str, Path]:
        """time_course.png in ``out``."""
        return plot_all(self, out)


def analyse_mixing(recording: Recording, *, config: SimConfig, settings: MixingSettings, density: float | None = None,
                   progress: bool = False) -> Mixing:
    """Track the apparent viscosity of ``recording`` over ``settings.window``-second windows, fit its approach to a
    plateau and compare the plateau with the Lederer-Roegiers range of the components' ``settings.viscosities``
    (η1 > η2) [Pa·s] at volume fraction ``settings.fraction`` φ [1] of fluid 1. ``density`` [kg/m³]: used only
    without a density block. ``settings.model_error``: the relative force error σ_m of ``config``
    (``fitting.window_viscosity``); the plateau's interval carries it as read in the last window, where the course
    ends. ``progress``: show a progress bar of the simulations (``track_viscosity``)."""
    started = time.perf_counter()
    eta1, eta2 = settings.viscosities
    windows = time_windows(recording, settings.window)  # the recording holds a time course, before any simulation
    rho = combined_density([recording], density)
    points = track_viscosity(windows, config, rho["value"], iterations=settings.iterations,
                             model_error=settings.model_error, progress=progress)
    times = [0.5 * (p.window.start + p.window.end) for p in points]
    approach = fit_approach(times, [p.viscosity for p in points], [p.log_std for p in points],
                            systematic=points[-1].model_log_std)
    return Mixing(rho, points, approach, (eta1, eta2), float(settings.fraction), time.perf_counter() - started)
