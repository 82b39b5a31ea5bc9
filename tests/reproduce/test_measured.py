"""The `measured` reproduce target: a public measured BLE survey (tests/data/public_survey) thinned for the
quick variant, imported once per protocol, fitted and scored; its table reads the results."""
from __future__ import annotations

from pathlib import Path

from rfir_stages.reproduce.survey import thin
from rfir_stages.reproduce.targets import MEASURED_PROTOCOLS, declare

LINKS = Path(__file__).resolve().parents[1] / "data" / "public_survey" / "tetam_links.csv"


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
        assert len(table.rows) == 3 and "data__measured_room" in labels
        assert any("tests/data/public_survey/README.md" in n for n in table.notes if isinstance(n, str))
