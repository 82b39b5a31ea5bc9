"""The CLI: help, version, info, check, and one clear line (no traceback) for every bad input."""
import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from rfir_cli import __version__
from rfir_cli.main import app

runner = CliRunner()


def invoke(*args):
    return runner.invoke(app, list(args))


def assert_one_line_error(result, *fragments, code=None):
    assert result.exit_code != 0
    if code is not None:
        assert result.exit_code == code
    text = result.output.strip()
    assert "Traceback" not in text
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text
    for fragment in fragments:
        assert fragment in text, text


def test_help_and_version():
    result = invoke("--help")
    assert result.exit_code == 0 and "info" in result.output and "check" in result.output
    result = invoke("--version")
    assert result.exit_code == 0 and __version__ in result.output


def test_info_shows_kind_datasets_units_and_provenance(measurements_file):
    result = invoke("info", str(measurements_file))
    assert result.exit_code == 0, result.output
    for text in ("kind: measurements", "path_gain_db", "dB", "tx_pos", "world", "stage=test", "scene=unit"):
        assert text in result.output


def test_check_accepts_valid_and_rejects_wrong_kind(measurements_file):
    assert invoke("check", str(measurements_file)).exit_code == 0
    result = invoke("check", "--kind", "calib", str(measurements_file))
    assert_one_line_error(result, str(measurements_file), "expected 'calib'", code=3)


def test_missing_file(tmp_path):
    missing = tmp_path / "nope.h5"
    assert_one_line_error(invoke("info", str(missing)), str(missing), "file not found", code=2)
    assert_one_line_error(invoke("check", str(missing)), str(missing), "file not found", code=2)


def test_non_hdf5_and_truncated(tmp_path, measurements_file):
    junk = tmp_path / "junk.h5"
    junk.write_bytes(b"\x00" * 100)
    assert_one_line_error(invoke("info", str(junk)), str(junk), "not an HDF5 file")
    cut = tmp_path / "cut.h5"
    cut.write_bytes(measurements_file.read_bytes()[:2000])
    assert_one_line_error(invoke("check", str(cut)), str(cut), "truncated or damaged")


def test_unknown_major_version(measurements_file):
    with h5py.File(measurements_file, "a") as h5:
        h5.attrs["schema_version"] = "9.1.0"
    assert_one_line_error(invoke("info", str(measurements_file)), "schema version 9.1.0 is not supported")


def test_missing_dataset_and_nan_are_named(measurements_file):
    with h5py.File(measurements_file, "a") as h5:
        h5["path_gain_db"][1, 1] = np.nan
        del h5["freq_hz"]
    result = invoke("check", str(measurements_file))
    assert result.exit_code == 3
    assert "missing required dataset 'freq_hz'" in result.output
    assert "'path_gain_db' holds 1 NaN or Inf" in result.output
    assert "Traceback" not in result.output


@pytest.mark.parametrize("override, fragment", [
    ("general.no_such_key=1", "unknown config key 'general.no_such_key'"),
    ("general.work_dir=[1", "cannot read value"),
    ("general.work_dir=3", "must be str"),
])
def test_bad_set_option(measurements_file, override, fragment):
    result = invoke("--set", override, "info", str(measurements_file))
    assert_one_line_error(result, fragment, code=4)


def test_verbose_shows_traceback_on_error(tmp_path):
    result = invoke("-v", "info", str(tmp_path / "nope.h5"))
    assert result.exit_code == 2 and "Traceback" in result.output


def test_bad_device_option(measurements_file):
    result = invoke("--device", "tpu", "info", str(measurements_file))
    assert result.exit_code != 0 and "tpu" in result.output


def test_info_tracer_reports_backend():
    result = invoke("info", "--tracer")
    assert result.exit_code == 0, result.output
    assert "tracer:" in result.output and "cpu" in result.output.lower()
