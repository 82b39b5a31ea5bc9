"""rf-fit with rf_fit.physical.edge_waves = "auto": the edge waves are chosen by validation on the training
rows, kept on full-wave data and left out on physical-optics data (which have none); the choice is printed
in the selection, recorded in the artifact (root attribute edge_waves, checked by `rfir check`) and used
by prediction."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from rfir_core.artifacts import read_artifact, validate_artifact, write_artifact
from rfir_core.errors import ConfigError
from rfir_stages.fullwave.meshes import plate_screen
from rfir_stages.geom import write_scene_artifact
from rfir_stages.geom.from_mesh import gaussians_from_mesh
from rfir_core.physics.materials import C0
from rfir_stages.model.links import radar_links
from rfir_stages.rf_fit.physical_stage import sharing_candidates

from .helpers import DEG, po_measurements

FULLWAVE = Path(__file__).resolve().parents[2] / "results" / "reproduce" / "fullwave" / "fullwave_vs_po.json"
RANGE_M = 10.0
CFG = {"antenna": "isotropic", "physical": {"sharing": "global", "iterations": 40, "start_iterations": 10,
                                            "residual": "off", "reflection_ranges": False}}


def test_edge_waves_setting_gives_the_candidates():
    assert sharing_candidates({"sharing": "auto"}, 3, 3) == ["class", "global", "class+edges", "global+edges"]
    assert sharing_candidates({"sharing": "global", "edge_waves": "on"}, 0, 0) == ["global+edges"]
    assert sharing_candidates({"sharing": "auto", "edge_waves": "off"}, 0, 0) == ["segment", "global"]
    with pytest.raises(ConfigError, match="rf_fit.physical.edge_waves"):
        sharing_candidates({"edge_waves": "sometimes"}, 0, 0)


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    """The full-wave curve of the 0.3 m PEC plate (V, 2.4 GHz; results/reproduce/fullwave, every 4th
    aspect; odd rows test) and the PO solver's curve of the same plate, as measurement files; its scene."""
    d = tmp_path_factory.mktemp("plate")
    v, f = plate_screen(0.3, 4)
    write_scene_artifact(d / "scene.h5", gaussians_from_mesh(v, f, 0.03))
    case = next(c for c in json.loads(FULLWAVE.read_text())["cases"] if c["kind"] == "plate")
    phi = np.asarray(case["phi_deg"])[::4]
    rcs = np.asarray(case["bem_dbsm"])[::4]
    freq = float(case["freq_hz"])
    aspects = np.mod(-phi, 360.0)             # the curve's radar sits at azimuth phi; turntable: -aspect
    tx, rx, asp, rng = radar_links(aspects * DEG, np.array([RANGE_M]), np.zeros(3))
    lam = C0 / freq
    pg = rcs[:, None] - 10 * np.log10((4 * math.pi) ** 3 * RANGE_M**4 / lam**2)
    write_artifact(d / "bem.h5", "measurements",
                   {"tx_pos": tx, "rx_pos": rx, "freq_hz": np.array([freq]), "path_gain_db": pg, "rcs_dbsm": rcs[:, None],
                    "aspect_rad": asp, "range_m": rng, "split": (np.arange(len(asp)) % 2).astype(np.int64),
                    "scene_bounds": np.stack([v.min(0), v.max(0)])}, attrs={"task": "rcs", "scene": "test"})
    po_measurements(d / "po.h5", v, f, np.array(["pec"] * len(f)), np.zeros(len(f)), [freq], aspects,
                    ranges=(RANGE_M,))
    return d


@pytest.mark.slow
@pytest.mark.parametrize("data,expected", [("bem", "global+edges"), ("po", "global")])
def test_auto_keeps_edge_waves_on_full_wave_data_and_drops_them_on_po_data(plate, tmp_path, data, expected):
    from rfir_stages.model.artifact import load_physical
    from rfir_stages.predict.rcs import run_rcs
    from rfir_stages.rf_fit import run

    res = run(plate / "scene.h5", plate / f"{data}.h5", tmp_path / "rf.h5", CFG)
    assert {"val_mae_global_db", "val_mae_global+edges_db"} <= set(res.selection)
    assert res.selection["sharing_selected"] == expected, res.selection
    assert validate_artifact(tmp_path / "rf.h5") == []
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    assert rf.attrs["edge_waves"] == ("on" if expected.endswith("+edges") else "off")
    assert load_physical(rf).settings.edge_waves == expected.endswith("+edges")
    out = run_rcs(tmp_path / "rf.h5", tmp_path / "p.h5", {"occlusion": "auto"}, measurements_path=plate / f"{data}.h5",
                  results_path=tmp_path / "r.json")
    assert out.metrics["mae_db"] < 2.0, out.metrics
