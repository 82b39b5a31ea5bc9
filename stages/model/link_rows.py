"""Selecting the items of some links from a per-item table (pairs, double bounces, edge items, room paths)."""
from __future__ import annotations

import numpy as np
import torch


def renumber_links(link: torch.Tensor, num_links: int, rows) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The items of links `rows`, renumbered 0..len(rows)-1 in that order.

    link [I] int64: each item's link in 0..num_links-1; rows: link indices (array-like [R]).
    Returns (rows [R] int64, keep [I] bool: the items of those links, new_link [I'] int64: their new link
    ids, in item order)."""
    rows = torch.as_tensor(np.asarray(rows), dtype=torch.int64)
    new_id = torch.full((num_links,), -1, dtype=torch.int64)
    new_id[rows] = torch.arange(rows.numel())
    keep = new_id[link] >= 0
    return rows, keep, new_id[link][keep]
