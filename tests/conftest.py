"""Shared test set-up.

One torch thread per test in the packages whose problems are tiny (predict, rf_fit, rssi, edit):
on a shared CPU, thread hand-offs cost more than they save (measured 3x faster under load).
"""
import pytest
import torch

ONE_THREAD_PACKAGES = {"predict", "rf_fit", "rssi", "edit"}


@pytest.fixture(autouse=True)
def _one_thread(request):
    if request.path.parent.name not in ONE_THREAD_PACKAGES:
        yield
        return
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
