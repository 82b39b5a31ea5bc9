"""scripts/rtt_lab_to_csv.py: the Wi-Fi RTT Laboratory survey (tests/data/rtt_lab) converted right.

A small made-up copy of the data set's layout (its file names, columns, BOM and "0 = no RSS" rule)
checks the binning, means, spreads, ids and the skipping of undeployed APs against values worked out
by hand; the shipped CSVs are checked against values read off the source files."""
from __future__ import annotations

import csv
import importlib.util
import math
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data" / "rtt_lab"
SPEC = importlib.util.spec_from_file_location("rtt_lab_to_csv", ROOT / "scripts" / "rtt_lab_to_csv.py")
conv = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(conv)

HEADER = ["M1 Time Stamp (ms)", "AP1 RSS (dBm)", "AP2 RSS (dBm)", "AP5 RSS (dBm)", "M1 Ground Truth_x",
          "M1 Ground Truth_y", "user", "circle"]


def _write(path: Path, rows: list[list]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(HEADER)
        w.writerows(rows)


def _fake_lab(tmp_path: Path) -> Path:
    """AP1 at (1, 2), AP2 undeployed (0, 0), AP5 at (5, 2); samples in circle 1 only."""
    lab = tmp_path / "Laboratory"
    lab.mkdir()
    # the source's AP file starts with a byte-order mark and an empty first header
    (lab / "AP_idx_Laboratory.csv").write_text("\ufeff,x,y\nAP1,1,2\nAP2,0,0\nAP5,5,2\n", encoding="utf-8")
    # user 1 on y = 15.326: x 1.30, 1.40, 1.45 share the 0.25 m cell 5; x 1.60 is alone in cell 6.
    # AP5's 0 at x 1.40 is "no measurement"; AP2's values must be ignored (not deployed).
    _write(lab / "1" / "113.csv", [[0, -50, -30, -70, 1.30, 15.326, 1, 1], [250, -52, -30, 0, 1.40, 15.326, 1, 1],
                                   [500, -54, -30, -72, 1.45, 15.326, 1, 1], [750, -60, -30, -80, 1.60, 15.326, 1, 1]])
    # user 2 on y = 20.159: three samples in cell 12
    _write(lab / "1" / "124.csv", [[0, -40, -30, -60, 3.0, 20.159, 2, 1], [250, -40, -30, -61, 3.1, 20.159, 2, 1],
                                   [500, -43, -30, -62, 3.2, 20.159, 2, 1]])
    for c in range(2, 6):
        _write(lab / str(c) / f"{c}13.csv", [])
        _write(lab / str(c) / f"{c}24.csv", [])
    return lab


def _rows(path: Path) -> list[dict]:
    with path.open() as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


def test_binning_means_ids_by_hand(tmp_path):
    lab = _fake_lab(tmp_path)
    links, walls = tmp_path / "links.csv", tmp_path / "walls.csv"
    assert conv.main([str(lab), "--links", str(links), "--walls", str(walls), "--test-fraction", "0"]) == 0
    rows = _rows(links)
    # cell 5 keeps AP1 only (AP5 has 2 samples < 3); cell 6 has 1 sample per AP and is dropped; the
    # user-2 cell keeps AP1 and AP5; AP2 never appears
    got = {(r["tx_id"], r["rx_id"]): r for r in rows}
    assert sorted(got) == [("0", "1"), ("1", "1"), ("1", "5")]
    a = got[("0", "1")]
    assert float(a["tx_x"]) == pytest.approx((1.30 + 1.40 + 1.45) / 3, abs=1e-3)
    assert float(a["tx_y"]) == 15.326 and float(a["tx_z"]) == 1.2
    assert (float(a["rx_x"]), float(a["rx_y"]), float(a["rx_z"])) == (1.0, 2.0, 1.0)
    assert float(a["power_db"]) == pytest.approx(-52.0)
    assert float(a["rssi_std_db"]) == pytest.approx(math.sqrt(8 / 3), abs=0.01)
    assert int(a["n_packets"]) == 3 and a["split"] == "0" and float(a["freq_hz"]) == 5.2e9
    b = got[("1", "5")]
    assert float(b["tx_x"]) == pytest.approx(3.1, abs=1e-3) and float(b["tx_y"]) == 20.159
    assert (float(b["rx_x"]), float(b["rx_y"])) == (5.0, 2.0)
    assert float(b["power_db"]) == pytest.approx(-61.0)
    assert float(b["rssi_std_db"]) == pytest.approx(math.sqrt(2 / 3), abs=0.01)
    assert float(got[("1", "1")]["power_db"]) == pytest.approx(-41.0)
    header = [line for line in links.read_text().splitlines() if line.startswith("#")]
    assert "# power = rssi" in header and "# tx_power_dbm = 20" in header


def test_split_holds_out_whole_positions(tmp_path):
    lab = _fake_lab(tmp_path)
    links, walls = tmp_path / "links.csv", tmp_path / "walls.csv"
    conv.main([str(lab), "--links", str(links), "--walls", str(walls), "--test-fraction", "0.5"])
    by_pos: dict[str, set] = {}
    for r in _rows(links):
        by_pos.setdefault(r["tx_id"], set()).add(r["split"])
    assert all(len(s) == 1 for s in by_pos.values())  # all links of a position share its split
    assert sorted(s.pop() for s in by_pos.values()) == ["0", "1"]  # round(0.5 * 2) = 1 test position


def test_missing_file_is_named(tmp_path):
    lab = _fake_lab(tmp_path)
    (lab / "3" / "313.csv").unlink()
    with pytest.raises(SystemExit, match="313.csv: missing"):
        conv.main([str(lab), "--links", str(tmp_path / "l.csv"), "--walls", str(tmp_path / "w.csv")])


def test_plan_registration_within_a_pixel():
    # the six AP markers land on the APs' coordinates (AP_idx_Laboratory.csv of the source) to within
    # about a plan pixel (9 cm) after the fitted axis map
    aps = {1: (0.495, 15.47), 2: (0.495, 20.607), 5: (18.135, 20.607), 6: (17.359, 14.603),
           7: (22.874, 19.093), 8: (10.325, 21.827)}
    (sx, _), (sy, _), worst = conv.fit_axis_map(aps)
    assert worst < 0.1
    assert sx == pytest.approx(-sy, rel=0.02)  # square pixels; image rows point down, y up


def test_shipped_files_match_the_source():
    rows = _rows(DATA / "lab_links.csv")
    assert len(rows) == 1008
    # the APs' coordinates as the source lists them (AP_idx_Laboratory.csv), by AP number
    aps = {1: (0.495, 15.47), 2: (0.495, 20.607), 5: (18.135, 20.607), 6: (17.359, 14.603),
           7: (22.874, 19.093), 8: (10.325, 21.827)}
    for r in rows:
        assert (float(r["rx_x"]), float(r["rx_y"])) == aps[int(r["rx_id"])]
        assert float(r["tx_y"]) in (15.326, 20.159)  # the two walked lines
        assert 1.25 <= float(r["tx_x"]) <= 22.17
    # rows read off the source by hand (pandas over raw_data/Laboratory/<c>/<c>13.csv and <c>24.csv,
    # circles 1..5, nonzero RSS of the AP in the cell's x range): (user line y, cell x range, AP) ->
    # (samples, mean dBm, std dB, mean x of the cell's samples)
    checked = {(15.326, 1.25, 1): (74, -56.86, 4.87, 1.374), (20.159, 11.5, 2): (43, -45.3, 1.52, 11.621),
               (20.159, 21.75, 7): (45, -43.8, 3.98, 21.875)}
    for (y, x0, ap), (n, mean, std, x) in checked.items():
        r = [r for r in rows if float(r["tx_y"]) == y and x0 <= float(r["tx_x"]) < x0 + 0.25
             and int(r["rx_id"]) == ap]
        assert len(r) == 1
        r = r[0]
        assert (int(r["n_packets"]), float(r["power_db"]), float(r["rssi_std_db"]), float(r["tx_x"])) == (n, mean, std, x)
    walls = _rows(DATA / "lab_walls.csv")
    assert len(walls) == 18 and {w["material"] for w in walls} == {"concrete", "plasterboard"}


def test_the_measured_target_runs_the_lab_hall_under_three_protocols():
    from rfir_stages.reproduce.measured_target import LAB_PROTOCOLS
    from rfir_stages.reproduce.targets import declare

    for quick, every in ((True, "6"), (False, "1")):
        plan, tables = declare(["measured"], quick)
        steps = plan.steps
        thin = steps["data__measured_lab_links"].command
        assert "tests/data/rtt_lab/lab_links.csv" in thin and f"--every-tx {every}" in thin
        assert "tests/data/rtt_lab/lab_walls.csv" in steps["data__measured_lab_room"].command
        for name, protocol, _ in LAB_PROTOCOLS:
            imp = steps[f"data__measured_lab_survey_{name}"].command
            assert (f"--split {protocol}" in imp) if protocol else "--split" not in imp
            fit = steps[f"measured_lab_{name}__rfir_fit"]
            assert any(i.endswith(f"measured_lab/survey_{name}.h5") for i in fit.inputs)
            assert any(i.endswith("measured_lab/scene.h5") for i in fit.inputs)
        # ray tracing of the lab hall in the full variant only
        assert ("measured_lab__raytrace_sweep" in steps) is (not quick)
        table, _ = tables["measured"]
        assert len(table.rows) == 9      # TETAM, the lab hall, the measured-like flat: three protocols each
