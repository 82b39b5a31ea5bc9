"""docs/guide/rssi-survey.md runs as written: its commands, in order, on the measured survey in tests/data."""
import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TUTORIAL = ROOT / "docs" / "guide" / "rssi-survey.md"


def tutorial_commands() -> list[list[str]]:
    """The `rfir` lines of the guide page's first bash block, split as a shell would."""
    block = re.search(r"```bash\n(.*?)```", TUTORIAL.read_text(), re.S).group(1)
    return [shlex.split(line) for line in block.splitlines() if line.startswith("rfir ")]


def test_the_tutorial_has_the_whole_chain():
    steps = [" ".join(c[1:3]) for c in tutorial_commands()]
    assert steps[:4] == ["import csv", "import floorplan", "mesh-gaussians tut/room.ply", "rf-fit tut/scene.h5"]
    assert any(s.startswith("predict rssi") for s in steps)


@pytest.mark.slow
def test_the_tutorial_runs_and_the_model_beats_the_baselines_on_unseen_positions(tmp_path):
    rfir = Path(sys.executable).with_name("rfir")
    for cmd in tutorial_commands():
        args = [str(rfir)] + [a.replace("tut/", f"{tmp_path}/") for a in cmd[1:]]
        run = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=1200)
        assert run.returncode == 0, (cmd, run.stdout[-2000:], run.stderr[-2000:])
    metrics = json.loads((tmp_path / "scored.json").read_text())["metrics"]
    for baseline in ("log_distance", "multiwall", "nearest_links"):
        assert metrics["mae_db"] < metrics[f"baseline_{baseline}_mae_db"], metrics
    assert (tmp_path / "map.csv").exists() and (tmp_path / "map_tx1.tif").exists()
    assert len(list((tmp_path / "maps").glob("*.png"))) >= 3
