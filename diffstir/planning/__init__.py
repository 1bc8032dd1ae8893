"""Stir to learn: the stirring programme that makes a fluid's law identifiable (docs/planning.md).

    from diffstir import plan
    from diffstir.planning import PlanSettings, Prior

    stir = plan(prior=Prior(viscosity=(0.1, 10.0)), settings=PlanSettings(budget=8.0))
    stir.assessment.programme.speeds, stir.write("outputs/plan")

A calibration of the rig on the fitting simulator (``calibration``), the information a programme's speed windows
carry about each law (``information``), the search over programmes (``design``) and the plan's files (``result``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from ..mpm import FINE_STAGE, SimConfig
from ..rig import Rig
from .calibration import Calibration, calibrate, probe_viscosities
from .design import ArmLimits, Assessment, PlanSettings, Planner, Programme, candidates
from .information import Window, WindowErrors, WindowPoint, fisher_information, information_gain, window_points
from .prior import PLAN_LAWS, Prior
from .result import StirPlan

#: How long each calibration stir holds its speed after the ramp [s]: the settling time and three behaviour windows.
CALIBRATION_STEADY_TIME = 0.8
#: The rate [Hz] at which a calibration stir's simulated force is read: its mean |reading| over the steady part does
#: not depend on it, so one calibration serves a sensor of any rate (``PlanSettings.sample_rate`` counts the
#: samples of a window).
CALIBRATION_SAMPLE_RATE = 100.0

__all__ = ["CALIBRATION_SAMPLE_RATE", "CALIBRATION_STEADY_TIME", "ArmLimits", "Assessment", "Calibration", "PLAN_LAWS",
           "PlanSettings", "Planner", "Prior", "Programme", "StirPlan", "Window", "WindowErrors", "WindowPoint",
           "calibrate", "candidates", "fisher_information", "information_gain", "plan", "probe_viscosities",
           "rig_calibration", "window_points"]


def plan(rig: Rig | None = None, prior: Prior | None = None, settings: PlanSettings | None = None, *,
         config: SimConfig = FINE_STAGE, workers: int = 1, cache_dir: str | Path | None = None,
         report: Callable[[tuple], None] | None = None) -> StirPlan:
    """The programme of at most ``settings.budget`` seconds that maximises the expected information about the
    prior's laws in ``rig`` (default: the paper's), on the fitting simulator ``config`` (default: the fit's fine
    stage), beside the single stir at ``settings.baseline_speed``. The rig's calibration runs its simulations in
    ``workers`` processes, once per rig, speeds and simulator (``cache_dir``, ``calibration.calibrate``)."""
    started = time.perf_counter()
    rig, prior, settings = rig or Rig(), prior or Prior(), settings or PlanSettings()
    calibration = rig_calibration(rig, prior, settings, config, workers=workers, cache_dir=cache_dir, report=report)
    planner = Planner(calibration, prior, settings)
    single = Programme.through((settings.baseline_speed,), settings)
    best = planner.best()
    return StirPlan(planner.assess(best), planner.assess(single), calibration, prior, settings,
                    seconds=time.perf_counter() - started)


def rig_calibration(rig: Rig, prior: Prior, settings: PlanSettings, config: SimConfig = FINE_STAGE, *,
                    workers: int = 1, cache_dir: str | Path | None = None,
                    report: Callable[[tuple], None] | None = None) -> Calibration:
    """The calibration ``plan`` uses: ``settings``' allowed speeds and its single speed, on its circle, with probes
    over ``prior``'s viscosities, a ramp for the fastest step from rest and ``CALIBRATION_STEADY_TIME`` at speed."""
    settings.check_rig(rig)
    speeds = tuple(sorted(set(settings.levels()) | {settings.baseline_speed}))
    ramp = settings.arm.ramp_time(max(speeds), settings.min_ramp)
    return calibrate(rig, config, settings.density, settings.radius, speeds, probe_viscosities(prior.viscosity),
                     ramp_time=ramp, steady_time=CALIBRATION_STEADY_TIME, settle_time=settings.settle_time,
                     sample_rate=CALIBRATION_SAMPLE_RATE, workers=workers, cache_dir=cache_dir, report=report)
