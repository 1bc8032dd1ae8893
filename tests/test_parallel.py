"""Worker processes share the CPUs: each runs its share of torch threads, never more than its parent set."""

from dataclasses import dataclass

import pytest
import torch

from diffstir import parallel
from diffstir.parallel import Workers, default_workers, worker_threads


@dataclass
class ThreadsJob:
    """Reports the torch threads of the process that runs it."""

    stage: str
    key: str

    @property
    def priority(self) -> tuple:
        return ()

    def run(self, report) -> int:
        return torch.get_num_threads()


@pytest.mark.parametrize("parent, cpus, count, expected", [
    (16, 16, 2, 8),   # a process that never set its threads: one per CPU, shared between the workers
    (2, 2, 2, 1),     # the 2-core machine: one each, not two each on the same two cores
    (1, 16, 4, 1),    # the apps' threads = 1 is kept
    (4, 16, 2, 4),    # ... and so is a larger setting that fits
    (8, 2, 4, 1),     # more workers than CPUs: still one thread
])
def test_each_worker_runs_the_parents_threads_at_most_its_share_of_the_cpus(monkeypatch, parent, cpus, count,
                                                                             expected):
    monkeypatch.setattr(parallel.torch, "get_num_threads", lambda: parent)
    monkeypatch.setattr(parallel, "default_workers", lambda device="cpu": cpus)
    assert worker_threads(count) == expected


def test_workers_of_a_process_with_one_thread_per_cpu_do_not_oversubscribe_the_cpus():
    before = torch.get_num_threads()
    torch.set_num_threads(default_workers())  # as torch starts in a process that never set its threads
    try:
        with Workers(2, report=lambda event: None) as pool:
            threads = pool.map([ThreadsJob("threads", key) for key in "ab"])
    finally:
        torch.set_num_threads(before)
    assert threads == [max(1, default_workers() // 2)] * 2
