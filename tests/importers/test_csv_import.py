"""`rfir import csv`: values land in the right cells; every bad-row kind is reported with its line."""
import numpy as np
import pytest
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_core.errors import InputFileError
from rfir_cli.main import app
from rfir_stages.importers import import_csv

HEADER = "tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz,power_db"
GOOD = [
    "0,0,1,3,0,1,2.4e9,-50",
    "0,0,1,3,0,1,5.8e9,-58",
    "0,0,1,0,4,1,2.4e9,-53",
    "0,0,1,0,4,1,5.8e9,-61",
]


def write(tmp_path, lines, header=HEADER):
    path = tmp_path / "links.csv"
    path.write_text("\n".join([header] + lines) + "\n")
    return path


def test_links_and_frequencies_are_gridded(tmp_path):
    result = import_csv(write(tmp_path, GOOD), tmp_path / "m.h5", scene="lab")
    art = read_artifact(result.path, "measurements")
    assert (result.links, result.freqs, result.task) == (2, 2, "rssi")
    np.testing.assert_array_equal(art["freq_hz"], [2.4e9, 5.8e9])
    np.testing.assert_array_equal(art["path_gain_db"], [[-50, -58], [-53, -61]])
    np.testing.assert_array_equal(art["rx_pos"], [[3, 0, 1], [0, 4, 1]])
    assert art.attrs["scene"] == "lab" and art.provenance.inputs


def test_optional_columns_phase_rcs_split(tmp_path):
    header = HEADER + ",phase_rad,aspect_deg,range_m,rcs_dbsm,split"
    lines = ["3,0,0,3,0,0,2.4e9,-70,0.5,0,3,-10,train", "0,-3,0,0,-3,0,2.4e9,-71,0.5,90,3,-12,test"]
    art = read_artifact(import_csv(write(tmp_path, lines, header), tmp_path / "r.h5", tx_power_dbm=10).path)
    assert art.attrs["task"] == "rcs"
    np.testing.assert_allclose(art["aspect_rad"], [0, np.pi / 2])
    np.testing.assert_array_equal(art["split"], [0, 1])
    np.testing.assert_allclose(art["path_gain_db"][:, 0], [-80, -81])
    np.testing.assert_allclose(20 * np.log10(np.abs(art["channel"][:, 0])), [-80, -81])
    np.testing.assert_allclose(np.angle(art["channel"][:, 0]), 0.5)


@pytest.mark.parametrize("lines, header, message", [
    (GOOD[:1] + ["0,0,abc,3,0,1,5.8e9,-58"], HEADER, "line 3, column tx_z: 'abc' is not a number"),
    (GOOD[:1] + ["0,0,1,3,0,1,5.8e9,nan"], HEADER, "line 3, column power_db: nan is not a finite number"),
    (["0,0,1,3,0,1,2.4e9"], "tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz", "missing required column(s): power_db"),
    (GOOD + ["0,0,1,3,0,1,2.4e9,-49"], HEADER, "lines 2 and 6: the same link and frequency with different values"),
    (["0,0,1000,3000,0,1000,2.4e9,-50"], HEADER, "looks like millimetres"),
    (["0,0,1,3,0,1,2.4,-50"], HEADER, "give Hz, not GHz"),
    (GOOD[:3], HEADER, "lacks frequency 5.8e+09 Hz"),
    ([], HEADER, "no data rows"),
])
def test_bad_rows_are_named_and_nothing_is_written(tmp_path, lines, header, message):
    out = tmp_path / "out.h5"
    with pytest.raises(InputFileError) as info:
        import_csv(write(tmp_path, lines, header), out)
    assert message in str(info.value)
    assert str(tmp_path / "links.csv") in str(info.value)
    assert not out.exists()


def test_identical_duplicates_are_merged(tmp_path):
    result = import_csv(write(tmp_path, GOOD + GOOD[:1]), tmp_path / "m.h5")
    assert result.links == 2


def test_many_problems_are_summarised(tmp_path):
    lines = [f"0,0,x{i},3,0,1,2.4e9,-50" for i in range(10)]
    with pytest.raises(InputFileError, match="10 problems, nothing written: .*and 4 more"):
        import_csv(write(tmp_path, lines), tmp_path / "o.h5")


def test_cli_bad_file_one_line_and_exit_code(tmp_path):
    path = write(tmp_path, ["0,0,1,3,0,1,2.4e9,oops"])
    result = CliRunner().invoke(app, ["import", "csv", str(path), "-o", str(tmp_path / "o.h5")])
    assert result.exit_code == 2
    assert "line 2, column power_db" in result.output and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not (tmp_path / "o.h5").exists()


def test_cli_does_not_clobber_existing_artifact_on_error(tmp_path):
    good = import_csv(write(tmp_path, GOOD), tmp_path / "m.h5").path
    before = good.read_bytes()
    bad = tmp_path / "bad.csv"
    bad.write_text(HEADER + "\n0,0,1,3,0,1,2.4e9,\n")
    result = CliRunner().invoke(app, ["import", "csv", str(bad), "-o", str(good)])
    assert result.exit_code == 2 and good.read_bytes() == before
