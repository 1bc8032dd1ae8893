"""A long computation's progress: forward simulations done against an estimate of all it will spend, revised as its
tasks finish, the best loss so far of each law, and a one-line summary at the end.

The work is split into tasks, each with its expected simulations. An identification's are the start (the
Newtonian ladder and the effective shear rate's probes), every fit job (a model on a stage from one start) and the
magnitude estimate; a behaviour or mixing analysis's are its windows and its joint fits. A model's fit
on a stage is one task until its jobs are handed out, then one per job (``expect``). The total is the sum over
tasks of the larger of what each is expected to spend and what it has spent; a finished task counts what it spent,
so a fit that converges early lowers the total and one that needs more raises it.

A fit spends about its budget (the start and one simulation per accepted or rejected step) and k more for each
Jacobian it computes by forward differences (k parameters): at the start unless it reuses a coarser stage's, and at
the fit unless it reports its Broyden matrix (``fit_simulations``).
"""

from __future__ import annotations

import math
import time
from pathlib import Path


def fit_simulations(size: int, budget: int, differences: int) -> int:
    """The simulations a fit of ``size`` parameters with ``budget`` optimiser evaluations and ``differences``
    forward-difference Jacobians (0, 1 or 2) is expected to spend (module docstring)."""
    return budget + differences * size


class Progress:
    """Simulations done and expected, by task (module docstring); a tqdm bar and TensorBoard scalars when asked.

    Args:
        expected: each task's expected simulations, by task name.
        bar: show a progress bar.
        log_dir: TensorBoard log directory (None: no logs).
        label: what the bar and the summary line call the computation.
    """

    def __init__(self, expected: dict[str, int], *, bar: bool = False, log_dir: str | Path | None = None,
                 label: str = "identify"):
        self.label = label
        self.closed = False
        self.expected = dict(expected)
        self.spent: dict[str, int] = {}
        self.finished_tasks: set[str] = set()
        self.best: dict[str, float] = {}
        self.started = time.perf_counter()
        self.bar = None
        if bar:
            from tqdm.auto import tqdm
            self.bar = tqdm(total=self.total, unit="sim", desc=label)
        self.writer = None
        if log_dir is not None:
            from torch.utils.tensorboard import SummaryWriter
            self.writer = SummaryWriter(str(log_dir))

    @property
    def done(self) -> int:
        """Simulations run so far."""
        return sum(self.spent.values())

    @property
    def total(self) -> int:
        """The simulations the identification is expected to spend in all (module docstring)."""
        tasks = set(self.expected) | set(self.spent)
        return sum(self.spent.get(t, 0) if t in self.finished_tasks else
                   max(self.expected.get(t, 0), self.spent.get(t, 0)) for t in tasks)

    def expect(self, task: str, simulations: int, replaces: str | None = None) -> None:
        """Task ``task`` is expected to spend ``simulations``; it takes the place of the estimate ``replaces`` (a
        model's fit on a stage, before its jobs were known), of which nothing was spent."""
        if replaces is not None and replaces != task:
            self.expected.pop(replaces, None)
        self.expected[task] = simulations
        self._refresh()

    def evaluation(self, task: str, law: str | None = None, loss: float | None = None) -> None:
        """One simulation of ``task``, of law ``law`` with the loss ``loss`` [N] (None: not a fit's)."""
        self.spent[task] = self.spent.get(task, 0) + 1
        if law is not None and loss is not None and math.isfinite(loss):
            self.best[law] = min(self.best.get(law, math.inf), loss)
        if self.bar is not None:  # one redraw per simulation, by ``update``
            self.bar.total = self.total
            self.bar.set_description(f"{self.label} {task}", refresh=False)
            if law in self.best:
                self.bar.set_postfix_str(f"best {law} loss {self.best[law]:.3g} N", refresh=False)
            self.bar.update(1)

    def finished(self, task: str) -> None:
        """``task`` spent all it will: the total counts what it spent."""
        self.finished_tasks.add(task)
        self._refresh()

    def iteration(self, name: str, iteration: int, loss: float, params: dict[str, float]) -> None:
        """An accepted iterate of fit ``name``: its loss [N] and SI parameters as TensorBoard scalars."""
        if self.writer is not None:
            self.writer.add_scalar(f"loss/{name}", loss, iteration)
            for key, value in params.items():
                self.writer.add_scalar(f"{name}/{key}", value, iteration)

    def summary(self, outcome: str) -> str:
        """One line: simulations run, wall time, the ``outcome`` (e.g. ``"selected carreau"``)."""
        seconds = time.perf_counter() - self.started
        minutes, rest = divmod(round(seconds), 60)
        wall = f"{minutes} min {rest} s" if minutes else f"{seconds:.1f} s"
        return f"{self.label}: {self.done} simulations in {wall}; {outcome}"

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *_) -> None:
        self.close()

    def close(self, outcome: str | None = None) -> None:
        """Close the bar (printing ``summary(outcome)`` below it when there is an outcome) and the logs; closing
        again does nothing."""
        if self.closed:
            return
        self.closed = True
        if self.bar is not None:
            self.bar.total = self.total
            self.bar.refresh()
            self.bar.close()
            if outcome is not None:
                print(self.summary(outcome), flush=True)
        if self.writer is not None:
            self.writer.close()

    def _refresh(self) -> None:
        """The bar's total follows the estimate; it is drawn at the next simulation."""
        if self.bar is not None:
            self.bar.total = self.total
