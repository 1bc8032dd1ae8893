"""Identify a fluid from a recording: density, every model fitted, uncertainty, the selected law.

    result = identify(load_recording("diffstir/data/examples/carreau_example"), config=SimConfig(dim=2),
                      checkpoint="out/checkpoint.json")
    result.summary()["selected"]

A ladder of Newtonian simulations gives the first viscosity and the stir's effective shear rate (``initial``). The
Newtonian law is fitted first; every other model starts from its fit, and the fits run side by side in ``workers``
processes as soon as their inputs are known (``stages``). An interrupted run resumes from ``checkpoint``: finished
fits are not repeated and a fit under way restarts from its last iterate.
"""

from __future__ import annotations

import json
import math
import time
from functools import partial
from pathlib import Path

import numpy as np

from ..density import density_estimate
from ..errors import OutputError
from ..fitting import (LADDER_VISCOSITIES, MAGNITUDE_STEPS, PROBE_INDEX_STEP, SHEAR_RATE_PROBES, FitModel, FitResult,
                       FitSettings, Identification, MagnitudeJob, Progress, SensorNuisance, StirProblem,
                       ViscosityLadder, Windows, bic, effective_shear_rate, fit_simulations, force_error, laplace,
                       mean_readings_on, mean_stirring_speed, noise_scale, select)
from ..mpm import SimConfig
from ..mpm.config import NUMERICS
from ..parallel import Workers
from ..recording import Recording
from ..recording.digest import recording_digest
from ..report_files import write_text_atomically
from ..rheology import LAWS
from ..slice_correction import slice_correction_table
from .stages import SECANT_STEPS, Plan, Stage

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
            scratch, then refined on ``config`` for ``fit.fine_iterations`` Broyden steps that start from the
            coarse fit and its Jacobian, so the fine resolution costs about one simulation per iteration.
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
    unknown = sorted(set(models) - set(LAWS))
    if unknown:  # before minutes of fitting, not when their turn comes
        raise ValueError(f"model = {unknown}: unknown laws; choose from {sorted(LAWS)} (the corotated baseline is "
                         "fitted with baseline=true)")
    started = time.perf_counter()
    density_report = density_estimate(recording, density)
    windows = Windows.of(recording, settings.window, settings.holdout_fraction)
    windows.dead_start.require_signal()
    problem = StirProblem(recording, config, density_report["value"], windows, corrected=settings.slice_correction)
    names = ["newtonian"] + [m for m in models if m != "newtonian"] + (["corotated"] if baseline else [])
    sensor = SensorNuisance(tuple(settings.sensor_nuisance))
    fingerprint = {"recording": recording_digest(recording), "sensor_nuisance": list(sensor.fitted),
                   "models": names, "window": settings.window, "holdout_fraction": settings.holdout_fraction,
                   "optimizer": settings.optimizer, "max_iterations": settings.max_iterations,
                   **config.force_settings(), "density": density_report["value"],
                   "slice_correction": (slice_correction_table()["coefficients"]
                                        if config.dim == 2 and settings.slice_correction else None),
                   "shear_rate_probes": PROBE_INDEX_STEP,
                   "coarse": (None if coarse is None
                              else {**coarse.force_settings(), "fine_iterations": settings.fine_iterations})}
    state = _load_checkpoint(checkpoint, fingerprint, recording_label(recording), overwrite)

    def save() -> None:
        if checkpoint is not None:
            Path(checkpoint).parent.mkdir(parents=True, exist_ok=True)
            write_text_atomically(checkpoint, json.dumps(state))

    def on_event(event: tuple) -> None:
        """A job's event (``jobs``): progress and TensorBoard, and its last iterate into the checkpoint."""
        kind, stage, name, *data = event
        if kind == "evaluation":
            count, loss = data
            if name.startswith("probe") or name == "magnitude":
                tracker.evaluation("start" if name.startswith("probe") else name)
            else:
                tracker.evaluation(f"{stage}/{name}", name.split("/")[0], loss)
        elif kind == "iteration":
            iteration, loss, theta, params = data
            state["running"].setdefault(stage, {})[name] = theta
            tracker.iteration(f"{stage}/{name}", iteration, loss, params)
            save()

    def start_estimates(stage: Stage, pool: Workers) -> None:
        """The Newtonian ladder, its estimate (the fit's start, the rectifier's input) and γ̇_eff, once."""
        stage_problem = stage.problem
        evaluate = partial(mean_readings_on, pool, stage.name, stage_problem)
        if "ladder" not in state:
            ladder = ViscosityLadder.simulate(stage_problem, evaluate=evaluate)
            eta = ladder.estimate(stage_problem)
            state["ladder"] = {"viscosities": list(ladder.viscosities), "mean_abs": list(ladder.mean_abs),
                               "estimate": eta, "resolves": ladder.resolves(stage_problem.mean_reading()),
                               **stage_problem.config.numerics()}
            save()
        if "effective_shear_rate" not in state:
            state["effective_shear_rate"] = effective_shear_rate(stage_problem, state["ladder"]["estimate"],
                                                                 evaluate=evaluate)
            save()

    def stage_dt(stage: Stage, eta: float) -> float:
        """The stage's time step for the corotated baseline [s]: that of a Newtonian fluid of viscosity ``eta``
        [Pa·s], computed once per stage."""
        if stage.name not in state["dt"]:
            state["dt"][stage.name] = stage.problem.simulator(FitModel.named("newtonian", eta=eta).material
                                                              ).time_step(stage.problem.trajectory)
        return state["dt"][stage.name]

    state.setdefault("dt", {})
    if coarse is None:
        stages = (Stage("fit", problem, settings.max_iterations),)
    else:
        stages = (Stage("coarse", problem.with_config(coarse), settings.max_iterations),
                  Stage("fine", problem, settings.fine_iterations))
    tracker = Progress(_expected_simulations(stages, names, state, size_estimate), bar=progress, log_dir=log_dir)
    with Workers(workers, on_event) as pool:
        start_estimates(stages[0], pool)
        tracker.finished("start")
        plan = Plan(stages, names, ladder_estimate=state["ladder"]["estimate"],
                    shear_rate=state["effective_shear_rate"], optimizer=settings.optimizer, sensor=sensor,
                    stage_dt=stage_dt, done=state["done"], running=state["running"])
        magnitude_pending = False

        def submit_ready() -> None:
            """The fits whose inputs are known, and the magnitude estimate once the last Newtonian fit is."""
            nonlocal magnitude_pending
            for ready in plan.ready():
                tracker.expect(f"{ready.stage}/{ready.key}", fit_simulations(ready.model.size, ready.budget,
                                                                             ready.jacobian is not None),
                               replaces=f"{ready.stage}/{ready.model.name}")
                pool.submit(ready)
            newtonian = plan.fits[stages[-1].name].get("newtonian")
            if size_estimate and newtonian is not None and "magnitude" not in state and not magnitude_pending:
                eta = newtonian.model.params_si()["eta"]
                error = force_error(settings.model_error, problem.slice_correction(newtonian.model.material))
                pool.submit(MagnitudeJob(stages[-1].name, "magnitude", problem, eta, error))
                magnitude_pending = True

        submit_ready()
        for job, result in pool.completed():
            if isinstance(job, MagnitudeJob):
                state["magnitude"] = result.summary()
                tracker.finished("magnitude")
            else:
                plan.finish(job, result)
                tracker.finished(f"{job.stage}/{job.key}")
            save()
            submit_ready()
    fits = plan.final()

    train = problem.train
    residuals = {name: (fit.predicted - problem.measured)[train] for name, fit in fits.items()}
    uncertainty = {name: laplace(fit.model, fit.theta, sensor.projected(fit.jacobian, fit.simulated_readings,
                                                                        problem.times, fit.sensor, train),
                                 residuals[name], fit.simulated_readings[train],
                                 force_error(settings.model_error, problem.slice_correction(fit.model.material)),
                                 viscous_readings=fit.jacobian[train] @ fit.model.stress_direction(),
                                 inertial_error=settings.inertial_error)
                   for name, fit in fits.items()}
    # one sample count for every model, or BIC would compare likelihoods of different data: that of the
    # best-fitting model, whose residuals are the closest to the noise
    best = min(residuals, key=lambda n: float(residuals[n] @ residuals[n]))
    n_effective = uncertainty[best].effective_samples
    bics = {name: bic(r, fits[name].model.size + sensor.size, n_effective) for name, r in residuals.items()}
    laws = [n for n in fits if n != "corotated"]
    chosen = select({n: fits[n].loss for n in laws}, {n: bics[n] for n in laws},
                    {n: fits[n].holdout_loss for n in laws}, settings.selection)
    chosen["bic"] = bics
    tracker.close(f"selected {chosen['selected']}")
    return Identification(recording=recording, problem=problem, density=density_report, fits=fits,
                          uncertainty=uncertainty, effective_shear_rate=float(state["effective_shear_rate"]),
                          selection=chosen, resolvable=_resolvable(problem, fits["newtonian"]),
                          model_error=settings.model_error, inertial_error=settings.inertial_error,
                          seconds=time.perf_counter() - started, preliminary=_preliminary(state["ladder"], problem),
                          magnitude=state.get("magnitude"))


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
    reading's noise level (and the sensor's resolution); and the drag's viscous share e = d ln F / d ln η [1], the
    least-squares slope (J·p)/(p·p) of the Newtonian fit's Jacobian J = d p / d ln η on its readings p. A drag
    F = F_v + F_i with F_v ∝ η has e = F_v / F; below ``VISCOUS_SHARE_FLOOR`` the stir is inertia-dominated: a
    relative error ε_i of the simulated inertial part moves ln η by about ε_i (1 − e) / e, which
    ``uncertainty.laplace`` holds (``inertial_error``)."""
    jacobian, readings = newtonian.jacobian[problem.train, 0], newtonian.simulated_readings[problem.train]
    change = float(np.sqrt(np.mean((jacobian * math.log(2.0)) ** 2)))
    noise = noise_scale(problem.measured, problem.recording.sensor.resolution)
    floor = max(noise, problem.recording.sensor.resolution or 0.0)
    norm = float(readings @ readings)
    share = float(jacobian @ readings) / norm if norm > 0 else 0.0
    return {"viscosity": bool(change > floor), "reading_change_per_doubling": change, "noise": float(noise),
            "unit": "N", "viscous_share": share, "inertia_dominated": bool(share < VISCOUS_SHARE_FLOOR)}


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
                budget = stage.iterations + (SECANT_STEPS if index > 0 and size == 1 else 0)
                expected[f"{stage.name}/{name}"] = fit_simulations(size, budget, index > 0)
    if size_estimate and "magnitude" not in state:
        expected["magnitude"] = MAGNITUDE_STEPS + 1
    return expected


def recording_label(recording: Recording) -> str:
    """How a checkpoint names its recording: its directory (or name)."""
    return str(recording.path) if recording.path else (recording.name or "(unnamed)")


def _load_checkpoint(path: str | Path | None, settings: dict, label: str, overwrite: bool) -> dict:
    """The state saved in the checkpoint ``path`` when it holds a fit of the same recording (``settings["recording"]``,
    its digest) with the same ``settings``; a fresh state when there is none or with ``overwrite``. Otherwise an
    ``OutputError`` in one line."""
    fresh = {"settings": settings, "recording": label, "done": {}, "running": {}}
    if path is None or overwrite or not Path(path).exists():
        return fresh
    try:
        state = json.loads(Path(path).read_text())
    except json.JSONDecodeError as exc:
        raise OutputError(f"{path}: the checkpoint is not valid JSON ({exc}); use another out= or "
                          "overwrite=true") from None
    saved = state.get("settings", {}) if isinstance(state, dict) else {}
    if saved.get("recording") != settings["recording"]:
        digest = saved.get("recording") or "none"
        raise OutputError(f"{path} holds a fit of recording {state.get('recording', '(unknown)')} (sha256 "
                          f"{digest[:12]}…), not of {label} (sha256 {settings['recording'][:12]}…); use another "
                          "out= or overwrite=true")
    changed = sorted(k for k in settings if saved.get(k) != settings[k])
    if changed:
        raise OutputError(f"{path}: the checkpoint was written with other settings ({', '.join(changed)}); use "
                          "another out= or overwrite=true")
    return state
