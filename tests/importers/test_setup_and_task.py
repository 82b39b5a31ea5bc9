"""Import records the measurement set-up (header < sidecar < flags), detects the task by a stated rule,
and refuses aspect columns that disagree with the positions (naming the row)."""
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact, validate_artifact, write_artifact
from rfir_core.errors import InputFileError
from rfir_cli.main import app
from rfir_core.physics.closed_forms import rcs_from_path_gain
from rfir_stages.importers import import_csv

HEADER = "tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz,power_db,aspect_deg,range_m"


def radar_rows(aspects, freqs, range_m=3.0, value=-20.0, sign=-1.0, zero=0.0):
    """Monostatic rows at azimuth sign * aspect + zero (the convention: sign -1, zero 0)."""
    lines = []
    for a in aspects:
        phi = math.radians(sign * a + zero)
        x, y = range_m * math.cos(phi), range_m * math.sin(phi)
        for f in freqs:
            lines.append(f"{x:.6f},{y:.6f},0,{x:.6f},{y:.6f},0.002,{f:g},{value},{a:g},{range_m:g}")
    return lines


def write(tmp_path, lines, comments=(), header=HEADER, name="links.csv"):
    path = tmp_path / name
    path.write_text("\n".join(list(comments) + [header] + lines) + "\n")
    return path


def test_header_options_are_recorded_and_sidecar_and_flags_win(tmp_path):
    path = write(tmp_path, radar_rows([0, 90], [2.4e9]),
                 comments=["# a comment without options", "# antenna_tx = horn:40", "# antenna_rx = isotropic",
                           "# polarisation = H"])
    art = read_artifact(import_csv(path, tmp_path / "a.h5").path)
    assert (art.attrs["antenna_tx"], art.attrs["antenna_rx"], art.attrs["polarisation"]) == ("horn:40", "isotropic", "H")
    assert art.attrs["power"] == "path_gain"
    (tmp_path / "links.toml").write_text('antenna = "dipole:0,0,2"\n')
    art = read_artifact(import_csv(path, tmp_path / "b.h5").path)
    assert (art.attrs["antenna_tx"], art.attrs["antenna_rx"]) == ("dipole:0,0,1", "dipole:0,0,1")
    art = read_artifact(import_csv(path, tmp_path / "c.h5", antenna_rx="horn:25", polarisation="v").path)
    assert (art.attrs["antenna_tx"], art.attrs["antenna_rx"], art.attrs["polarisation"]) == ("dipole:0,0,1", "horn:25", "V")
    assert art.provenance.extra["setup_origin"]["antenna_rx"] == "flag"


def test_no_antenna_stated_records_none_and_says_so(tmp_path):
    result = import_csv(write(tmp_path, radar_rows([0, 90], [2.4e9])), tmp_path / "m.h5")
    art = read_artifact(result.path)
    assert "antenna_tx" not in art.attrs and "antenna_rx" not in art.attrs
    assert any("antenna_tx not stated (rf-fit will assume isotropic)" in n for n in result.notes)


def test_pattern_table_is_stored_in_the_artifact(tmp_path):
    (tmp_path / "pattern.csv").write_text("theta_deg,gain_dbi\n0,9\n30,6\n90,-20\n")
    path = write(tmp_path, radar_rows([0], [2.4e9]), comments=["# antenna = table:pattern.csv"])
    art = read_artifact(import_csv(path, tmp_path / "m.h5").path)
    assert art.attrs["antenna_tx"] == "table:pattern.csv"
    np.testing.assert_array_equal(art.attrs["antenna_rx_table_gain_dbi"], [9, 6, -20])
    assert validate_artifact(tmp_path / "m.h5") == []


def test_power_rcs_converts_by_the_radar_equation(tmp_path):
    """power = rcs: path gain = sigma / ((4 pi)^3 r^4 / (G^2 lambda^2)); a 40 deg horn (G0 = 2 (q + 1))."""
    path = write(tmp_path, radar_rows([0, 90], [2.4e9, 5.8e9], range_m=4.0, value=-7.5))
    art = read_artifact(import_csv(path, tmp_path / "m.h5", power="rcs", antenna="horn:40").path)
    q = math.log(0.5) / math.log(math.cos(math.radians(20.0)))
    g0 = 2 * (q + 1)
    lam = 299792458.0 / np.array([2.4e9, 5.8e9])
    expected = -7.5 + 10 * np.log10(g0**2 * lam**2 / ((4 * math.pi) ** 3 * 4.0**4))
    np.testing.assert_allclose(art["path_gain_db"], np.tile(expected, (2, 1)), atol=1e-9)
    np.testing.assert_allclose(art["rcs_dbsm"], -7.5)
    back = 10 * np.log10(rcs_from_path_gain(10 ** (art["path_gain_db"] / 10), 4.0, art["freq_hz"][None], g0, g0))
    np.testing.assert_allclose(back, -7.5, atol=1e-9)


def test_power_rssi_needs_tx_power(tmp_path):
    path = write(tmp_path, radar_rows([0], [2.4e9]), comments=["# power = rssi"])
    with pytest.raises(InputFileError, match="power = rssi needs tx_power_dbm"):
        import_csv(path, tmp_path / "m.h5")
    art = read_artifact(import_csv(path, tmp_path / "m.h5", tx_power_dbm=20).path)
    assert art.attrs["power"] == "rssi" and art["path_gain_db"][0, 0] == -40.0


@pytest.mark.parametrize("comments, flags, message", [
    (["# antenna_tx = horn"], {}, "antenna_tx 'horn': expected isotropic, dipole"),
    (["# antenna = horn:400"], {}, "beamwidth must be 1..180"),
    (["# antena = horn:40"], {}, "line 1: unknown option 'antena'"),
    ([], {"antenna": "table:missing.csv"}, "antenna table not found"),
    ([], {"polarisation": "X"}, "expected V or H"),
    ([], {"power": "watts"}, "power 'watts': expected path_gain, rcs, rssi"),
    ([], {"tx_power_dbm": 10, "power": "path_gain"}, "tx_power_dbm goes with power = rssi"),
    ([], {"task": "radar"}, "task 'radar': expected"),
])
def test_bad_setup_is_one_clear_error_and_nothing_written(tmp_path, comments, flags, message):
    out = tmp_path / "m.h5"
    with pytest.raises(InputFileError, match=message):
        import_csv(write(tmp_path, radar_rows([0], [2.4e9]), comments=comments), out, **flags)
    assert not out.exists()


def test_bad_sidecar_names_the_sidecar(tmp_path):
    path = write(tmp_path, radar_rows([0], [2.4e9]))
    (tmp_path / "links.toml").write_text("antenna = [1, 2\n")
    with pytest.raises(InputFileError, match="links.toml: not a readable TOML"):
        import_csv(path, tmp_path / "m.h5")
    (tmp_path / "links.toml").write_text('antena = "horn:40"\n')
    with pytest.raises(InputFileError, match="links.toml: unknown key"):
        import_csv(path, tmp_path / "m.h5")


@pytest.mark.parametrize("freqs, task", [
    ([2.4e9], "rcs"),
    ([2.4e9, 5.8e9], "rcs"),                                   # two discrete frequencies: narrowband
    (list(np.linspace(8e9, 12e9, 9)), "wideband"),              # a dense band
    (list(np.linspace(8e9, 12e9, 9)) + [24e9], "rcs"),          # a band plus a far one: discrete
])
def test_task_rule(tmp_path, freqs, task):
    result = import_csv(write(tmp_path, radar_rows([0, 90], freqs)), tmp_path / "m.h5")
    assert result.task == task and read_artifact(result.path).attrs["task"] == task
    assert result.notes[0].startswith(f"task {task}: ")


def test_task_can_be_forced(tmp_path):
    result = import_csv(write(tmp_path, radar_rows([0, 90], [2.4e9, 5.8e9])), tmp_path / "m.h5", task="wideband")
    assert result.task == "wideband"


@pytest.mark.parametrize("sign, zero, why", [
    (1.0, 0.0, "the aspect turns the other way (sign): negate aspect_deg"),
    (-1.0, 30.0, "off by the same +30.0 deg (zero of the turntable): subtract 30.0 from aspect_deg"),
    (1.0, 30.0, "negate aspect_deg and shift it"),
])
def test_turntable_disagreement_names_the_first_row_and_why(tmp_path, sign, zero, why):
    path = write(tmp_path, radar_rows([0, 10, 20], [2.4e9], sign=sign, zero=zero), comments=["# power = path_gain"])
    out = tmp_path / "m.h5"
    with pytest.raises(InputFileError) as info:
        import_csv(path, out)
    text = str(info.value)
    first_bad = 4 if (sign, zero) == (1.0, 0.0) else 3   # line 1 comment, 2 header; aspect 0 agrees when only the sign is off
    assert f"line {first_bad}: aspect_deg" in text and why in text and str(path) in text
    assert not out.exists()


def test_turntable_agreement_passes_and_bistatic_rows_are_not_checked(tmp_path):
    assert import_csv(write(tmp_path, radar_rows(range(0, 360, 45), [2.4e9])), tmp_path / "m.h5").links == 8
    bistatic = ["0,-3,1,3,0,1,2.4e9,-50,0,3"]
    assert import_csv(write(tmp_path, bistatic, name="b.csv"), tmp_path / "b.h5").links == 1


def test_check_refuses_bad_setup_attributes(tmp_path):
    data = {"tx_pos": np.zeros((1, 3)), "rx_pos": np.ones((1, 3)), "freq_hz": np.array([2.4e9]),
            "path_gain_db": np.array([[-50.0]])}
    path = tmp_path / "m.h5"
    write_artifact(path, "measurements", data, attrs={"task": "rssi", "scene": "x"})
    import h5py

    with h5py.File(path, "a") as h5:
        h5.attrs["antenna_tx"] = "horn:wide"
        h5.attrs["power"] = "watts"
        h5.attrs["antenna_rx"] = "table:p.csv"
    problems = validate_artifact(path)
    assert any("'antenna_tx' is 'horn:wide', not valid" in p for p in problems)
    assert any("'power' is 'watts', expected one of path_gain, rcs, rssi" in p for p in problems)
    assert any("'antenna_rx' is a table but antenna_rx_table_deg" in p for p in problems)
    result = CliRunner().invoke(app, ["check", str(path)])
    assert result.exit_code == 3 and "Traceback" not in result.output


def test_cli_prints_the_task_rule_and_the_setup(tmp_path):
    path = write(tmp_path, radar_rows([0, 90], [2.4e9, 5.8e9]), comments=["# antenna = horn:40"])
    result = CliRunner().invoke(app, ["import", "csv", str(path), "-o", str(tmp_path / "m.h5")])
    assert result.exit_code == 0, result.output
    assert "task rcs: 2 discrete frequencies" in result.output
    assert "antenna_tx horn:40 (header)" in result.output and "power_db is path_gain (default)" in result.output


def test_the_shipped_radar_example_imports_as_documented(tmp_path):
    """docs/examples/radar_rcs.csv: a 0.1 m sphere (RCS pi a^2) seen by 40-degree horns, power = rcs."""
    from pathlib import Path

    example = Path(__file__).resolve().parents[2] / "docs" / "examples" / "radar_rcs.csv"
    result = import_csv(example, tmp_path / "m.h5")
    art = read_artifact(result.path)
    assert (result.links, result.freqs, result.task) == (24, 2, "rcs")
    assert (art.attrs["antenna_tx"], art.attrs["polarisation"], art.attrs["power"]) == ("horn:40", "V", "rcs")
    np.testing.assert_allclose(art["rcs_dbsm"], 10 * np.log10(math.pi * 0.1**2), atol=0.005)
    q = math.log(0.5) / math.log(math.cos(math.radians(20.0)))
    back = 10 * np.log10(rcs_from_path_gain(10 ** (art["path_gain_db"] / 10), art["range_m"][:, None],
                                            art["freq_hz"][None], 2 * (q + 1), 2 * (q + 1)))
    np.testing.assert_allclose(back, art["rcs_dbsm"], atol=1e-9)
