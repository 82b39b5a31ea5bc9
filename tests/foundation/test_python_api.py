"""The Python API's guide page (docs/guide/python-api.md) runs as written: its python block, on the small room of
the RSSI tests (tests/rssi/helpers.py: a partition wall with a doorway, synthetic measurements), and what it
prints and computes is checked against the geometry: removing the partition raises the map behind it."""
import importlib.util
import re
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "guide" / "python-api.md"


def _room_helpers():
    spec = importlib.util.spec_from_file_location("rssi_room_helpers", ROOT / "tests" / "rssi" / "helpers.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _python_block() -> str:
    blocks = re.findall(r"```python\n(.*?)```", PAGE.read_text(), re.S)
    assert len(blocks) == 1, f"{PAGE.name}: expected one python block, found {len(blocks)}"
    return blocks[0]


def test_the_page_is_short_and_names_its_data_command():
    text = PAGE.read_text()
    assert len(text.splitlines()) < 80
    assert "helpers.write_scene('scene.h5'); helpers.write_measurements('survey.h5')" in text


def test_the_guide_example_runs_and_removing_the_partition_raises_the_map_behind_it(tmp_path, monkeypatch, capsys):
    helpers = _room_helpers()
    helpers.write_scene(tmp_path / "scene.h5")
    helpers.write_measurements(tmp_path / "survey.h5")
    monkeypatch.chdir(tmp_path)
    scope: dict = {}
    exec(compile(_python_block(), str(PAGE), "exec"), scope)
    printed = capsys.readouterr().out
    assert "held-out MAE" in printed and "partition: eps_r" in printed
    # every material's |Gamma(0)| lies inside the range the training links allow (rf-fit's reflection ranges)
    for name, m in scope["model"].materials().items():
        lo, hi = m["gamma_normal_range"]
        assert lo - 1e-6 <= m["gamma_normal_abs"] <= hi + 1e-6, (name, m)
    for name in ("rf.h5", "rf_no_partition.h5", "rf_copy.h5"):
        assert (tmp_path / name).is_file(), name
    survey, test = scope["survey"], scope["test"]
    assert scope["pred"].shape == (int(test.sum()), 1)
    before, change = scope["before"], scope["change"]
    means = np.asarray(survey["rx_pos"])
    assert before.path_gain_db.shape == (len(before.x_m), len(before.y_m), 1)
    assert before.x_m.min() > 0 and before.x_m.max() < helpers.ROOM[0] and np.all(np.diff(before.x_m) > 0)
    assert len(means) and np.isfinite(before.path_gain_db).sum() > 0.9 * before.path_gain_db.size
    # the transmitter stands at x = 1.2 m, in front of the partition (x = PART_X); behind it the wall's
    # transmission loss is gone, in front only its reflection is
    x = before.x_m[:, None] * np.ones((1, len(before.y_m)))
    behind, front = change[..., 0][x > helpers.PART_X + 0.2], change[..., 0][x < helpers.PART_X - 0.2]
    assert np.nanmean(behind) > 0.5, np.nanmean(behind)
    assert np.nanmean(behind) > abs(np.nanmean(front)), (np.nanmean(behind), np.nanmean(front))
