"""`rfir edit --freq`: the radio change of an edit drawn at a frequency other than the fitted one.

In a room whose every material is air the room model predicts free space, so its map at 5.8 GHz lies
20 log10(2.4 / 5.8) dB (-7.7 dB) below its map at 2.4 GHz at every receiver (Friis: the received power scales with
the wavelength squared); a frequency outside the material laws' range is refused in one line before anything is
written.
"""
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from rfir_cli.main import app
from rfir_stages.edit import run
from rfir_stages.edit.script import edits_from_options

from ..rssi.helpers import write_air_room

TX_M = (1.0, 1.5, 1.8)


@pytest.fixture(scope="module")
def air_room(tmp_path_factory):
    return write_air_room(tmp_path_factory.mktemp("air") / "rf.h5")


def _edit(rf, tmp_path, name, freq_hz):
    return run(rf, tmp_path / f"{name}.h5", edits_from_options(["label:table"], ["translate:1.5,0.5,0"], False),
               plot_path=tmp_path / f"{name}.png", map_tx=TX_M, freq_hz=freq_hz)


def test_edit_map_at_5g8_is_the_2g4_map_scaled_as_free_space(air_room, tmp_path):
    low, high = _edit(air_room, tmp_path, "low", None), _edit(air_room, tmp_path, "high", 5.8e9)
    assert (low.radio_freq_hz, low.radio_freq_assumed) == (2.4e9, True)
    assert (high.radio_freq_hz, high.radio_freq_assumed) == (5.8e9, False)
    a, b = low.radio_change, high.radio_change
    assert a["points"] == b["points"] >= 30
    np.testing.assert_array_equal(a["rx_m"], b["rx_m"])
    # free space at every receiver (independent closed form), then the scaling between the two frequencies
    d = np.linalg.norm(a["rx_m"] - np.asarray(TX_M), axis=1)
    for res, f in ((a, 2.4e9), (b, 5.8e9)):
        friis = 20 * np.log10(299_792_458.0 / f / (4 * math.pi * d))
        np.testing.assert_allclose(res["before_db"], friis, atol=1e-3)
        np.testing.assert_allclose(res["after_db"], friis, atol=1e-3)    # a table of air moved changes nothing
    np.testing.assert_allclose(b["before_db"] - a["before_db"], 20 * math.log10(2.4 / 5.8), atol=1e-6)
    assert high.radio_plot.is_file()


def test_edit_cli_prints_the_frequency_and_refuses_one_outside_the_range(air_room, tmp_path):
    invoke = lambda *a: CliRunner().invoke(app, [str(x) for x in a])  # noqa: E731
    common = ["--select", "label:table", "--op", "translate:1.5,0.5,0", "--map-tx", "1,1.5,1.8"]
    r = invoke("edit", air_room, "-o", tmp_path / "e.h5", *common, "--plot", tmp_path / "e.png")
    assert r.exit_code == 0, r.output
    assert "at 2.4 GHz (the frequency the model was fitted at; --freq sets another)" in " ".join(r.output.split())
    r = invoke("edit", air_room, "-o", tmp_path / "f.h5", *common, "--plot", tmp_path / "f.png", "--freq", "5.8e9")
    assert r.exit_code == 0, r.output
    assert "f_radio.png at 5.8 GHz (mean" in " ".join(r.output.split())
    r = invoke("edit", air_room, "-o", tmp_path / "g.h5", *common, "--plot", tmp_path / "g.png", "--freq", "500e9")
    lines = [x for x in r.output.splitlines() if x.strip()]
    assert r.exit_code != 0 and "Traceback" not in r.output, r.output
    assert len(lines) == 1 and "--freq 5e+11: frequency 500 GHz is outside 1-100 GHz" in lines[0], r.output
    assert not (tmp_path / "g.h5").exists()
