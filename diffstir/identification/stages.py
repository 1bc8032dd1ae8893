"""Which fits an identification needs, in which order: every model on every stage (coarse, then fine), as jobs.

A model's fit on a stage needs (``Plan.inputs_ready``):

- the Newtonian law on the first stage: the ladder's estimate only;
- any model on a later stage: its own fit on the stage before (its start, and a one-parameter model's Jacobian);
- any other model: the Newtonian fit on the same stage (its start on the first stage, and on every stage the fit it
  must not end above).

On the first stage a law that contains the Newtonian one starts from its typical shape (``initial_models``); on a
later stage every model starts from its own fit on the stage before. If a law's kept fit on a stage ends above that
stage's Newtonian fit, it is fitted once more there from its Newtonian embedding (``NEWTONIAN_START``) and the
lower loss kept, so that no law ends above the law it contains. The embedding is a fallback, not a rival start:
offered beside the typical shape on every first stage, the coarse grid's lower loss chose a sharper Carreau corner
on both Carreau fluids of the 3-D-truth benchmark, whose apparent viscosity then read 24 and 29 % high
(docs/accuracy.md).

On a later stage a law of several parameters computes its Jacobian there by forward differences at its start and
then takes Broyden steps from it; the coarse stage's Jacobian misstates how the fine stage's readings trade one
parameter for another (its flow index against its consistency), and Broyden's updates learn only along the steps
taken, so from the coarse Jacobian the fine steps fall short of the fine stage's own optimum (docs/identification.md,
step 5). A one-parameter model (the Newtonian law, the corotated baseline) keeps the coarse Jacobian: its Broyden
steps are secant steps, exact in one dimension.

``Plan.ready`` returns the fits whose inputs are known as ``FitJob``s, one per start, so that the starts of a
yield-stress law run side by side too; ``Plan.finish`` records a job's fit and keeps a model's lowest-loss start.
The checkpoint (``done``, ``running``) holds each finished fit by stage and by job key, and a model's kept fit by
its name, so an interrupted identification restores what it finished and resumes each job from its last iterate.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from ..fitting import (FitJob, FitModel, FitResult, SensorNuisance, StirProblem, fit_simulations, initial_models,
                       newtonian_embedding)

#: The key suffix of a fit from the Newtonian embedding, run when a law's kept fit on a stage ends above the
#: stage's Newtonian fit (module docstring).
NEWTONIAN_START = "newtonian_start"

#: Fine-stage evaluations a one-parameter model (the Newtonian law, the corotated baseline) gets beyond the
#: stage's iterations: its Broyden steps are secant steps, cheap, and needed where inertia flattens the loss (a
#: small d ln F / d ln η at Re ≈ 25 and above), where one step from the coarse optimum can run to the trust
#: region's edge.
SECANT_STEPS = 2
SUBSTEP_COST = 0.05  # a shear-stress substep over a whole step: 0.05 of a projection step, about 0.15 of a
#                      compressible one on the 2-D slice (scripts/viscous_substeps_study.py, docs/validation.md)


@dataclass(frozen=True)
class Stage:
    """One resolution of an identification: its name (``"fit"``, ``"coarse"``, ``"fine"``), the problem simulated
    there and the optimiser's iterations per model there."""

    name: str
    problem: StirProblem
    iterations: int


class Plan:
    """The fits of ``names`` (the Newtonian law first) on ``stages``, coarsest first.

    Args:
        ladder_estimate: the Newtonian law's start on the first stage [Pa·s].
        shear_rate: the stir's effective shear rate γ̇_eff [1/s], where the other laws' starts match the Newtonian
            fit.
        stage_dt: the corotated baseline's fixed time step [s] on a stage, given the Newtonian viscosity [Pa·s] it
            is taken at (1 Pa·s on the first stage, the Newtonian fit of the stage before on a later one).
        done, running: the checkpoint's finished fits and last iterates by stage and key, updated in place.
    """

    def __init__(self, stages: tuple[Stage, ...], names: list[str], *, ladder_estimate: float, shear_rate: float,
                 optimizer: str, sensor: SensorNuisance, stage_dt: Callable[[Stage, float], float],
                 done: dict, running: dict):
        self.stages, self.names = stages, names
        self.ladder_estimate, self.shear_rate = ladder_estimate, shear_rate
        self.optimizer, self.sensor, self.stage_dt = optimizer, sensor, stage_dt
        self.done, self.running = done, running
        self.fits: dict[str, dict[str, FitResult]] = {stage.name: {} for stage in stages}
        self.starts: dict[tuple[str, str], dict[str, FitResult | None]] = {}  # (stage, model) -> key -> fit
        self.queued: list[FitJob] = []  # Newtonian starts that ``finish`` asked for, for ``ready`` to hand out

    def final(self) -> dict[str, FitResult]:
        """Every model's fit on the last stage, in ``names``' order."""
        last = self.fits[self.stages[-1].name]
        missing = [n for n in self.names if n not in last]
        if missing:
            raise RuntimeError(f"the fits of {missing} on stage {self.stages[-1].name!r} never became ready")
        return {name: last[name] for name in self.names}

    def ready(self) -> list[FitJob]:
        """The jobs whose inputs are known and that were not handed out yet; fits the checkpoint holds are
        restored instead, which may make more jobs ready."""
        jobs: list[FitJob] = []
        restored = True
        while restored:
            restored = False
            for index, stage in enumerate(self.stages):
                for name in self.names:
                    if (stage.name, name) in self.starts or not self.inputs_ready(index, name):
                        continue
                    saved = self.done.get(stage.name, {}).get(name)
                    if saved is not None:
                        self.starts[(stage.name, name)] = {}
                        self.fits[stage.name][name] = restore(name, saved, stage.problem, self._dt(index, name))
                        restored = True
                        continue
                    new = self._jobs(index, stage, name)
                    self.starts[(stage.name, name)] = {job.key: None for job in new}
                    for job in new:
                        saved = self.done.get(stage.name, {}).get(job.key)
                        if saved is None:
                            jobs.append(job)
                        else:  # one start of several finished before the interruption
                            self.finish(job, restore(name, saved, job.problem, self._dt(index, name)), save=False)
                            restored = restored or name in self.fits[stage.name]
            while self.queued:
                job = self.queued.pop()
                saved = self.done.get(job.stage, {}).get(job.key)
                if saved is None:
                    jobs.append(job)
                else:  # the Newtonian start finished before the interruption
                    self.finish(job, restore(job.model.name, saved, job.problem, None), save=False)
                    restored = restored or job.model.name in self.fits[job.stage]
        return jobs

    def inputs_ready(self, index: int, name: str) -> bool:
        """Whether model ``name``'s fit on stage ``index`` has its inputs (module docstring)."""
        before = self.fits[self.stages[index - 1].name] if index > 0 else None
        if name == "newtonian":
            return before is None or "newtonian" in before
        return "newtonian" in self.fits[self.stages[index].name] and (before is None or name in before)

    def finish(self, job: FitJob, fit: FitResult, save: bool = True) -> None:
        """Record ``job``'s fit; once every start of its model has finished, keep the one of lowest loss."""
        name = job.model.name
        starts = self.starts[(job.stage, name)]
        starts[job.key] = fit
        if save:
            self.done.setdefault(job.stage, {})[job.key] = serialise(fit)
            self.running.get(job.stage, {}).pop(job.key, None)
        if all(f is not None for f in starts.values()):
            best = min(starts.values(), key=lambda f: f.loss)
            fallback = self._newtonian_start(job.stage, name, best)
            if fallback is not None:
                starts[fallback.key] = None
                self.queued.append(fallback)
                return
            self.fits[job.stage][name] = best
            self.done.setdefault(job.stage, {})[name] = serialise(best)

    def _newtonian_start(self, stage_name: str, name: str, best: FitResult) -> FitJob | None:
        """The job that fits law ``name`` on stage ``stage_name`` from its Newtonian embedding, if its kept fit
        ``best`` ends above the stage's Newtonian fit and it has not run yet (module docstring); None otherwise."""
        index = [stage.name for stage in self.stages].index(stage_name)
        key = f"{name}/{NEWTONIAN_START}"
        newtonian = self.fits[stage_name].get("newtonian")
        if not _has_embedding(name) or key in self.starts[(stage_name, name)] or newtonian is None \
                or best.loss <= newtonian.loss:
            return None
        model = newtonian_embedding(name, newtonian.model.params_si()["eta"], self.shear_rate)
        return self._job(index, self.stages[index], key, model, self.stages[index].iterations)

    def _dt(self, index: int, name: str) -> float | None:
        """The corotated baseline's step on stage ``index`` [s] (None for the laws, which need none)."""
        if name != "corotated":
            return None
        eta = 1.0 if index == 0 else self.fits[self.stages[index - 1].name]["newtonian"].model.params_si()["eta"]
        return self.stage_dt(self.stages[index], eta)

    def _jobs(self, index: int, stage: Stage, name: str) -> list[FitJob]:
        """One job per start of model ``name`` on ``stage``."""
        dt = self._dt(index, name)
        start = self.fits[self.stages[index - 1].name][name] if index > 0 else None
        if start is not None:
            model = start.model.copy()
            if start.model.is_baseline:  # keep its apparent viscosity mu * dt across the change of step
                mu = start.model.params_si()["shear_modulus"]
                model = FitModel.named(name, dt=dt, shear_modulus=mu * start.model.dt / dt)
            models = [model]
        elif name == "newtonian":
            models = [FitModel.named("newtonian", eta=self.ladder_estimate)]
        else:  # every start of initial_models is fitted and the lowest loss kept
            eta = self.fits[stage.name]["newtonian"].model.params_si()["eta"]
            models = initial_models(name, eta, self.shear_rate, dt=dt)
        # a law that may get a Newtonian start keys its own starts apart from its kept fit
        single = len(models) == 1 and not _has_embedding(name)
        return [self._job(index, stage, name if single else f"{name}/start{k}", model, stage.iterations, start)
                for k, model in enumerate(models)]

    def _job(self, index: int, stage: Stage, key: str, model: FitModel, budget: int,
             start: FitResult | None = None) -> FitJob:
        """The job that fits ``model`` on stage ``index`` under ``key``, resumed from the checkpoint's last iterate
        of that key, with its critical-path cost. A one-parameter model on a later stage reuses ``start``'s
        Jacobian (its fit on the stage before) with ``SECANT_STEPS`` more evaluations; a model of several
        parameters computes its own there and reports its Broyden matrix at the fit (module docstring)."""
        name = model.name
        problem = self._problem(index, name)
        jacobian = readings = None
        if start is not None and model.size == 1:
            # with a fitted lag the coarse Jacobian is that of the lagged reading while Broyden follows the bare
            # one: a phase shift of ωτ (0.13 rad at 20 ms and a 1 s period), left to the secant updates
            jacobian, readings, budget = start.jacobian, start.simulated_readings, budget + SECANT_STEPS
        last = self.running.get(stage.name, {}).get(key)
        if last is not None:  # resume the interrupted job from its last iterate
            model.set_theta(np.array(last))
        job = FitJob(stage.name, key, problem, model, budget, self.optimizer, self.sensor, jacobian=jacobian,
                     readings=readings, recompute_jacobian=recomputes_jacobian(self.stages, index, model.size))
        job.cost = job.simulations * _steps(problem, model) + self._later_cost(index, name, model)
        return job

    def _later_cost(self, index: int, name: str, model: FitModel) -> float:
        """The simulated steps that the later stages of model ``name`` will spend from ``model`` [steps]: a job
        that others wait for goes first (a critical-path priority)."""
        cost = 0.0
        for later in range(index + 1, len(self.stages)):
            cost += stage_simulations(self.stages, later, model.size) * _steps(self._problem(later, name), model)
        return cost

    def _problem(self, index: int, name: str) -> StirProblem:
        """Stage ``index``'s problem for model ``name``: the corotated baseline's viscosity is mu * dt, so its
        step is held fixed there (``_dt``)."""
        problem, dt = self.stages[index].problem, self._dt(index, name)
        return problem if dt is None else problem.with_config(replace(problem.config, dt=dt))


def recomputes_jacobian(stages: tuple[Stage, ...], index: int, size: int) -> bool:
    """Whether a fit of ``size`` parameters on ``stages[index]`` recomputes its Jacobian by forward differences at
    the end: on a lone stage, whose intervals it gives after up to ``iterations`` Broyden updates, and where the
    next stage reuses it (a one-parameter model); elsewhere the Broyden matrix is reported."""
    return len(stages) == 1 or (index < len(stages) - 1 and size == 1)


def stage_simulations(stages: tuple[Stage, ...], index: int, size: int) -> int:
    """The simulations a fit of ``size`` parameters spends at most on ``stages[index]`` (``Plan._job``): on the
    first stage its iterations and its forward-difference Jacobians; on a later one its iterations and the secant
    steps from the stage before's Jacobian for one parameter, a Jacobian by forward differences for several."""
    stage = stages[index]
    if index > 0:
        return stage.iterations + (SECANT_STEPS if size == 1 else size)
    return fit_simulations(size, stage.iterations, 1 + recomputes_jacobian(stages, index, size))


def _has_embedding(name: str) -> bool:
    """Whether law ``name`` contains the Newtonian one as ``newtonian_embedding`` (the laws but the Newtonian
    one; not the corotated baseline)."""
    return name not in ("newtonian", "corotated")


def _steps(problem: StirProblem, model: FitModel) -> float:
    """The cost of one simulation of ``model`` on ``problem`` at its current θ, in steps: a high viscosity (a
    yield stress at low shear rates) adds shear-stress substeps (``StirringSimulator.substeps``) at
    ``SUBSTEP_COST`` of a step each, or shortens the steps where they are not split."""
    simulator = problem.simulator(model.material)
    dt = simulator.time_step(problem.trajectory)
    return problem.trajectory.duration / dt * (1.0 + SUBSTEP_COST * (simulator.substeps(problem.trajectory, dt) - 1))


def serialise(fit: FitResult) -> dict:
    """A fit as the checkpoint's JSON (``restore`` reads it back)."""
    return {"theta": fit.theta.tolist(), "predicted": fit.predicted.tolist(), "jacobian": fit.jacobian.tolist(),
            "history": fit.history, "evaluations": fit.evaluations, "seconds": fit.seconds, "message": fit.message,
            "converged": fit.converged, "params": fit.model.params_si(), "sensor": fit.sensor,
            "simulated": None if fit.simulated is None else fit.simulated.tolist()}


def restore(name: str, saved: dict, problem: StirProblem, dt: float | None) -> FitResult:
    """The fit of model ``name`` that ``serialise`` saved, on ``problem`` (``dt``: the corotated baseline's step)."""
    model = FitModel.named(name, dt=dt, **saved["params"])
    model.set_theta(np.array(saved["theta"]))  # the fit's exact θ, as the finished fit set it
    predicted = np.array(saved["predicted"])
    return FitResult(model=model, theta=np.array(saved["theta"]), predicted=predicted,
                     jacobian=np.array(saved["jacobian"]), loss=problem.loss(predicted),
                     holdout_loss=problem.loss(predicted, train=False), history=saved["history"],
                     evaluations=saved["evaluations"], seconds=saved["seconds"], message=saved["message"],
                     converged=saved.get("converged", False), sensor=saved.get("sensor", {}),
                     simulated=None if saved.get("simulated") is None else np.array(saved["simulated"]))
