"""The 0.3 m PEC plate in H polarisation against its full-wave (BEM) curve, by aspect region (docs/po.md).

    .venv/bin/python bench/plate_h_vs_bem.py

The curve is the committed fixture tests/model/data/bem_plate_h_2g4.csv (2.4 GHz, 0-89 degrees from
broadside); the model is rf-fit's physical model with perfect conductors and nothing fitted on 3 cm
surfels, as physical optics alone and with the edge waves (docs/physics.md 8.13). Aspects within 40 dB of
the BEM's peak; regions: specular below 11 degrees, wide angle 11-79, near grazing 80 and up. Prints the
MAE and, in brackets, the mean of model - BEM in dB."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rfir_stages.fullwave.meshes import plate_screen  # noqa: E402
from tests.model.helpers import surfels  # noqa: E402
from tests.model.test_edges import _rcs  # noqa: E402

FIXTURE = ROOT / "tests" / "model" / "data" / "bem_plate_h_2g4.csv"


def main() -> None:
    rows = np.loadtxt(FIXTURE, delimiter=",", comments="#", skiprows=4)
    phi, bem = rows[:, 0], rows[:, 1]
    keep = bem > bem.max() - 40
    phi, bem = phi[keep], bem[keep]
    geom, _ = surfels(*plate_screen(0.3, 4), 0.03)
    models = {"PO surfels": _rcs(geom, phi, 2.4e9, False, polarisation="H"),
              "with edge waves": _rcs(geom, phi, 2.4e9, True, polarisation="H")}
    regions = {"specular": phi < 11, "wide angle": (phi >= 11) & (phi < 80), "near grazing": phi >= 80}
    for name, sel in regions.items():
        cells = [f"{label} {np.abs(m - bem)[sel].mean():.2f} ({(m - bem)[sel].mean():+.2f})" for label, m in models.items()]
        print(f"plate H 2.4 GHz, {name} ({int(sel.sum())} aspects): " + "; ".join(cells))


if __name__ == "__main__":
    main()
