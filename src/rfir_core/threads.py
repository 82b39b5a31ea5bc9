"""single_thread_torch: run a block with one torch intra-op thread (the PO kernels, the model's small-tensor loops)."""
from __future__ import annotations

import torch


class single_thread_torch:
    """Context manager: torch intra-op threads = 1 inside (restored after).

    The PO kernels call torch on blocks of ~1e5 elements, the model's fit loops on many small tensors; with 2 threads
    on a shared, busy CPU the thread hand-offs cost more than the work."""

    def __enter__(self):
        self._n = torch.get_num_threads()
        if self._n != 1:
            torch.set_num_threads(1)
        return self

    def __exit__(self, *exc):
        if self._n != 1:
            torch.set_num_threads(self._n)
        return False
