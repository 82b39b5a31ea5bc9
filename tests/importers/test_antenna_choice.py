"""Which antenna rf-fit uses: rf_fit.antenna, else what the measurements state, else the simulator's
horn (simulated data, unchanged), else isotropic (said so); tables survive into the rf artifact."""
from types import SimpleNamespace

import numpy as np
import pytest

from rfir_core.errors import ConfigError
from rfir_stages.model.antenna_patterns import antenna_choice, antenna_from_attrs


def meas(attrs=None, simulator=None):
    return SimpleNamespace(attrs=dict(attrs or {}), free={"simulator@attrs": simulator} if simulator else {})


def test_simulated_rcs_data_keep_the_simulators_horn():
    ant = antenna_choice({"antenna": "auto"}, meas(simulator={"antenna_tx": "horn", "horn_hpbw_deg": 30.0}), "rcs", "m.h5")
    assert (ant.kind, ant.hpbw_deg, ant.source) == ("horn", 30.0, "the simulator's")
    ant = antenna_choice({"antenna": "auto"}, meas(simulator={"antenna_tx": "omni"}), "rssi", "m.h5")
    assert ant.kind == "isotropic" and ant.source == "the simulator's"


def test_stated_antenna_wins_over_simulator_and_config_wins_over_both():
    m = meas({"antenna_tx": "horn:25", "antenna_rx": "horn:25"}, simulator={"horn_hpbw_deg": 40.0})
    assert antenna_choice({"antenna": "auto"}, m, "rcs", "m.h5").hpbw_deg == 25.0
    ant = antenna_choice({"antenna": "isotropic"}, m, "rcs", "m.h5")
    assert (ant.kind, ant.source) == ("isotropic", "rf_fit.antenna")


def test_nothing_stated_is_isotropic_and_said():
    ant = antenna_choice({"antenna": "auto"}, meas(), "rcs", "m.h5")
    assert ant.kind == "isotropic" and ant.note().startswith("antenna isotropic (assumed: the measurements state no")


def test_table_pattern_is_used_and_recorded_for_predict():
    m = meas({side: "table:p.csv" for side in ("antenna_tx", "antenna_rx")}
             | {f"{side}_table_{k}": v for side in ("antenna_tx", "antenna_rx")
                for k, v in (("deg", np.array([0.0, 90.0])), ("gain_dbi", np.array([10.0, 0.0])))})
    ant = antenna_choice({"antenna": "auto"}, m, "rcs", "m.h5")
    assert ant.kind == "table" and ant.boresight_gain == pytest.approx(10.0)
    back = antenna_from_attrs(ant.describe())
    assert back == ant and back.boresight_gain == pytest.approx(10.0)


@pytest.mark.parametrize("attrs, task, message", [
    ({"antenna_tx": "horn:30", "antenna_rx": "isotropic"}, "rcs", "rf-fit fits one pattern for both sides"),
    ({"antenna_tx": "horn:30"}, "rcs", "antenna_rx unstated differ"),
    ({"antenna_tx": "dipole:0,0,1", "antenna_rx": "dipole:0,0,1"}, "rcs", "a dipole on a monostatic radar"),
    ({"antenna_tx": "dipole:1,0,0", "antenna_rx": "dipole:1,0,0"}, "rssi", "dipoles along z only"),
])
def test_what_rf_fit_cannot_model_is_refused_before_work(attrs, task, message):
    with pytest.raises(ConfigError, match=message):
        antenna_choice({"antenna": "auto"}, meas(attrs), task, "m.h5")
