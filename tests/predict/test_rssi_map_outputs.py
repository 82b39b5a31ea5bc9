"""`rfir predict rssi` maps an engineer can use: a transmitter on a receiver point (left out, said), received
power in dBm, map files (CSV, NPZ, GeoTIFF-like TIFF), several transmitters with the best server and the
coverage, and bad options refused in one line before any work. On the reduced test room (seconds)."""
import csv

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app

from .conftest import FAST

# the grid 1.0,0.5 of the 4 x 3 m room: 8 x 6 cell centres at x, y = 0.25 + 0.5 k, z = 1 m
GRID = ["--grid", "1.0,0.5"]
ON_POINT = "1.25,1.75,1.0"    # exactly a grid point
TX_B = "3.1,0.9,1.5"


def _invoke(*args):
    return CliRunner().invoke(app, [*FAST, *map(str, args)])


def _one_line_error(r, code, *fragments):
    text = r.output.strip()
    assert r.exit_code == code, text
    assert "Traceback" not in text and "internal error" not in text
    assert len([line for line in text.splitlines() if line.strip()]) == 1, text
    for f in fragments:
        assert f in text, text


@pytest.fixture
def rf(rssi_rf):
    return rssi_rf


def test_transmitter_on_a_grid_point_is_left_out_and_said(rf, tmp_path):
    out = tmp_path / "map.h5"
    r = _invoke("predict", "rssi", rf, "--tx", ON_POINT, *GRID, "-o", out, "--format", "npz")
    assert r.exit_code == 0, r.output
    assert "internal error" not in r.output
    assert "1 receiver point(s) closer than 0.05 m to the transmitter" in r.output
    assert "1 of 48 points left out" in r.output
    pred = read_artifact(out, "predictions")
    assert len(pred["rx_pos"]) == 47 and np.isfinite(pred["path_gain_db"]).all()
    assert np.linalg.norm(pred["rx_pos"] - [1.25, 1.75, 1.0], axis=1).min() > 0.05
    z = np.load(out.with_suffix(".npz"))
    values, points = z["values"][0], z["points_m"]
    gone = np.flatnonzero(np.isnan(values))
    assert len(points) == 48 and gone.tolist() == [int(np.argmin(np.linalg.norm(points - [1.25, 1.75, 1.0], axis=1)))]


def test_receiver_file_with_a_point_at_the_transmitter(rf, tmp_path):
    pts = tmp_path / "pts.csv"
    pts.write_text("x,y,z\n1.25,1.75,1.0\n0.5,0.5,1.0\n3.0,2.5,1.0\n")
    r = _invoke("predict", "rssi", rf, "--tx", ON_POINT, "--rx", pts, "-o", tmp_path / "p.h5")
    assert r.exit_code == 0, r.output
    assert "1 receiver point(s) closer than 0.05 m" in r.output
    assert len(read_artifact(tmp_path / "p.h5")["rx_pos"]) == 2
    pts.write_text("1.25,1.75,1.0\n1.26,1.75,1.0\n")
    _one_line_error(_invoke("predict", "rssi", rf, "--tx", ON_POINT, "--rx", pts, "-o", tmp_path / "q.h5"), 5,
                    "every receiver is closer than 0.05 m")
    assert not (tmp_path / "q.h5").exists()


def test_dbm_values_and_map_files(rf, tmp_path):
    out = tmp_path / "map.h5"
    r = _invoke("predict", "rssi", rf, "--tx", "1.2,2.0,1.8", *GRID, "-o", out, "--tx-power-dbm", "20",
                "--format", "csv,npz", "--format", "tif")
    assert r.exit_code == 0, r.output
    assert "received power (P_T = 20 dBm) median" in r.output and " dBm" in r.output
    pred = read_artifact(out, "predictions")
    assert float(pred.attrs["tx_power_dbm"]) == 20.0
    pg = pred["path_gain_db"][:, 0]          # the artifact keeps path gain [dB]
    z = np.load(out.with_suffix(".npz"))
    assert str(z["unit"]) == "dBm"
    np.testing.assert_allclose(z["values"][0], pg + 20.0)
    np.testing.assert_allclose(z["points_m"], pred["rx_pos"])
    # CSV: x_m, y_m, z_m and the value in dBm
    with open(out.with_suffix(".csv")) as handle:
        rows = list(csv.reader(handle))
    assert rows[0] == ["x_m", "y_m", "z_m", "rssi_dbm"] and len(rows) == 49
    got = np.asarray(rows[1:], float)
    np.testing.assert_allclose(got[:, :3], pred["rx_pos"], atol=1e-5)
    np.testing.assert_allclose(got[:, 3], pg + 20.0, atol=1e-3)
    # TIFF: float32, north up (row 0 = largest y), the grid's step and top-left corner as GeoTIFF tags
    im = Image.open(out.with_suffix(".tif"))
    assert im.mode == "F" and im.size == (8, 6)
    assert tuple(im.tag_v2[33550]) == (0.5, 0.5, 0.0)
    assert tuple(im.tag_v2[33922]) == (0.0, 0.0, 0.0, 0.0, 3.0, 0.0)
    img = np.asarray(im, np.float64)
    top_left = np.flatnonzero((np.abs(pred["rx_pos"][:, 0] - 0.25) < 1e-9) & (np.abs(pred["rx_pos"][:, 1] - 2.75) < 1e-9))
    assert img[0, 0] == pytest.approx(pg[top_left[0]] + 20.0, abs=1e-3)
    np.testing.assert_allclose(img[::-1], z["grid_values"][0], atol=1e-3)


def test_several_transmitters_best_server_and_coverage(rf, tmp_path):
    out = tmp_path / "multi.h5"
    r = _invoke("predict", "rssi", rf, "--tx", ON_POINT, "--tx", TX_B, *GRID, "-o", out, "--tx-power-dbm", "10",
                "--threshold-dbm", "-35", "--format", "npz,tif", "--plots", tmp_path / "plots")
    assert r.exit_code == 0, r.output
    pred = read_artifact(out, "predictions")
    assert len(pred["rx_pos"]) == 47 + 48      # one point left out of the first transmitter's map
    z = np.load(out.with_suffix(".npz"))
    values, best = z["values"], z["best_tx"]
    assert values.shape == (2, 48)
    filled = np.where(np.isnan(values), -np.inf, values)
    np.testing.assert_array_equal(best, np.argmax(filled, 0))
    strongest = filled.max(0)
    share = np.mean(strongest >= -35.0)
    assert f"coverage: {100 * share:.1f} % of 48 points at or above -35 dBm" in r.output
    assert 0.0 < share < 1.0
    counts = np.bincount(best, minlength=2)
    assert f"Tx 1 {counts[0]}, Tx 2 {counts[1]}" in r.output
    # each transmitter's map is the one it gets alone
    single = tmp_path / "b.h5"
    assert _invoke("predict", "rssi", rf, "--tx", TX_B, *GRID, "-o", single, "--tx-power-dbm", "10",
                   "--format", "npz").exit_code == 0
    np.testing.assert_allclose(np.load(single.with_suffix(".npz"))["values"][0], values[1], atol=1e-9)
    names = {p.name for p in (tmp_path / "plots").iterdir()}
    assert {"rssi_predicted_tx1.png", "rssi_predicted_tx2.png", "best_tx.png", "coverage.png"} <= names
    tif = [out.with_name(n) for n in ("multi_tx1.tif", "multi_tx2.tif", "multi_best_tx.tif")]
    assert all(p.exists() for p in tif)
    best_img = np.asarray(Image.open(tif[2]), np.float64)[::-1]
    np.testing.assert_array_equal(best_img, best.reshape(8, 6).T + 1)


@pytest.mark.parametrize("args, fragment", [
    (["--threshold-dbm", "-70"], "--threshold-dbm needs --tx-power-dbm"),
    (["--format", "csv,xls"], "--format 'xls'"),
    (["--tx-power-dbm", "nan"], "--tx-power-dbm must be a finite number"),
])
def test_bad_map_options_are_one_line_before_work(rf, tmp_path, args, fragment):
    out = tmp_path / "x.h5"
    _one_line_error(_invoke("predict", "rssi", rf, "--tx", "1.2,2.0,1.8", *GRID, "-o", out, *args), 4, fragment)
    assert not out.exists()


def test_tif_needs_a_grid_and_map_files_never_replace_an_input(rf, tmp_path):
    pts = tmp_path / "pts.csv"
    pts.write_text("0.5,0.5,1.0\n3.0,2.5,1.0\n")
    before = pts.read_bytes()
    _one_line_error(_invoke("predict", "rssi", rf, "--tx", "1.2,2.0,1.8", "--rx", pts, "-o", tmp_path / "a.h5",
                            "--format", "tif"), 4, "--format tif needs receivers on a grid")
    # -o pts.h5 with --format csv would write pts.csv: the receiver file itself
    _one_line_error(_invoke("predict", "rssi", rf, "--tx", "1.2,2.0,1.8", "--rx", pts, "-o", tmp_path / "pts.h5",
                            "--format", "csv"), 2, str(pts), "input of this command")
    assert pts.read_bytes() == before and not (tmp_path / "pts.h5").exists()
