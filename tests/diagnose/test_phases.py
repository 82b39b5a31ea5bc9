"""Absent phases stay absent: the CSV importer writes no 0.0 for a phase it was not given, and diagnose
does not test phase-needing effects without measured phases (and says so)."""
import numpy as np

from rfir_stages.importers.csv_links import read_links_csv

ATTRS = {"task": "rcs", "scene": "synthetic"}
HEADER = "tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz,power_db,phase_rad\n"


def _csv(tmp_path, phases):
    rows = [f"0,0,1,{i + 1},0,1,2.4e9,{-40 - i},{p}\n" for i, p in enumerate(phases)]
    path = tmp_path / "links.csv"
    path.write_text(HEADER + "".join(rows))
    return read_links_csv(path)["data"]


def test_empty_phase_cells_are_absent_not_zero(tmp_path):
    data = _csv(tmp_path, ["0.5", "", "nan"])
    ch = data["channel"][:, 0]
    assert np.isclose(np.angle(ch[0]), 0.5) and np.isnan(ch[1]) and np.isnan(ch[2])
    assert np.allclose(data["path_gain_db"][:, 0], [-40, -41, -42])


def test_no_phase_at_all_writes_no_channel(tmp_path):
    assert "channel" not in _csv(tmp_path, ["", "", ""])


def test_diagnose_says_leakage_was_not_tested_without_phases(tmp_path):
    from rfir_core.artifacts import write_artifact
    from rfir_stages.diagnose import run

    asp = np.radians(np.arange(0, 360, 2.0))
    tx = np.stack([3 * np.cos(asp), 3 * np.sin(asp), np.zeros_like(asp)], 1)
    pred = -75 + 8 * np.cos(2 * asp) ** 8 + 4 * np.cos(5 * asp)
    base = {"tx_pos": tx, "rx_pos": tx, "freq_hz": np.array([2.4e9]), "aspect_rad": asp,
            "range_m": np.full(len(asp), 3.0), "split": np.arange(len(asp)) % 2}
    write_artifact(tmp_path / "model.h5", "measurements", {**base, "path_gain_db": pred[:, None]}, attrs=ATTRS)
    meas = pred + np.random.default_rng(0).normal(0, 0.5, len(asp))
    zero_phase = 10 ** (meas / 20) + 0j            # what an importer filling 0.0 would write
    write_artifact(tmp_path / "meas.h5", "measurements", {**base, "path_gain_db": meas[:, None],
                                                           "channel": zero_phase[:, None]}, attrs=ATTRS)
    res = run(tmp_path / "model.h5", tmp_path / "meas.h5", tmp_path / "rep")
    import json

    out = json.loads((tmp_path / "rep" / "results.json").read_text())
    assert "placeholders" in out["phases"] and out["untested_without_phase"] == ["leakage"]
    assert "Not tested without measured phases: leakage" in (tmp_path / "rep" / "report.md").read_text()
    assert res.named == []
