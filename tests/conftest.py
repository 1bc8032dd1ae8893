import pytest
import torch


@pytest.fixture(autouse=True, scope="session")
def _threads():
    torch.set_num_threads(1)


@pytest.fixture
def cache_dir(tmp_path_factory):
    """A settled-state cache private to the test session."""
    return tmp_path_factory.getbasetemp() / "settled-cache"
