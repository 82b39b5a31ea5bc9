"""One torch thread per test here: the problems are tiny, and on a shared CPU thread hand-offs
cost more than they save (measured 3x faster under load)."""
import pytest
import torch


@pytest.fixture(autouse=True)
def _one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
