"""Fits as jobs: one model fitted on one stage from one start, run in this process or in worker processes
(``diffstir.parallel.Workers``).

An identification's fits depend on few others (``pipeline``): every model's first stage on the Newtonian fit
there, a model's next stage on its own previous one and on the Newtonian fit of that stage. So once the Newtonian
law's coarse fit is known, the other models' coarse fits (each start of a yield-stress law on its own), the
Newtonian fine fit and, as their inputs arrive, the other fine fits run side by side, one torch thread per worker.
A job reports what it does as events, ``(kind, stage, key, *data)``, which the parent turns into its progress bar,
TensorBoard scalars and checkpoint:

- ``("evaluation", stage, key, count, loss)``: a forward simulation was spent by the job ``key`` (its
  ``count``-th, loss [N]);
- ``("iteration", stage, key, iteration, loss, theta, params)``: an accepted iterate, to resume from.

Each simulation is deterministic at a given number of threads, so the fits do not depend on the number of
workers, only the order in which they finish does.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..parallel import Workers
from .magnitude import MAGNITUDE_STEPS, MagnitudeEstimate, magnitude_estimate
from .models import FitModel
from .nuisance import SensorNuisance
from .optimise import FitResult, Readings, fit_model
from .problem import FitProblem, StirProblem
from .progress import fit_simulations


@dataclass
class FitJob:
    """``model`` fitted on ``problem`` from its current θ (``fit_model``).

    Attributes:
        stage: the stage's name (``"fit"``, ``"coarse"``, ``"fine"``).
        key: the checkpoint's name for the job: the model's name, or ``name/start<k>`` for one of its starts.
        budget: the optimiser's iterations (``fit_model``'s ``max_iterations``).
        jacobian, readings: a coarser stage's Jacobian and readings at the start (coarse-to-fine), or None: a
            Jacobian by forward differences at the start.
        recompute_jacobian: the Jacobian reported at the fit is recomputed by forward differences (None: unless
            ``jacobian`` is given; ``fit_model``).
        cost: its expected work and that of the jobs waiting for it, in simulated steps, for ``priority`` (None:
            its own simulations).
    """

    stage: str
    key: str
    problem: FitProblem
    model: FitModel
    budget: int
    optimizer: str
    sensor: SensorNuisance
    jacobian: np.ndarray | None = None
    readings: np.ndarray | None = None
    recompute_jacobian: bool | None = None
    cost: float | None = None

    def run(self, report: Callable[[tuple], None]) -> FitResult:
        def on_evaluation(model_name, count, loss):
            report(("evaluation", self.stage, self.key, count, loss))

        def on_iteration(model, iteration, loss, theta):
            report(("iteration", self.stage, self.key, iteration, loss, [float(t) for t in theta], model.params_si()))

        return fit_model(self.problem, self.model, max_iterations=self.budget, optimizer=self.optimizer,
                         initial_jacobian=self.jacobian, initial_readings=self.readings,
                         recompute_jacobian=self.recompute_jacobian,
                         on_evaluation=on_evaluation, on_iteration=on_iteration, sensor=self.sensor)

    @property
    def simulations(self) -> int:
        """The simulations it spends at most: its budget, and the parameters' forward differences at the start
        where no coarser stage's Jacobian is reused and at the fit where it is recomputed."""
        recompute = self.jacobian is None if self.recompute_jacobian is None else self.recompute_jacobian
        return fit_simulations(self.model.size, self.budget, (self.jacobian is None) + recompute)

    @property
    def priority(self) -> tuple[bool, float]:
        """Jobs of higher priority start first: the Newtonian law's, which every other model waits for, then the
        dearer ones (``cost``)."""
        return self.model.name == "newtonian", self.simulations if self.cost is None else self.cost


@dataclass
class ReadingJob:
    """One forward simulation of ``model`` on ``problem``: its readings [N] on the fitted samples (the Newtonian
    ladder's and the effective shear rate's probes, ``initial``; the joint fit's start screens,
    ``behaviour.joint``)."""

    stage: str
    key: str
    problem: FitProblem
    model: FitModel
    priority: tuple[bool, int] = (True, 1)  # probes come before the fits that wait for them

    def run(self, report: Callable[[tuple], None]) -> np.ndarray:
        readings = Readings(self.problem, self.model,
                            lambda name, count, loss: report(("evaluation", self.stage, self.key, count, loss)))
        return readings(self.model.theta())


@dataclass
class MagnitudeJob:
    """The Newtonian viscosity whose simulated reading has the size of ``problem``'s (``magnitude``), from
    ``start`` [Pa·s], with the simulator's relative force error ``model_error`` and its inertial part's relative
    error ``inertial_error`` in its interval."""

    stage: str
    key: str
    problem: StirProblem
    start: float
    model_error: float
    inertial_error: float
    priority: tuple[bool, int] = (False, MAGNITUDE_STEPS + 1)  # nothing waits for it: after the Newtonian fits

    def run(self, report: Callable[[tuple], None]) -> MagnitudeEstimate:
        return magnitude_estimate(
            self.problem, self.start, self.model_error, inertial_error=self.inertial_error,
            on_evaluation=lambda name, count, loss: report(("evaluation", self.stage, self.key, count, loss)))


def mean_readings_on(workers: Workers, stage: str, problem: StirProblem, models: list[FitModel]) -> list[float]:
    """``initial.mean_readings`` side by side: the mean |reading| [N] of each model on ``problem``, in order."""
    readings = workers.map([ReadingJob(stage, f"probe{k}", problem, model) for k, model in enumerate(models)])
    return [problem.mean_reading(r) for r in readings]
