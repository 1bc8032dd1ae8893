"""Independent jobs side by side in worker processes, their events passed to the parent.

A job (``Job``) is a picklable object with a ``stage`` and a ``key`` that name it, a ``priority`` (higher starts
first) and ``run(report)``, which returns its result and may call ``report(event)`` with a tuple
``(kind, stage, name, *data)`` (progress, checkpoints): the parent's ``report`` receives it as it happens. The
identification's fits (``fitting.jobs``) and the diagnosis's candidates (``diagnosis.compare``) run this way.

Each worker runs ``worker_threads`` torch threads: this process's, at most its share of the CPUs. A process that
never set its threads has one per CPU; workers that each ran that many on the same cores would wait at each other's
OpenMP barriers (two threads per process made a step 2.9-4.4 times slower on a busy 2-core machine,
docs/benchmarks-cpu.md).
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import pickle
import queue
import signal
import sys
from concurrent.futures import Future, ProcessPoolExecutor, wait
from typing import Callable, Iterator, Protocol

import torch


class Job(Protocol):
    stage: str
    key: str

    @property
    def priority(self) -> tuple: ...

    def run(self, report: Callable[[tuple], None]) -> object: ...


def default_workers(device: str = "cpu") -> int:
    """Worker processes for a job pool: the CPUs this process may use on a CPU device, one on a GPU."""
    if torch.device(device).type != "cpu":
        return 1
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def worker_threads(count: int) -> int:
    """Torch threads for each of ``count`` workers: this process's (``torch.get_num_threads``, as the apps' ``threads``
    sets it), at most the CPUs this process may use divided among the workers, and at least one."""
    return max(1, min(torch.get_num_threads(), default_workers() // max(count, 1)))


class Workers:
    """Runs jobs (``Job``) in up to ``count`` processes; ``report`` receives every job's events
    in this process. They run in this process when ``count`` is 1, and when this process is itself a worker of a
    pool (a joblib sweep's, ``hydra/launcher=joblib``): that pool already fills the cores, and its workers cannot
    spawn processes.

        with Workers(2, report) as workers:
            workers.submit(job)
            for job, result in workers.completed():   # more jobs may be submitted meanwhile
                ...

    A job that fails raises from ``completed`` once the jobs already running have finished. Leaving the ``with``
    block on an exception (a failed job, KeyboardInterrupt from SIGINT or SIGTERM) ends the worker processes at
    once; each worker also dies with this process if it is killed (``_start_worker``).
    """

    def __init__(self, count: int, report: Callable[[tuple], None]):
        self.report = report
        self.inline = count <= 1 or multiprocessing.parent_process() is not None
        self.waiting: list[Job] = []  # submitted, not started, by priority
        self.running: dict[Future, Job] = {}
        self.pool = self.events = None
        self.finished: set[tuple[str, str]] = set()
        if not self.inline:
            context = multiprocessing.get_context("spawn")  # fork would copy the parent's torch thread pools
            self.events = context.Queue()
            self.pool = ProcessPoolExecutor(count, mp_context=context, initializer=_start_worker,
                                            initargs=(self.events, worker_threads(count), os.getpid()))
            self.slots = count

    def __enter__(self) -> "Workers":
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if self.pool is None:
            return
        if exc_type is None:
            self.pool.shutdown(wait=True, cancel_futures=True)
        else:
            self.terminate()

    def terminate(self, grace: float = 2.0) -> None:
        """End the worker processes now: SIGTERM, then SIGKILL for any still alive after ``grace`` [s]."""
        processes = list((self.pool._processes or {}).values())
        for process in processes:
            process.terminate()
        self.pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.join(grace)
            if process.is_alive():
                process.kill()
                process.join()

    def submit(self, job: Job) -> None:
        self.waiting.append(job)
        self.waiting.sort(key=lambda j: j.priority, reverse=True)

    def map(self, jobs: list[Job]) -> list:
        """Every job's result, in order; call it while no other job is waiting or running."""
        if self.waiting or self.running:
            raise RuntimeError("Workers.map would take the results of jobs submitted before it")
        if len({(job.stage, job.key) for job in jobs}) < len(jobs):
            raise ValueError("Workers.map: two jobs share a (stage, key)")
        for job in jobs:
            self.submit(job)
        results = {(job.stage, job.key): result for job, result in self.completed()}
        return [results[(job.stage, job.key)] for job in jobs]

    def completed(self) -> Iterator[tuple[Job, object]]:
        """Each job with its result as it finishes, until none is waiting or running."""
        while self.waiting or self.running:
            if self.inline:
                job = self.waiting.pop(0)
                yield job, job.run(self.report)
                continue
            while self.waiting and len(self.running) < self.slots:  # no more than can run: a later one may go first
                job = self.waiting.pop(0)
                self.running[self.pool.submit(_run_in_worker, pickle.dumps(job))] = job
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
                    yield job, pickle.loads(future.result())

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
PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _start_worker(events, threads: int, parent: int) -> None:
    """A worker's set-up: its event queue and torch threads; SIGINT ignored (a terminal's Ctrl-C reaches the whole
    process group, and the parent ends its workers); on Linux, SIGKILL when the parent process ``parent`` dies."""
    global _EVENTS
    _EVENTS = events
    torch.set_num_threads(threads)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent(parent)


def die_with_parent(parent: int) -> None:
    """Have the kernel send this process SIGKILL when the thread that started it exits (Linux
    ``prctl(PR_SET_PDEATHSIG)``); exit at once if ``parent`` has died already. Elsewhere, nothing."""
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG)")
    if os.getppid() != parent:
        os._exit(1)


def _run_in_worker(pickled_job: bytes) -> bytes:
    """Runs a job pickled by value and returns its result pickled by value: plain pickle copies tensors into the
    message, where multiprocessing's pickler would share their memory through a file descriptor that a process
    ended by a signal mid-transfer leaves its peer waiting for."""
    job = pickle.loads(pickled_job)
    result = job.run(_EVENTS.put)
    _EVENTS.put(("finished", job.stage, job.key))
    return pickle.dumps(result)
