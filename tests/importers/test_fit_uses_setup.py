"""rf-fit and predict use the imported set-up (antenna), say what they assumed, and select rows
by --range / --aspects with a one-line error when a selection keeps nothing."""
import json

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.context import GlobalOptions
from rfir_stages.geom import write_scene_artifact
from rfir_stages.importers import import_csv
from rfir_stages.model.links import scene_centre
from rfir_stages.simulate.scenes import box

from ..rf_fit.helpers import box_fields, geometry, po_measurements

FAST = ["rf_fit.occlusion=brute-force", "rf_fit.physical.iterations=4", "rf_fit.physical.start_iterations=2",
        "rf_fit.physical.sharing=global", "rf_fit.physical.residual=off", "predict.occlusion=brute-force"]


def _app():
    from rfir_cli.commands import import_, predict, rf_fit

    app = typer.Typer()

    @app.callback()
    def _cb(ctx: typer.Context):
        ctx.obj = GlobalOptions(overrides=list(FAST))

    for module in (rf_fit, predict, import_):
        module.register(app)
    return app


@pytest.fixture(scope="module")
def box_csv(tmp_path_factory):
    """A box scene and a CSV of its isotropic-antenna path gains: 2 ranges x 12 aspects, even aspects train."""
    d = tmp_path_factory.mktemp("user")
    fields = box_fields(0.05, 0.05)
    write_scene_artifact(d / "scene.h5", fields)
    geom = geometry(fields)
    centre = scene_centre(geom)
    assert np.allclose(centre.numpy()[:2], 0.0)   # the turntable axis is x = y = 0
    v, f = box((-0.05,) * 3, (0.05,) * 3)         # the physical-optics RCS of the box as metal
    meas = read_artifact(po_measurements(d / "po.h5", v, f, np.array(["metal"] * len(f)), np.full(len(f), 0.003),
                                         [2.4e9], np.arange(0, 360, 30), ranges=(2.0, 3.0)), "measurements")
    tx, rx, asp, rng = (np.asarray(meas[k]) for k in ("tx_pos", "rx_pos", "aspect_rad", "range_m"))
    pg, rcs = np.asarray(meas["path_gain_db"])[:, 0], np.asarray(meas["rcs_dbsm"])[:, 0]
    lines = ["tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz,power_db,rcs_dbsm,aspect_deg,range_m,split"]
    for i in range(len(tx)):
        a = round(float(np.degrees(asp[i]))) % 360
        lines.append(",".join(f"{v:.9g}" for v in (*tx[i], *rx[i])) + f",2.4e9,{pg[i]:.6f},{rcs[i]:.6f},{a},{rng[i]:g},"
                     + ("train" if (a // 30) % 2 == 0 else "test"))
    (d / "links.csv").write_text("\n".join(lines) + "\n")
    return d


def _fit(d, meas, out, *extra):
    return CliRunner().invoke(_app(), ["rf-fit", str(d / "scene.h5"), str(meas), "-o", str(out), *extra])


def test_a_file_that_states_no_antenna_is_fitted_isotropic_and_says_so(box_csv, tmp_path):
    import_csv(box_csv / "links.csv", tmp_path / "m.h5")
    r = _fit(box_csv, tmp_path / "m.h5", tmp_path / "rf.h5")
    assert r.exit_code == 0, r.output
    assert "antenna isotropic (assumed: the measurements state no antenna" in r.output
    assert "rows used: 12 train, 12 test (split data); frequencies 2.4 GHz; ranges 2, 3 m" in r.output
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    assert rf.free["model@attrs"]["antenna_kind"] == "isotropic"
    assert str(rf.free["model@attrs"]["antenna_source"]).startswith("assumed")
    assert rf.free["training@attrs"]["num_test_rows"] == 12 and rf.free["training@attrs"]["train_ranges_m"] == "2, 3"


def test_the_stated_antenna_reaches_the_fit_and_predict(box_csv, tmp_path, monkeypatch):
    import_csv(box_csv / "links.csv", tmp_path / "m.h5", antenna="horn:30", polarisation="H")
    r = _fit(box_csv, tmp_path / "m.h5", tmp_path / "rf.h5")
    assert r.exit_code == 0, r.output
    assert "antenna horn:30 (stated by the measurements)" in r.output
    assert "polarisation H (stated by the measurements; rf_fit.physical.polarisation V not used)" in r.output
    attrs = read_artifact(tmp_path / "rf.h5", "rf").free["model@attrs"]
    assert attrs["antenna_kind"] == "horn" and attrs["antenna_hpbw_deg"] == 30.0
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(_app(), ["predict", "rcs", str(tmp_path / "rf.h5"), "--measurements", str(tmp_path / "m.h5"),
                                    "-o", str(tmp_path / "p.h5"), "--aspects", "0:90", "--range", "3",
                                    "--freq", "2.4e9"])
    assert r.exit_code == 0, r.output
    pred = read_artifact(tmp_path / "p.h5", "predictions")
    np.testing.assert_allclose(np.sort(np.degrees(pred["aspect_rad"])), [0, 30, 60], atol=1e-9)
    assert np.all(pred["range_m"] == 3.0)
    res = json.loads((tmp_path / "p.json").read_text())
    assert res["antenna"]["antenna_kind"] == "horn" and res["antenna"]["antenna_source"] == "stated by the measurements"


def test_row_selection_in_rf_fit(box_csv, tmp_path):
    import_csv(box_csv / "links.csv", tmp_path / "m.h5")
    r = _fit(box_csv, tmp_path / "m.h5", tmp_path / "rf.h5", "--aspects", "300:90", "--range", "2", "--freq", "2.4e9")
    assert r.exit_code == 0, r.output
    assert read_artifact(tmp_path / "rf.h5", "rf").free["training@attrs"]["num_train_rows"] == 3   # 300, 0 and 60 deg train
    r = _fit(box_csv, tmp_path / "m.h5", tmp_path / "rf2.h5", "--range", "7")
    assert r.exit_code == 5 and "--range 7 leaves no row of the 12 considered (the file has ranges 2, 3 m" in r.output
    assert len(r.output.strip().splitlines()) <= 3 and "Traceback" not in r.output   # log lines, then the error
    assert not (tmp_path / "rf2.h5").exists()
    r = _fit(box_csv, tmp_path / "m.h5", tmp_path / "rf2.h5", "--freq-hz", "5.8e9")
    assert r.exit_code == 5 and "frequency 5.8 GHz is not in the file" in r.output
    r = _fit(box_csv, tmp_path / "m.h5", tmp_path / "rf2.h5", "--aspects", "0:9x")
    assert r.exit_code == 4 and "--aspects '0:9x'" in r.output


def test_different_antennas_per_side_are_refused_before_work(box_csv, tmp_path):
    import_csv(box_csv / "links.csv", tmp_path / "m.h5", antenna_tx="horn:30", antenna_rx="isotropic")
    r = _fit(box_csv, tmp_path / "m.h5", tmp_path / "rf.h5")
    assert r.exit_code == 4 and "rf-fit fits one pattern for both sides" in r.output
