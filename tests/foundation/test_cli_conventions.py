"""The CLI's conventions as a user meets them: click-style help, the exit codes listed, piped output
unbroken, `check` going through every file, plural agreement."""
import re
from pathlib import Path

import h5py
import pytest
import typer
from typer.testing import CliRunner

from rfir_core.artifacts import write_artifact
from rfir_cli.main import app
from rfir_core.provenance import Provenance
from rfir_core.text import plural, standard_errors

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[2]


def _paths() -> list[list[str]]:
    out = []

    def walk(cmd, path):
        out.append(path)
        for name, sub in sorted((getattr(cmd, "commands", None) or {}).items()):
            walk(sub, path + [name])

    walk(typer.main.get_command(app), [])
    return out


@pytest.mark.parametrize("path", _paths(), ids=lambda p: " ".join(p) or "rfir")
def test_help_placeholders_are_click_style(path):
    out = runner.invoke(app, path + ["--help"]).output
    usage = out.splitlines()[0]
    assert "{" not in usage and "<" not in usage, usage
    assert not re.search(r"<(str|int|float|path|bool|list\[[a-z]+\])>", out), out
    assert "--help, -h" not in out


def test_usage_lines_name_the_arguments():
    assert runner.invoke(app, ["simulate", "--help"]).output.startswith("Usage: rfir simulate [OPTIONS] SCENE OUT")
    assert "Usage: rfir check [OPTIONS] ARTIFACT..." in runner.invoke(app, ["check", "--help"]).output
    rssi = runner.invoke(app, ["predict", "rssi", "--help"]).output
    assert "--tx X,Y,Z" in rssi and "--grid HEIGHT,STEP" in rssi
    top = runner.invoke(app, ["--help"]).output
    assert "--config FILE" in top and "--set SECTION.KEY=VALUE" in top
    missing = runner.invoke(app, ["rf-fit", "scene.h5"])
    assert missing.exit_code == 2 and "Missing argument 'MEASUREMENTS'" in missing.output


def test_info_says_the_artifact_is_required_unless_tracer():
    out = runner.invoke(app, ["info", "--help"]).output
    assert "Usage: rfir info [OPTIONS] [ARTIFACT]" in out and "required unless --tracer" in out
    result = runner.invoke(app, ["info"])
    assert result.exit_code == 4
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "missing ARTIFACT" in lines[0] and "--tracer" in lines[0], result.output


def test_exit_codes_are_listed_in_help_and_readme():
    out = runner.invoke(app, ["--help"]).output
    from rfir_core.errors import ConfigError, InputFileError, RfirError, SchemaError, StageError
    codes = {RfirError.exit_code, InputFileError.exit_code, SchemaError.exit_code, ConfigError.exit_code,
             StageError.exit_code, 70, 130}
    block = out[out.index("Exit codes"):]
    for code in codes:
        assert re.search(rf"^\s+{code}\s+\w", block, re.M), block
    readme = (ROOT / "README.md").read_text()
    line = readme[readme.index("Exit codes:"):][:400]
    for code in codes:
        assert re.search(rf"\b{code} [a-z]", line), line


def _measurements(path):
    import numpy as np
    rng = np.random.default_rng(0)
    data = {"tx_pos": rng.normal(size=(3, 3)), "rx_pos": rng.normal(size=(3, 3)), "freq_hz": np.array([2.4e9]),
            "path_gain_db": rng.uniform(-90, -40, size=(3, 1))}
    return write_artifact(path, "measurements", data, attrs={"task": "rssi", "scene": "unit"},
                          provenance=Provenance(stage="test"))


def test_check_goes_through_every_file_and_exits_with_the_worst_code(tmp_path):
    a, c = _measurements(tmp_path / "a.h5"), _measurements(tmp_path / "c.h5")
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"\x00" * 100)
    result = runner.invoke(app, ["check", str(a), str(bad), str(c)])
    assert result.exit_code == 2, result.output
    assert f"ok {a}" in result.output and f"ok {c}" in result.output
    assert f"invalid: {bad}: not an HDF5 file" in result.output
    assert "1 of 3 artifacts failed validation" in result.output and "Traceback" not in result.output
    schema_bad = _measurements(tmp_path / "s.h5")
    with h5py.File(schema_bad, "a") as h5:
        del h5["freq_hz"]
    result = runner.invoke(app, ["check", str(schema_bad), str(a)])
    assert result.exit_code == 3 and f"ok {a}" in result.output, result.output
    result = runner.invoke(app, ["check", str(schema_bad), str(bad), str(tmp_path / "missing.h5"), str(a)])
    assert result.exit_code == 3 and "3 of 4 artifacts failed validation" in result.output, result.output
    assert "missing.h5: file not found" in result.output


def test_piped_output_is_not_broken_mid_sentence(tmp_path):
    """CliRunner is not a terminal: a message longer than 80 columns stays on one line."""
    from rfir_cli.context import console, err_console
    assert not console.is_terminal
    long = " ".join(f"word{i}" for i in range(60))
    with console.capture() as cap:
        console.print(long)
    assert cap.get().strip() == long
    with err_console.capture() as cap:
        err_console.print(long)
    assert cap.get().strip() == long
    result = runner.invoke(app, ["info", str(tmp_path / ("a_rather_long_folder_name_" * 4) / "file.h5")])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].endswith("file not found"), result.output


def test_plural_and_standard_errors():
    assert plural(1, "frequency") == "1 frequency" and plural(2, "frequency") == "2 frequencies"
    assert plural(0, "link") == "0 links" and plural(3, "key") == "3 keys" and plural(2, "box") == "2 boxes"
    assert plural(2, "datum", "data") == "2 data"
    assert standard_errors(1.26) == "+1.3 SE" and standard_errors(-0.04) == "-0.0 SE"
    assert standard_errors(3e299) == "not determined by the links"
    assert standard_errors(float("inf")) == standard_errors(float("nan")) == "not determined by the links"
