import pytest
import torch


@pytest.fixture(autouse=True, scope="session")
def _threads():
    # the simulator's tensors are small: beside another job one thread is several times faster than two (the
    # rectifier tests' shard fixture, `pytest tests/test_rectifier.py --durations=2` with a benchmark on the other
    # core, 2026-11-22: 42 s against 254 s)
    torch.set_num_threads(1)


@pytest.fixture
def cache_dir(tmp_path_factory):
    """A settled-state cache private to the test session."""
    return tmp_path_factory.getbasetemp() / "settled-cache"
