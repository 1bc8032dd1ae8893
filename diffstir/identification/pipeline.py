"""Identify a fluid from a recording: density, every model fitted, uncertainty, the selected law.

    result = identify(load_recording("diffstir/data/examples/carreau_example"), config=FINE_STAGE,
                      coarse=COARSE_STAGE, checkpoint="out/checkpoint.json")
    result.write("out/")          # report.json, report.md, plots

A ladder of Newtonian simulations gives the first viscosity and the stir's effective shear rate (``initial``). The
Newtonian law is fitted first; every other model starts from its fit, and the fits run side by side in ``workers``
processes as soon as their inputs are known (``stages``, ``FitRun``). Each fit's intervals (``quantify``) and the
selection among the laws (``select_law``) follow. An interrupted run resumes from ``checkpoint``
(``checkpoint.Checkpoint``): finished fits are not repeated and a fit under way restarts from its last iterate.
"""

from __future__ import annotations

import math
import time
from functools import partial
from pathlib import Path

import numpy as np

from ..density import density_estimate
from ..fitting import (LADDER_VISCOSITIES, MAGNITUDE_STEPS, SHEAR_RATE_PROBES, FitModel, FitResult,
                       FitSettings, Identification, MagnitudeJob, Progress, SensorNuisance, StirProblem, Uncertainty,
                       ViscosityLadder, Windows, bic, effective_shear_rate, force_error, laplace,
                       mean_readings_on, mean_stirring_speed, noise_scale, select)
from ..mpm import SimConfig
from ..mpm.config import NUMERICS
from ..parallel import Workers
from ..recording import Recording, RecordingError
from ..rheology import LAWS
from .checkpoint import Checkpoint, fingerprint, recording_label
from .stages import Plan, Stage, stage_simulations

DEFAULT_MODELS = ("newtonian", "carreau", "cross", "herschel_bulkley")


def identify(recording: Recording, models=DEFAULT_MODELS, *, config: SimConfig, fit: FitSettings | None = None,
             coarse: SimConfig | None = None, density: float | None = None, baseline: bool = True,
             checkpoint: str | Path | None = None, progress: bool = True, log_dir: str | Path | None = None,
             size_estimate: bool = True, workers: int = 1, overwrite: bool = False) -> Identification:
    """Fit every model in ``models`` (and the corotated baseline) to ``recording``; see the module docstring.

    Args:
        recording: a loaded recording.
        models: law names (``diffstir.rheology.LAWS``); the Newtonian law is always fitted first.
        config: the simulator's resolution and numerics for fitting (the fine stage, with ``coarse``).
        fit: how each law is fitted, its intervals and the selection (``FitSettings``; None: its defaults, those
            of ``diffstir-fit``).
        coarse: a coarser, faster simulation to fit on first (coarse-to-fine): every model is fitted there from
            scratch, then refined on ``config`` from the coarse fit in at most ``fit.fine_iterations`` simulations
            after a Jacobian by forward differences there (a one-parameter model reuses the coarse Jacobian and
            takes two more secant steps; ``stages``).
        density: the fluid's density [kg/m³]; required when the recording has no density block, otherwise the
            Archimedes estimate is used and this is ignored.
        baseline: also fit the paper's corotated baseline.
        checkpoint: a JSON file to resume from and save to after every iteration. It holds the recording's
            content digest (``recording.digest``) and the settings; a checkpoint of another recording or of other
            settings is refused (``OutputError``) unless ``overwrite``.
        progress: show a progress bar.
        log_dir: TensorBoard log directory (None: no logs).
        size_estimate: also estimate the Newtonian viscosity from the size of the reading (``magnitude``), beside
            the fits; a caller that reads only the fits (the diagnosis) saves its simulations with False.
        workers: processes that run the fits side by side (1: in this process).
        overwrite: start afresh, replacing a checkpoint of another recording or of other settings.
    """
    settings = FitSettings() if fit is None else fit
    names = model_names(models, baseline)
    started = time.perf_counter()
    density_report = density_estimate(recording, density)
    windows = Windows.of(recording, settings.window, settings.holdout_fraction)
    windows.dead_start.require_signal()
    problem = StirProblem(recording, config, density_report["value"], windows, corrected=settings.slice_correction)
    sensor = SensorNuisance(tuple(settings.sensor_nuisance))
    saved = Checkpoint.open(checkpoint, fingerprint(problem, names, settings, sensor, coarse),
                            recording_label(recording), overwrite)
    if coarse is None:
        stages = (Stage("fit", problem, settings.max_iterations),)
    else:
        stages = (Stage("coarse", problem.with_config(coarse), settings.max_iterations),
                  Stage("fine", problem, settings.fine_iterations))
    tracker = Progress(_expected_simulations(stages, names, saved.state, size_estimate), bar=progress,
                       log_dir=log_dir)
    fits = FitRun(stages, names, settings, sensor, saved, tracker, size_estimate).fits(workers)
    uncertainty = quantify(problem, fits, sensor, settings)
    selection = select_law(problem, fits, uncertainty, sensor, settings.selection)
    tracker.close(f"selected {selection['selected']}")
    state = saved.state
    return Identification(recording=recording, problem=problem, density=density_report, fits=fits,
                          uncertainty=uncertainty, effective_shear_rate=float(state["effective_shear_rate"]),
                          selection=selection, resolvable=_resolvable(problem, fits["newtonian"]),
                          model_error=settings.model_error, inertial_error=settings.inertial_error,
                          seconds=time.perf_counter() - started, preliminary=_preliminary(state["ladder"], problem),
                          magnitude=state.get("magnitude"))


def model_names(models, baseline: bool) -> list[str]:
    """The models an identification fits, in order: the Newtonian law first, the other laws of ``models``, the
    corotated baseline last when ``baseline``. ValueError for a name that is not a law, before any fitting."""
    unknown = sorted(set(models) - set(LAWS))
    if unknown:
        raise ValueError(f"model = {unknown}: unknown laws; choose from {sorted(LAWS)} (the corotated baseline is "
                         "fitted with baseline=true)")
    return ["newtonian"] + [m for m in models if m != "newtonian"] + (["corotated"] if baseline else [])


class FitRun:
    """The fits of an identification, run on ``Workers``: the Newtonian ladder and γ̇_eff on the first stage, then
    every model on every stage as ``Plan`` hands them out, and the viscosity from the reading's size once the last
    stage's Newtonian fit is known (``size_estimate``). Every event goes to the progress ``tracker`` and every
    iterate into the ``checkpoint``, from which an interrupted run resumes."""

    def __init__(self, stages: tuple[Stage, ...], names: list[str], settings: FitSettings, sensor: SensorNuisance,
                 checkpoint: Checkpoint, tracker: Progress, size_estimate: bool):
        self.stages, self.names, self.settings, self.sensor = stages, names, settings, sensor
        self.checkpoint, self.state, self.tracker = checkpoint, checkpoint.state, tracker
        self.size_estimate, self.magnitude_pending = size_estimate, False

    def fits(self, workers: int) -> dict[str, FitResult]:
        """Every model's fit on the last stage, by name, run in ``workers`` processes (1: in this one)."""
        with Workers(workers, self.on_event) as pool:
            self.start_estimates(pool)
            self.tracker.finished("start")
            plan = Plan(self.stages, self.names, ladder_estimate=self.state["ladder"]["estimate"],
                        shear_rate=self.state["effective_shear_rate"], optimizer=self.settings.optimizer,
                        sensor=self.sensor, stage_dt=self.stage_dt, done=self.state["done"],
                        running=self.state["running"])
            self.submit_ready(plan, pool)
            for job, result in pool.completed():
                if isinstance(job, MagnitudeJob):
                    self.state["magnitude"] = result.summary()
                    self.tracker.finished("magnitude")
                else:
                    plan.finish(job, result)
                    self.tracker.finished(f"{job.stage}/{job.key}")
                self.checkpoint.save()
                self.submit_ready(plan, pool)
        return plan.final()

    def on_event(self, event: tuple) -> None:
        """A job's event (``jobs``): progress and TensorBoard, and its last iterate into the checkpoint."""
        kind, stage, name, *data = event
        if kind == "evaluation":
            count, loss = data
            if name.startswith("probe") or name == "magnitude":
                self.tracker.evaluation("start" if name.startswith("probe") else name)
            else:
                self.tracker.evaluation(f"{stage}/{name}", name.split("/")[0], loss)
        elif kind == "iteration":
            iteration, loss, theta, params = data
            self.state["running"].setdefault(stage, {})[name] = theta
            self.tracker.iteration(f"{stage}/{name}", iteration, loss, params)
            self.checkpoint.save()

    def start_estimates(self, pool: Workers) -> None:
        """The Newtonian ladder, its estimate (the fit's start, the rectifier's input) and γ̇_eff on the first
        stage, once."""
        stage = self.stages[0]
        problem = stage.problem
        evaluate = partial(mean_readings_on, pool, stage.name, problem)
        if "ladder" not in self.state:
            ladder = ViscosityLadder.simulate(problem, evaluate=evaluate)
            self.state["ladder"] = {"viscosities": list(ladder.viscosities), "mean_abs": list(ladder.mean_abs),
                                    "estimate": ladder.estimate(problem),
                                    "resolves": ladder.resolves(problem.mean_reading()),
                                    **problem.config.numerics()}
            self.checkpoint.save()
        estimate, cap = self.state["ladder"]["estimate"], min(s.problem.config.viscosity_cap for s in self.stages)
        if estimate > cap:  # every law's reading stops thickening at the cap: no fit could reach the recording
            raise RecordingError(
                f"{problem.recording.source('csv')}: the stir reads like a Newtonian fluid of about "
                f"{estimate:.3g} Pa s (the Newtonian ladder), above sim.viscosity_cap ({cap:g} Pa s), where the "
                "simulated fluid stops thickening: raise sim.viscosity_cap with sim.viscous_solver=implicit, or stir "
                "at several speeds and analyse with experiment=flow_curve, whose rungs go to behaviour.thickest_rung")
        if "effective_shear_rate" not in self.state:
            self.state["effective_shear_rate"] = effective_shear_rate(problem, self.state["ladder"]["estimate"],
                                                                      evaluate=evaluate)
            self.checkpoint.save()

    def stage_dt(self, stage: Stage, eta: float) -> float:
        """The stage's time step for the corotated baseline [s]: that of a Newtonian fluid of viscosity ``eta``
        [Pa·s], computed once per stage."""
        if stage.name not in self.state["dt"]:
            material = FitModel.named("newtonian", eta=eta).material
            self.state["dt"][stage.name] = stage.problem.simulator(material).time_step(stage.problem.trajectory)
        return self.state["dt"][stage.name]

    def submit_ready(self, plan: Plan, pool: Workers) -> None:
        """Hand out the fits whose inputs are known, and the magnitude estimate once the last stage's Newtonian
        fit is."""
        for ready in plan.ready():
            self.tracker.expect(f"{ready.stage}/{ready.key}", ready.simulations,
                                replaces=f"{ready.stage}/{ready.model.name}")
            pool.submit(ready)
        last = self.stages[-1]
        newtonian = plan.fits[last.name].get("newtonian")
        if self.size_estimate and newtonian is not None and "magnitude" not in self.state \
                and not self.magnitude_pending:
            eta = newtonian.model.params_si()["eta"]
            error = force_error(self.settings.model_error, last.problem.slice_correction(newtonian.model.material))
            pool.submit(MagnitudeJob(last.name, "magnitude", last.problem, eta, error, self.settings.inertial_error))
            self.magnitude_pending = True


def quantify(problem: StirProblem, fits: dict[str, FitResult], sensor: SensorNuisance,
             settings: FitSettings) -> dict[str, Uncertainty]:
    """Each fit's intervals (``fitting.laplace``) on ``problem``'s fitted samples: its Jacobian with the sensor's
    nuisances profiled out, the simulator's force error (``settings.model_error`` and the slice correction's) and
    the inertial part's (``settings.inertial_error``)."""
    train = problem.train
    return {name: laplace(fit.model, fit.theta, sensor.projected(fit.jacobian, fit.simulated_readings,
                                                                 problem.times, fit.sensor, train),
                          (fit.predicted - problem.measured)[train], fit.simulated_readings[train],
                          force_error(settings.model_error, problem.slice_correction(fit.model.material)),
                          viscous_readings=fit.jacobian[train] @ fit.model.stress_direction(),
                          inertial_error=settings.inertial_error)
            for name, fit in fits.items()}


def select_law(problem: StirProblem, fits: dict[str, FitResult], uncertainty: dict[str, Uncertainty],
               sensor: SensorNuisance, criterion: str) -> dict:
    """The selection among the laws (the baseline left out) by ``criterion`` (``fitting.select``), with every
    model's BIC under ``"bic"``. One sample count serves every model, or BIC would compare likelihoods of
    different data: the effective samples of the best-fitting model, whose residuals are the closest to the
    noise."""
    residuals = {name: (fit.predicted - problem.measured)[problem.train] for name, fit in fits.items()}
    best = min(residuals, key=lambda n: float(residuals[n] @ residuals[n]))
    n_effective = uncertainty[best].effective_samples
    bics = {name: bic(r, fits[name].model.size + sensor.size, n_effective) for name, r in residuals.items()}
    laws = [n for n, f in fits.items() if not f.model.is_baseline]
    chosen = select({n: fits[n].loss for n in laws}, {n: bics[n] for n in laws},
                    {n: fits[n].holdout_loss for n in laws}, criterion)
    chosen["bic"] = bics
    return chosen


def _preliminary(ladder: dict, problem: StirProblem) -> dict:
    """The ladder's Newtonian-equivalent viscosity and the stir's mean speed: the rectifier's inputs."""
    return {"viscosity": ladder["estimate"], "mean_stirring_speed": mean_stirring_speed(problem),
            "resolves": ladder["resolves"], "units": {"viscosity": "Pa s", "mean_stirring_speed": "m/s"},
            "estimator": {"name": "newtonian_ladder", **{k: ladder.get(k) for k in NUMERICS},
                          "probes": ladder["viscosities"], "mean_abs": ladder["mean_abs"]}}


#: The viscous share of the drag below which the stir is reported inertia-dominated [1]: the part of the force
#: that scales with η is then smaller than the part that does not.
VISCOUS_SHARE_FLOOR = 0.5


def _resolvable(problem: StirProblem, newtonian: FitResult) -> dict:
    """Whether the sensor resolves the viscosity: the rms change of the reading for a factor 2 in η, against the
    larger of the reading's noise level and the sensor's resolution (``floor`` [N]); and the drag's viscous share
    e = d ln F / d ln η [1], the least-squares slope (J·p)/(p·p) of the Newtonian fit's Jacobian J = d p / d ln η
    on its readings p. A drag F = F_v + F_i with F_v ∝ η has e = F_v / F; below f = ``VISCOUS_SHARE_FLOOR`` the stir
    is inertia-dominated: a relative error ε_i of the simulated inertial part moves ln η by about ε_i (1 − e) / e,
    which ``uncertainty.laplace`` holds (``inertial_error``).

    For an inertia-dominated stir it also names the slower one that would not be: with F_v ∝ U and F_i ∝ U² (a
    steady stir at mean speed U [m/s]), F_i / F_v = (1 − e) / e scales as U, so the viscous share reaches f at
    ``viscous_speed`` = U e (1 − f) / ((1 − e) f) [m/s], where the change per doubling is the present one times
    ``viscous_speed`` / U (F_v ∝ U) and ``viscous_speed_resolves`` says whether it stays above ``floor``."""
    jacobian, readings = newtonian.jacobian[problem.train, 0], newtonian.simulated_readings[problem.train]
    change = float(np.sqrt(np.mean((jacobian * math.log(2.0)) ** 2)))
    noise = noise_scale(problem.measured, problem.recording.sensor.resolution)
    floor = max(noise, problem.recording.sensor.resolution or 0.0)
    norm = float(readings @ readings)
    share = float(jacobian @ readings) / norm if norm > 0 else 0.0
    resolvable = {"viscosity": bool(change > floor), "reading_change_per_doubling": change, "noise": float(noise),
                  "floor": float(floor), "unit": "N", "viscous_share": share,
                  "inertia_dominated": bool(share < VISCOUS_SHARE_FLOOR)}
    if 0.0 < share < VISCOUS_SHARE_FLOOR:
        speed = mean_stirring_speed(problem)
        ratio = share * (1.0 - VISCOUS_SHARE_FLOOR) / ((1.0 - share) * VISCOUS_SHARE_FLOOR)
        resolvable.update(viscous_speed=speed * ratio, viscous_speed_change_per_doubling=change * ratio,
                          viscous_speed_resolves=bool(change * ratio > floor))
    return resolvable


def _expected_simulations(stages: tuple[Stage, ...], names: list[str], state: dict, size_estimate: bool
                          ) -> dict[str, int]:
    """The simulations each task of an identification is expected to spend (``progress``), what the checkpoint
    ``state`` holds left out: the start (ladder and shear-rate probes), each model's fit on each stage (one start,
    revised when its jobs are handed out) and the magnitude estimate."""
    expected = {"start": (0 if "ladder" in state else len(LADDER_VISCOSITIES))
                + (0 if "effective_shear_rate" in state else SHEAR_RATE_PROBES)}
    for index, stage in enumerate(stages):
        for name in names:
            if name not in state["done"].get(stage.name, {}):
                size = 1 if name == "corotated" else FitModel.named(name).size
                expected[f"{stage.name}/{name}"] = stage_simulations(stages, index, size)
    if size_estimate and "magnitude" not in state:
        expected["magnitude"] = MAGNITUDE_STEPS + 1
    return expected
