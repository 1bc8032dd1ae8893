"""Fits as jobs: one model fitted on one stage from given starts, run in this process or in worker processes.

An identification's fits depend on few others (``pipeline``): every model's first stage on the Newtonian fit
there, a model's next stage on its own previous one and on the Newtonian fit of that stage. So once the Newtonian
law's coarse fit is known, the other models' coarse fits (each start of a yield-stress law on its own), the
Newtonian fine fit and, as their inputs arrive, the other fine fits run side by side, one torch thread per worker.
A job reports what it does as events, ``(kind, stage, key, *data)``, which the parent turns into its progress bar,
TensorBoard scalars and checkpoint:

- ``("evaluation", stage, model, count, loss)``: a forward simulation was spent (loss [N]);
- ``("iteration", stage, key, iteration, loss, theta, params)``: an accepted iterate, to resume from.

Each simulation is deterministic at a given number of threads, so the fits do not depend on the number of
workers, only the order in which they finish does.
"""

from __future__ import annotations

import multiprocessing
import os
import queue
from concurrent.futures import Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np
import torch

from .models import FitModel
from .nuisance import SensorNuisance
from .optimise import FitResult, Readings, fit_model
from .problem import StirProblem


@dataclass
class FitJob:
    """``model`` fitted on ``problem`` from its current θ (``fit_model``).

    Attributes:
        stage: the stage's name (``"fit"``, ``"coarse"``, ``"fine"``).
        key: the checkpoint's name for the job: the model's name, or ``name/start<k>`` for one of its starts.
        budget: the optimiser's iterations (``fit_model``'s ``max_iterations``).
        jacobian, readings: a coarser stage's Jacobian and readings at the start (coarse-to-fine), or None.
    """

    stage: str
    key: str
    problem: StirProblem
    model: FitModel
    budget: int
    optimizer: str
    sensor: SensorNuisance
    jacobian: np.ndarray | None = None
    readings: np.ndarray | None = None

    def run(self, report: Callable[[tuple], None]) -> FitResult:
        def on_evaluation(model_name, count, loss):
            report(("evaluation", self.stage, model_name, count, loss))

        def on_iteration(model, iteration, loss, theta):
            report(("iteration", self.stage, self.key, iteration, loss, [float(t) for t in theta], model.params_si()))

        return fit_model(self.problem, self.model, max_iterations=self.budget, optimizer=self.optimizer,
                         initial_jacobian=self.jacobian, initial_readings=self.readings,
                         on_evaluation=on_evaluation, on_iteration=on_iteration, sensor=self.sensor)

    @property
    def priority(self) -> tuple[bool, int]:
        """Jobs of higher priority start first: the Newtonian law's, which every other model waits for, then the
        dearer ones, in simulations: a first finite-difference Jacobian (parameters + 1), or the budget where a
        coarser stage's Jacobian is reused."""
        cost = self.budget if self.jacobian is not None else self.model.size + 1
        return self.model.name == "newtonian", cost


@dataclass
class ReadingJob:
    """One forward simulation of ``model`` on ``problem``: its mean |reading| [N] over the fitted samples (the
    Newtonian ladder's and the effective shear rate's probes, ``initial``)."""

    stage: str
    key: str
    problem: StirProblem
    model: FitModel
    priority: tuple[bool, int] = (True, 1)  # probes come before the fits that wait for them

    def run(self, report: Callable[[tuple], None]) -> float:
        readings = Readings(self.problem, self.model, lambda *data: report(("evaluation", self.stage, *data)))
        return self.problem.mean_reading(readings(self.model.theta()))


def default_workers(device: str = "cpu") -> int:
    """Worker processes for fitting: the CPUs this process may use on a CPU device, one on a GPU."""
    if torch.device(device).type != "cpu":
        return 1
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


class Workers:
    """Runs jobs (``FitJob``, ``ReadingJob``) in up to ``count`` processes; ``report`` receives every job's events
    in this process. They run in this process when ``count`` is 1, and when this process is itself a worker of a
    pool (a joblib sweep's, ``hydra/launcher=joblib``): that pool already fills the cores, and its workers cannot
    spawn processes.

        with Workers(2, report) as workers:
            workers.submit(job)
            for job, fit in workers.completed():   # more jobs may be submitted meanwhile
                ...

    A job that fails raises from ``completed`` once the jobs already running have finished.
    """

    def __init__(self, count: int, report: Callable[[tuple], None]):
        self.report = report
        self.inline = count <= 1 or multiprocessing.parent_process() is not None
        self.waiting: list[FitJob | ReadingJob] = []  # submitted, not started, by priority
        self.running: dict[Future, FitJob | ReadingJob] = {}
        self.pool = self.events = None
        self.finished: set[tuple[str, str]] = set()
        if not self.inline:
            context = multiprocessing.get_context("spawn")  # fork would copy the parent's torch thread pools
            self.events = context.Queue()
            self.pool = ProcessPoolExecutor(count, mp_context=context, initializer=_start_worker,
                                            initargs=(self.events, torch.get_num_threads()))
            self.slots = count

    def __enter__(self) -> "Workers":
        return self

    def __exit__(self, *exc) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)

    def submit(self, job: FitJob | ReadingJob) -> None:
        self.waiting.append(job)
        self.waiting.sort(key=lambda j: j.priority, reverse=True)

    def mean_readings(self, stage: str, problem: StirProblem, models: list[FitModel]) -> list[float]:
        """``initial.MeanReadings`` side by side: the mean |reading| [N] of each model on ``problem``, in order.
        Call it while no other job is waiting or running."""
        if self.waiting or self.running:
            raise RuntimeError("mean_readings would take the results of jobs already submitted")
        jobs = [ReadingJob(stage, f"probe{k}", problem, model) for k, model in enumerate(models)]
        for job in jobs:
            self.submit(job)
        means = {job.key: mean for job, mean in self.completed()}
        return [means[job.key] for job in jobs]

    def completed(self) -> Iterator[tuple[FitJob | ReadingJob, FitResult | float]]:
        """Each job with its fit as it finishes, until none is waiting or running."""
        while self.waiting or self.running:
            if self.inline:
                job = self.waiting.pop(0)
                yield job, job.run(self.report)
                continue
            while self.waiting and len(self.running) < self.slots:  # no more than can run: a later one may go first
                job = self.waiting.pop(0)
                self.running[self.pool.submit(_run_in_worker, job)] = job
            self._forward_events(timeout=0.2)
            for future, job in list(self.running.items()):
                if not future.done():
                    continue
                if future.exception() is not None:
                    wait(self.running)
                    self._forward_events(timeout=0.5)
                    raise future.exception()
                if (job.stage, job.key) in self.finished:  # every event of the job has been handed on
                    self.finished.remove((job.stage, job.key))
                    del self.running[future]
                    yield job, future.result()

    def _forward_events(self, timeout: float) -> None:
        """Hand on the events queued so far, waiting up to ``timeout`` [s] for the first. A job's last event,
        ``("finished", stage, key)``, says that all of its events have arrived (they travel on another pipe than
        its result)."""
        try:
            event = self.events.get(timeout=timeout)
            while True:
                if event[0] == "finished":
                    self.finished.add((event[1], event[2]))
                else:
                    self.report(event)
                event = self.events.get_nowait()
        except queue.Empty:
            return


_EVENTS = None  # a worker's event queue, set once by ``_start_worker``


def _start_worker(events, threads: int) -> None:
    global _EVENTS
    _EVENTS = events
    torch.set_num_threads(threads)


def _run_in_worker(job: FitJob | ReadingJob) -> FitResult | float:
    fit = job.run(_EVENTS.put)
    _EVENTS.put(("finished", job.stage, job.key))
    return fit
