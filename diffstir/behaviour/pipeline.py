"""Behaviour classification of one fluid stirred at several speeds: windows, apparent viscosities, class, joint
fit.

Metzner and Otto's effective shear rate is γ̇_eff = k_s U / a with k_s a constant of the stirrer and cup in
laminar flow. Each window measures its own k_s, and these drift with speed (inertia at the faster speeds, the
programme's history); the classification uses their geometric mean k̄_s for every window. The slope of ln η
against ln γ̇ and the Herschel-Bulkley test do not depend on a common factor of the shear rates (it is absorbed by
the intercept and by the consistency k), only the flow curve's position does.

    result = characterise([load_recording("rec/slow"), load_recording("rec/fast")], config=SimConfig(dim=2))
    result.summary()["behaviour"]["class"]
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

from ..density import combined_density
from ..errors import check_choice
from ..fitting import (MODEL_FORCE_ERROR, PROGRAMME_SIMULATIONS, Z95, FitModel, ProgrammeFit, Progress,
                       SpeedWindow, ViscosityPoint, WindowsJob, programme_viscosities, speed_windows, window_event,
                       window_simulations)
from ..mpm import SimConfig
from ..parallel import Workers
from ..recording import Recording, RecordingError
from ..report_files import Report
from ..rheology import has_yield_stress
from .classify import (YIELD_SHARE_SIGMAS, Classification, SlopeEstimate, classify, decide, joint_yield_test,
                       slope_agreement)
from .flow_laws import FlowCurveLaws, flow_curve_laws
from .joint import JointFit, joint_fit, joint_simulations, yield_share
from .report import markdown, plot_all
from .settings import SLOPE_TESTS, BehaviourSettings


@dataclass
class Behaviour(Report):
    """What :func:`characterise` found: ``summary()`` (report.json, SI units), ``report()`` (report.md),
    ``plots(out)`` (viscosity_vs_speed.png, flow_curve.png), ``write(out)`` all of them."""

    density: dict
    points: list[ViscosityPoint]
    used: list[ViscosityPoint]
    metzner_otto: float
    classification: Classification
    joint: JointFit | FlowCurveLaws | None
    seconds: float
    programmes: list[ProgrammeFit] | None = None

    def shear_rates(self, points: list[ViscosityPoint]) -> np.ndarray:
        """γ̇_eff = k̄_s U / a [1/s] of ``points`` with the common Metzner-Otto constant k̄_s."""
        return np.array([self.metzner_otto * p.speed / p.window.recording.rod.radius for p in points])

    def summary(self) -> dict:
        points = [{**p.summary(), "shear_rate": float(g), "classified": any(p is q for q in self.used)}
                  for p, g in zip(self.points, self.shear_rates(self.points))]
        behaviour = self.classification.summary()
        index = self.joint.power_law_slope() if isinstance(self.joint, JointFit) else None
        if index is not None:
            behaviour["slope_check"] = slope_agreement(self.classification.slope, SlopeEstimate(*index))
        return {"behaviour": behaviour, "density": self.density,
                "metzner_otto": {"value": self.metzner_otto, "unit": "1",
                                 "meaning": "effective shear rate = value * rod speed / rod radius, the geometric "
                                            "mean of the windows' measured constants"},
                "points": points,
                "joint_fit": None if self.joint is None else self.joint.summary(), "seconds": self.seconds,
                "programmes": None if self.programmes is None else [p.summary() for p in self.programmes]}

    def report(self) -> str:
        """report.md: the class, its slope and tests, the per-speed points and the joint fit's laws."""
        return markdown(self.summary())

    def plots(self, out: Path) -> dict[str, Path]:
        """viscosity_vs_speed.png and flow_curve.png in ``out``."""
        return plot_all(self, out)


def characterise(recordings: list[Recording], *, config: SimConfig, settings: BehaviourSettings | None = None,
                 density: float | None = None, workers: int = 1, progress: bool = False) -> Behaviour:
    """Classify the fluid of ``recordings`` (one fluid; each recording at one speed or a programme of several).

    Args:
        config: the simulation the windows are fitted on.
        settings: the windows, fits, tests and errors (``BehaviourSettings``; None: its defaults, those of
            ``diffstir-fit experiment=behaviour``). With laws both with and without a yield stress among
            ``settings.joint_models``, the joint fit decides the yield stress (``classify``, 3), counting a yield
            stress that carries more than ``YIELD_SHARE_SIGMAS`` σ_m of the stress at the slowest speed; with the
            power law among them, the report compares its index with the points' slope
            (``classify.slope_agreement``). With ``settings.analysis = "flow_curve"`` the windows are read by
            Newtonian simulations of each whole recording and the class is that of the law the points select
            (``flow_laws``, docs/flow-curve.md).
        density: the fluid's density [kg/m³], used only when no recording has a density block.
        workers: processes that run the recordings' windows side by side (``WindowsJob``: a recording's windows in
            order), then the joint laws (``joint.joint_fit``), or a recording's Newtonian rungs (``flow_curve``);
            1: in this process.
        progress: show a progress bar of the simulations (``fitting.progress``): one task per window and one
            per joint law (``settings.analysis = "flow_curve"``: one per recording).
    """
    started = time.perf_counter()
    if not recordings:
        raise ValueError("behaviour: no recordings; give recordings=[a,b,...] of one fluid")
    settings = BehaviourSettings() if settings is None else settings
    rho = combined_density(recordings, density)
    windows = [speed_windows(rec, tolerance=settings.speed_tolerance, min_duration=settings.min_window,
                             pause_speed=settings.pause_speed)
               for rec in recordings]  # every recording's, before the first simulation
    programme = settings.analysis == "flow_curve"
    if programme:
        expected = {f"programme {k}": PROGRAMME_SIMULATIONS for k, w in enumerate(windows) if w}
    else:
        expected = {label: window_simulations(k > 0, settings.iterations) for recording_windows in windows
                    for k, label in enumerate(w.label for w in recording_windows)}
        expected.update({f"joint {name}": joint_simulations(name, settings.joint_iterations)
                         for name in settings.joint_models})
    with Progress(expected, bar=progress, label="behaviour") as tracker:
        programmes = None
        if programme:
            programmes = programme_fits(windows, config, rho["value"], settings, workers, tracker)
            points = [p for fit in programmes for p in fit.points]
        else:
            jobs = [WindowsJob("windows", str(k), recording_windows, config, rho["value"], settings.iterations,
                               settings.model_error, settings.inertial_error)
                    for k, recording_windows in enumerate(windows) if recording_windows]
            with Workers(min(workers, len(jobs)), partial(window_event, tracker)) as pool:
                points = [p for recording_points in pool.map(jobs) for p in recording_points]
        used = [p for p in points if p.resolvable and math.isfinite(p.log_std) and p.log_std > 0]
        if len({round(p.speed, 6) for p in used}) < 2:
            states = [_window_state(p, used) for p in points]
            capped = "at the viscosity cap" in states
            advice = ["stir faster or at more speeds"] if "not resolved" in states or not capped else []
            if capped and programme:
                advice.append(_ceiling_advice(programmes, config))
            elif capped:
                solver = "" if config.viscous_solver == "implicit" else (
                    " with sim.viscous_solver=implicit, whose step does not shorten with the viscosity")
                advice.append(f"raise sim.viscosity_cap ({config.viscosity_cap:g} Pa s){solver}: the windows at it "
                              "read a fluid at least that thick")
            raise RecordingError("behaviour: fewer than two speeds whose drag the sensor resolves (" + ", ".join(
                f"{p.window.label}: {state}" for p, state in zip(points, states)) + "); " + "; ".join(advice))
        k_s = float(np.exp(np.mean([np.log(p.metzner_otto) for p in used])))
        rates = np.array([k_s * p.speed / p.window.recording.rod.radius for p in used])
        result = classify(rates, [p.viscosity for p in used], [p.total_log_std for p in used],
                          replicates=settings.replicates, seed=settings.seed)
        joint, index, test = None, None, None
        if settings.joint_models and programme:
            joint = flow_curve_laws(used, rates, list(settings.joint_models))
        elif settings.joint_models:
            joint = joint_fit(used, rates, config, rho["value"], list(settings.joint_models),
                              iterations=settings.joint_iterations, workers=workers, model_error=settings.model_error,
                              inertial_error=settings.inertial_error, report=partial(_joint_evaluation, tracker))
            for name in settings.joint_models:
                tracker.finished(f"joint {name}")
            slope = joint.power_law_slope()
            index = None if slope is None else SlopeEstimate(*slope)
        if isinstance(joint, FlowCurveLaws):
            band = (float(rates.min()), float(rates.max()))
            result = result.with_law_families(joint.families(band, float(np.exp(np.mean(np.log(rates))))), joint.bic)
        else:
            if joint is not None:
                test = joint_yield_test(joint.bic, joint.yield_shares(float(rates.min())),
                                        YIELD_SHARE_SIGMAS * settings.model_error)
            result = decide(result, index, test, settings.slope_test)
        tracker.close(f"{result.label} (confidence {result.confidence:.2f})")
    return Behaviour(rho, points, used, k_s, result, joint, time.perf_counter() - started, programmes)


def _ceiling_advice(programmes: list[ProgrammeFit], config: SimConfig) -> str:
    """What lifts the programmes' ceiling: a shorter step where a rung's simulation diverged below the thickest
    rung allowed, else a thicker thickest rung."""
    ceiling = min(fit.ceiling for fit in programmes)
    diverged = sorted({eta for fit in programmes for eta in fit.diverged})
    if diverged:
        rungs = ", ".join(f"{eta:.4g}" for eta in diverged)
        return (f"use a smaller sim.dt_max ({config.dt_max:g} s): the simulations of the {rungs} Pa s rungs "
                f"diverged, so the windows at {ceiling:.4g} Pa s read a fluid at least that thick")
    return (f"raise behaviour.thickest_rung ({ceiling:g} Pa s): the windows at it read a fluid at least that "
            "thick")


def _window_state(point, used: list) -> str:
    """What became of a window's point in the classification: ok, or why it was left out."""
    if any(point is q for q in used):
        return "ok"
    return "at the viscosity cap" if point.capped else "not resolved"


def programme_fits(windows: list[list[SpeedWindow]], config: SimConfig, density: float,
                   settings: BehaviourSettings, workers: int, tracker: Progress) -> list[ProgrammeFit]:
    """Each recording's windows read by simulations of its whole programme (``fitting.programme_viscosities``),
    recording after recording, each one's simulations side by side in ``workers`` processes."""
    fits = []
    with Workers(workers, partial(_programme_evaluation, tracker)) as pool:
        for k, recording_windows in enumerate(windows):
            if recording_windows:
                fit = programme_viscosities(recording_windows, config, density, workers=pool,
                                            model_error=settings.model_error, inertial_error=settings.inertial_error,
                                            thickest_rung=settings.thickest_rung, stage=f"programme {k}")
                tracker.finished(f"programme {k}")
                fits.append(fit)
    return fits


def _programme_evaluation(tracker: Progress, event: tuple) -> None:
    """A programme simulation's event (``fitting.programme``) counted against its recording's task."""
    kind, stage, _key, *data = event
    if kind == "evaluation":
        tracker.evaluation(stage, None, data[1])


def _joint_evaluation(tracker: Progress, event: tuple) -> None:
    """A joint fit's event (``fitting.jobs``) counted against its law's task."""
    kind, _stage, key, *data = event
    if kind == "evaluation":
        law = key.split("/")[0]
        tracker.evaluation(f"joint {law}", law, data[1])


def reclassify(summary: dict, *, slope_test: str = "combined", replicates: int = 200, seed: int = 0,
               model_error: float = MODEL_FORCE_ERROR) -> Classification:
    """The class of a behaviour report (``Behaviour.summary()``, report.json) decided again under ``slope_test``
    without simulating: from its classified points (γ̇ [1/s], η [Pa·s], the standard error of ln η from noise and
    simulator together), the joint power law's n and its 95 % interval, and the joint laws' BIC and parameters
    (their yield stresses' shares of the slowest stress, material above ``YIELD_SHARE_SIGMAS`` × ``model_error``).
    With the report's own test, ``replicates``, ``seed`` and ``model_error`` it gives the report's class and
    confidence (to the rounding of the parameters). A flow-curve report's class is again that of the law its points
    select (``behaviour.flow_laws``: the laws' classes and BICs it holds), whatever ``slope_test``."""
    check_choice("behaviour.slope_test", slope_test, SLOPE_TESTS)
    used = [p for p in summary["points"] if p["classified"]]
    points = classify([p["shear_rate"] for p in used], [p["viscosity"] for p in used],
                      [math.hypot(p["log_std"], p["model_log_std"]) for p in used], replicates=replicates, seed=seed)
    by_laws = summary["behaviour"].get("laws")
    if by_laws is not None:  # the flow-curve analysis: the class of the law the points select (flow_laws)
        return points.with_law_families(by_laws["families"],
                                        {name: law["bic"] for name, law in summary["joint_fit"]["laws"].items()})
    joint, index, test = summary.get("joint_fit"), reported_joint_index(summary), None
    if joint is not None:
        laws = joint["laws"]
        slowest = min(p["shear_rate"] for p in used)
        shares = {name: yield_share(FitModel.named(name, **law["params"]), slowest)
                  for name, law in laws.items() if has_yield_stress(name)}
        test = joint_yield_test({name: law["bic"] for name, law in laws.items()}, shares,
                                YIELD_SHARE_SIGMAS * model_error)
    if slope_test == "joint_index" and index is None:
        raise ValueError("behaviour.slope_test = 'joint_index' reads the joint power law's index; the report has none")
    return decide(points, index, test, slope_test)


def reported_joint_index(summary: dict) -> SlopeEstimate | None:
    """The joint power law's slope n − 1 [1] with the standard error of n [1] (infinite where the recordings do not
    determine n), read off a behaviour report (``Behaviour.summary()``); None without a joint power law. A report
    that states only n's 95 % interval [lo, hi] gives (hi − lo) / (2 z₉₅)."""
    law = (summary.get("joint_fit") or {"laws": {}})["laws"].get("power_law")
    if law is None:
        return None
    if "standard_error" in law:
        std = law["standard_error"]["n"]
    else:
        interval = law["ci95"]["n"]
        std = None if interval is None else (interval[1] - interval[0]) / (2.0 * Z95)
    return SlopeEstimate(law["params"]["n"] - 1.0, math.inf if std is None or not math.isfinite(std) else std)


