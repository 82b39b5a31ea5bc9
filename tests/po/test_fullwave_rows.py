"""The full-wave rows: BEM curves written as a turntable CSV and a mesh that rfir imports as they are."""
import importlib.util
import json
from pathlib import Path

import h5py
import numpy as np

from rfir_stages.geom.mesh_io import read_ply_mesh

ROOT = Path(__file__).resolve().parents[2]


def _cli():
    """scripts/fullwave_rows.py loaded by path."""
    spec = importlib.util.spec_from_file_location("fullwave_rows_cli", ROOT / "scripts" / "fullwave_rows.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_curves_round_trip_through_rfir_import(tmp_path):
    from typer.testing import CliRunner

    from rfir_cli.main import app

    phi = np.arange(0.0, 360.0, 1.0)
    rcs = 8.0 * np.cos(np.radians(phi)) ** 2 - 20.0
    case = {"kind": "plate", "size_m": 0.3, "freq_hz": 2.4e9, "polarization": "V", "phi_deg": phi.tolist(),
            "bem_dbsm": rcs.tolist()}
    (tmp_path / "check.json").write_text(json.dumps({"cases": [case]}))
    assert _cli().main([str(tmp_path / "check.json"), str(tmp_path / "rows")]) == 0
    mesh = read_ply_mesh(tmp_path / "rows" / "plate.ply")
    extent = mesh.vertices.max(0) - mesh.vertices.min(0)
    assert np.allclose(sorted(extent), [0.0, 0.3, 0.3])
    res = CliRunner().invoke(app, ["import", "csv", str(tmp_path / "rows" / "plate.csv"), "-o", str(tmp_path / "m.h5")])
    assert res.exit_code == 0, res.output
    with h5py.File(tmp_path / "m.h5") as f:
        got = f["rcs_dbsm"][:, 0]
        azimuth = np.degrees(np.arctan2(f["tx_pos"][:, 1], f["tx_pos"][:, 0])) % 360
        split = f["split"][:]
    order = np.argsort(azimuth)
    assert np.allclose(azimuth[order], phi, atol=1e-3)
    assert np.allclose(got[order], rcs, atol=1e-3)
    assert split[order][::2].max() == 0 and split[order][1::2].min() == 1   # even aspects train
