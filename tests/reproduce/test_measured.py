"""The `measured` reproduce target: a public measured BLE survey (tests/data/public_survey) thinned for the
quick variant, imported once per protocol, fitted and scored; its table reads the results."""
from __future__ import annotations

import importlib.util
from pathlib import Path

from rfir_stages.reproduce.measured_target import MEASURED_PROTOCOLS
from rfir_stages.reproduce.survey import thin
from rfir_stages.reproduce.targets import declare

ROOT = Path(__file__).resolve().parents[2]
LINKS = ROOT / "tests" / "data" / "public_survey" / "tetam_links.csv"


def test_thin_keeps_every_kth_transmitter_and_the_set_up_lines():
    text = LINKS.read_text()
    out, n_links, n_tx = thin(text, 3)
    assert (n_links, n_tx) == (42 * 12, 42)                       # 125 positions: 0, 3, ..., 123
    lines = out.splitlines()
    assert "# power = rssi" in lines and "# tx_power_dbm = 0" in lines
    header = next(ln for ln in lines if not ln.startswith("#"))
    assert header.split(",")[-3:] == ["split", "n_packets", "rssi_std_db"]
    bare, n_all, _ = thin(text, 1, drop_split=True)
    assert n_all == 1500 and "split" not in next(ln for ln in bare.splitlines() if not ln.startswith("#")).split(",")


def test_the_thinning_script_writes_the_kept_links_and_fails_in_one_line(tmp_path, capsys):
    """scripts/survey_thin.py (the workflow's step) writes what `thin` keeps; bad input: one line, exit 2."""
    spec = importlib.util.spec_from_file_location("survey_thin_cli", ROOT / "scripts" / "survey_thin.py")
    cli = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cli)
    out = tmp_path / "sub" / "links.csv"
    assert cli.main([str(LINKS), str(out), "--every-tx", "3"]) == 0
    assert out.read_text() == thin(LINKS.read_text(), 3)[0]
    assert "504 links of 42 transmitters" in capsys.readouterr().out
    assert cli.main([str(LINKS), str(tmp_path / "x.csv"), "--every-tx", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "tetam_links.csv" in err and "every_tx" in err and not (tmp_path / "x.csv").exists()


def test_the_measured_target_imports_each_protocol_and_fits_the_floor_plan():
    for quick, every in ((True, "3"), (False, "1")):
        plan, tables = declare(["measured"], quick)
        steps = plan.steps
        assert f"--every-tx {every}" in steps["data__measured_links"].command
        for name, protocol, _ in MEASURED_PROTOCOLS:
            imp = steps[f"data__measured_survey_{name}"].command
            assert (f"--split {protocol}" in imp) if protocol else ("--split" not in imp and "nosplit" not in imp)
            fit = steps[f"measured_{name}__rfir_fit"]
            assert any(i.endswith(f"measured/survey_{name}.h5") for i in fit.inputs)
            assert any(i.endswith("measured/scene.h5") for i in fit.inputs)
        assert "--preset room" in steps["data__measured_surfels"].command
        assert steps["measured_random__diagnose"].inputs[0].endswith("fits/measured_random.h5")
        table, labels = tables["measured"]
        assert len(table.rows) == 9 and "data__measured_room" in labels  # TETAM, the lab hall, the measured-like flat
        sim = steps["data__measured_flat_sim"].command
        assert "simulate flat" in sim and ("rx_grid=[19,15]" in sim) == quick
        assert any(i.rstrip("/").endswith("measured_flat/sim") for i in steps["data__measured_flat"].inputs)
        for name in ("random", "room", "rx"):
            fit = steps[f"measured_flat_{name}__rfir_fit"]
            assert any(i.rstrip("/").endswith("measured_flat/ml") for i in fit.inputs)
            assert any(i.endswith("measured_flat/plan_scene.h5") for i in fit.inputs)
        assert any("tests/data/public_survey/README.md" in n for n in table.notes if isinstance(n, str))
