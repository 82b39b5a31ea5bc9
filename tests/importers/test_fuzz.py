"""Property-based fuzzing of the CSV and NeRF2 importers and of `rfir check`: whatever the bytes
(malformed, truncated, huge numbers, non-UTF-8), the result is a valid artifact or one error line
naming the file with a non-zero exit, never a traceback and never a partial artifact."""
import shutil

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from rfir_core.artifacts import validate_artifact, write_artifact
from rfir_core.errors import RfirError
from rfir_cli.main import app
from rfir_stages.importers import import_csv, import_nerf2_ble

# derandomized: the same examples on every run, so a run's outcome does not depend on the draw (a random draw once
# left `rfir check` reading a damaged file's attribute for minutes)
FUZZ = settings(max_examples=40, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture])
HEADER = "tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz,power_db,aspect_deg,range_m,split"
GOOD_ROW = "3,0,0,3,0,0.002,2.4e9,-50,0,3,train"

# cells a user's file might hold: numbers, huge or odd ones, words, markup-looking text, empty
CELLS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-10**30, max_value=10**30).map(str),
    st.sampled_from(["", "1e400", "-1e400", "9" * 400, "nan", "inf", "0x10", "1,5", "train", "test", "2",
                     "[red]x[/red]", "[/]", "\"", "'", "#", "=", "\t", "é", "2.4e9", "5.8e9", "-50"]),
    st.text(max_size=8),
)
LINES = st.lists(CELLS, min_size=0, max_size=13).map(",".join)
COMMENTS = st.sampled_from(["", "# antenna = horn:40\n", "# antenna = horn:x\n", "# power = rcs\n",
                            "# tx_power_dbm = 1e999\n", "# unknown = 1\n", "# antenna_tx = table:nope.csv\n",
                            "# polarisation = Q\n", "#\n"])


def _assert_one_error_or_valid(tmp_path, run, out, where: str):
    """run() must write a valid artifact at `out` or raise RfirError naming a file under `where` and
    leave no file (an antenna table named by the CSV is such a file)."""
    try:
        run()
    except RfirError as exc:
        assert where in str(exc)
        assert "\n" not in str(exc).strip()
        assert not out.exists()
        assert not list(out.parent.glob(".*partial*"))
        return False
    assert validate_artifact(out) == []
    out.unlink()
    return True


@FUZZ
@given(comments=COMMENTS, body=st.lists(st.one_of(LINES, st.just(GOOD_ROW)), max_size=6),
       cut=st.integers(min_value=0, max_value=400), junk=st.binary(max_size=12))
def test_csv_importer_fuzz(tmp_path, comments, body, cut, junk):
    path = tmp_path / "links.csv"
    text = (comments + "\n".join([HEADER] + body) + "\n").encode()
    path.write_bytes(text[: len(text) - cut % (len(text) + 1)] + junk)
    _assert_one_error_or_valid(tmp_path, lambda: import_csv(path, tmp_path / "m.h5"), tmp_path / "m.h5", str(tmp_path))


@FUZZ
@given(data=st.binary(max_size=300))
def test_csv_importer_random_bytes(tmp_path, data):
    path = tmp_path / "links.csv"
    path.write_bytes(data)
    _assert_one_error_or_valid(tmp_path, lambda: import_csv(path, tmp_path / "m.h5"), tmp_path / "m.h5", str(path))


@FUZZ
@given(gateways=st.one_of(st.just("g1: [1, 2, 1]\ng2: [3, 0, 1]\n"), st.text(max_size=40),
                          st.sampled_from(["g1: [1e400, 0, 0]\n", "g1: {position: [0, 0]}\n", "- 1\n", "g1: [a, b, c]\n",
                                           "g1: [1, 2, 1]\n"])),
       tx=st.lists(LINES, min_size=0, max_size=4), rssi=st.lists(LINES, min_size=0, max_size=4),
       index=st.sampled_from([None, "0\n1\n", "7\n", "x\n", "-1\n", ""]), junk=st.binary(max_size=6))
def test_nerf2_importer_fuzz(tmp_path, gateways, tx, rssi, index, junk):
    folder = tmp_path / "ble"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir()
    (folder / "gateway_position.yml").write_bytes(gateways.encode() + junk)
    (folder / "tx_pos.csv").write_text("\n".join(["x,y,z", "1,1,1", *tx]) + "\n")
    (folder / "gateway_rssi.csv").write_text("\n".join(["g1,g2", "-60,-70", *rssi]) + "\n")
    if index is not None:
        (folder / "train_index.txt").write_text(index)
    out = tmp_path / "n.h5"
    _assert_one_error_or_valid(tmp_path, lambda: import_nerf2_ble(folder, out), out, str(folder))


def _valid_artifact(path):
    data = {"tx_pos": np.zeros((3, 3)), "rx_pos": np.ones((3, 3)), "freq_hz": np.array([2.4e9]),
            "path_gain_db": np.full((3, 1), -50.0)}
    write_artifact(path, "measurements", data, attrs={"task": "rssi", "scene": "x", "antenna_tx": "horn:40"})
    return path.read_bytes()


@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(min_value=0, max_value=10**6), flips=st.lists(st.tuples(st.integers(0, 10**6),
                                                                               st.integers(0, 255)), max_size=4))
def test_check_on_damaged_files_is_one_line_and_non_zero(tmp_path, cut, flips):
    good = tmp_path / "good.h5"
    blob = bytearray(_valid_artifact(good))
    for where, value in flips:
        blob[where % len(blob)] = value
    bad = tmp_path / "bad.h5"
    bad.write_bytes(bytes(blob[: len(blob) - cut % len(blob)] if cut % 3 else blob))
    result = CliRunner().invoke(app, ["check", str(bad)])
    assert "Traceback" not in result.output and "internal error" not in result.output, result.output
    if result.exit_code != 0:
        assert str(bad) in result.output
        assert all(line.startswith(("invalid:", "error:")) for line in result.output.strip().splitlines())


@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(comments=COMMENTS, body=st.lists(st.one_of(LINES, st.just(GOOD_ROW)), min_size=1, max_size=4))
def test_import_cli_prints_one_line_whatever_the_file_says(tmp_path, comments, body):
    """File contents quoted in an error (e.g. '[/]', which rich would read as markup) print as written."""
    path = tmp_path / "links.csv"
    path.write_text(comments + "\n".join([HEADER] + body) + "\n")
    out = tmp_path / "m.h5"
    result = CliRunner().invoke(app, ["import", "csv", str(path), "-o", str(out)])
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in result.output and "internal error" not in result.output, result.output
    if result.exit_code:
        assert result.output.startswith("error: ") and len(result.output.strip().splitlines()) == 1
        assert not out.exists()
    else:
        assert validate_artifact(out) == []
        out.unlink()
