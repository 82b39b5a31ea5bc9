"""A survey's own columns: device ids as names, links averaged already, columns rfir does not read."""
import numpy as np
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app

HEAD = "tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz,power_db,tx_id,rx_id,n_packets,rssi_std_db,note\n"
ROWS = ["1,1,1,3,1,1,2.4e9,-50,p001,sensorB,30,2.5,a", "1,1,1,1,4,1,2.4e9,-55,p001,sensorA,1,0,b",
        "2,2,1,3,1,1,2.4e9,-48,p002,sensorB,12,3.0,c"]


def _import(tmp_path, *flags, rows=ROWS):
    src = tmp_path / "survey.csv"
    src.write_text(HEAD + "\n".join(rows) + "\n")
    out = tmp_path / "m.h5"
    return CliRunner().invoke(app, ["import", "csv", str(src), "-o", str(out), *flags]), out


def test_ids_given_as_names_are_numbered_and_said(tmp_path):
    r, out = _import(tmp_path)
    assert r.exit_code == 0, r.output
    m = read_artifact(out, "measurements")
    assert np.asarray(m["tx_id"]).tolist() == [0, 0, 1] and np.asarray(m["rx_id"]).tolist() == [1, 0, 1]
    assert "rx_id holds names: numbered 0..1 in sorted order (sensorA -> 0, sensorB -> 1)" in r.output


def test_columns_rfir_does_not_read_are_named(tmp_path):
    r, _ = _import(tmp_path)
    assert "columns not read by rfir: n_packets, rssi_std_db, note" in r.output


def test_links_averaged_already_keep_their_count_and_spread(tmp_path):
    r, out = _import(tmp_path, "--column", "sample_count=n_packets", "--column", "sample_std_db=rssi_std_db")
    assert r.exit_code == 0, r.output
    m = read_artifact(out, "measurements")
    assert np.asarray(m["sample_count"]).tolist() == [30, 1, 12]
    np.testing.assert_allclose(np.asarray(m["sample_std_db"])[:, 0], [2.5, 0.0, 3.0])
    assert "columns not read by rfir: note" in r.output


def test_a_sample_count_that_is_not_a_whole_count_is_refused_and_nothing_written(tmp_path):
    rows = [ROWS[0].replace(",30,", ",0.5,")] + ROWS[1:]
    r, out = _import(tmp_path, "--column", "sample_count=n_packets", rows=rows)
    assert r.exit_code == 2 and "column sample_count: '0.5' is not a whole number of samples" in r.output
    assert not out.exists()
