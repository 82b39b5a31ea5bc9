"""RfFitResult: the summary of one rf-fit run, which every fit (RCS, wideband, room) returns."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class RfFitResult:
    """Summary of one rf-fit run."""

    path: Path
    num_gaussians: int
    num_train_links: int
    freqs_hz: list
    train_mae_db: float
    initial_mae_db: float
    iterations: int       # Adam steps the final fit ran in all (its starts, switch rounds and rf_fit.physical.iterations)
    wall_time_s: float
    trace_time_s: float
    occlusion: str
    timings_s: dict = field(default_factory=dict)
    selection: dict = field(default_factory=dict)    # material sharing requested / selected, validation MAEs
    materials: list = field(default_factory=list)    # one dict per fitted material
    warnings: list = field(default_factory=list)
    material_checks: list = field(default_factory=list)   # materials implausible for their surface, alternatives
