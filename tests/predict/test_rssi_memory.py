"""`rfir predict rssi` in bounded memory: a map that would need about 20 GB is refused before any work with
the estimate (the process stays small), and a map is evaluated in blocks of receivers that give the same
values as one block."""
import os
import subprocess
import sys
import time

import numpy as np
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app
from rfir_stages.predict import rssi, rssi_checks

# the reduced room is 4 x 3 m: a 1.2 mm grid is 3333 x 2500 = 8.3 million points, about 20 GB by the estimate
FINE_GRID = "1.0,0.0012"
PEAK_LIMIT_BYTES = 2 * 2**30


# the child reports its own high-water resident memory (VmHWM, which exec resets) at exit: ru_maxrss of a child
# forked from a large test process counts the parent's pages from before exec
_REPORT_PEAK = """
import atexit, runpy, sys
PEAK_FILE = sys.argv.pop(1)
def _peak():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            open(PEAK_FILE, "w").write(line.split()[1])
atexit.register(_peak)
runpy.run_module("rfir_cli.main", run_name="__main__")
"""


def _run_measured(args, tmp_path) -> tuple[int, str, int, float]:
    """(exit code, output, peak resident memory [bytes], seconds) of the CLI in a child process."""
    t0 = time.time()
    peak_file = tmp_path / "peak_kb.txt"
    wrapper = tmp_path / "report_peak.py"
    wrapper.write_text(_REPORT_PEAK)
    proc = subprocess.run([sys.executable, str(wrapper), str(peak_file), *map(str, args)], stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True)
    return proc.returncode, proc.stdout, int(peak_file.read_text()) * 1024, time.time() - t0


def test_a_20_gb_map_is_refused_before_work_in_little_memory(rssi_rf, tmp_path):
    out = tmp_path / "fine.h5"
    code, text, peak, _ = _run_measured(["predict", "rssi", rssi_rf, "--tx", "1.2,2.0,1.8", "--grid", FINE_GRID,
                                         "-o", out], tmp_path)
    lines = [line for line in text.strip().splitlines() if line.strip()]
    assert code == 5, text
    assert len(lines) == 1 and "Traceback" not in text, text
    assert "points" in lines[0] and "GiB, above predict.rssi.max_memory_gb = 8" in lines[0], text
    need = float(lines[0].split("need about ")[1].split(" GiB")[0])
    assert 15 < need < 30, text
    assert peak < PEAK_LIMIT_BYTES, f"peak {peak / 2**30:.2f} GiB"
    assert not out.exists()


def test_estimate_grows_with_points_and_transmitters(rssi_rf):
    from rfir_stages.predict.rssi_model_io import load_predictor

    pred = load_predictor(read_artifact(rssi_rf, "rf"))
    small, large = (rssi.memory_estimate_bytes(pred, n, 512) for n in (1_000, 8_300_000))
    assert small < 1 * 2**30 and large > 15 * 2**30


def test_blocks_give_the_values_of_one_block(rssi_rf, tmp_path, monkeypatch):
    args = ["predict", "rssi", rssi_rf, "--tx", "1.2,2.0,1.8", "--tx", "3.1,0.9,1.5", "--grid", "1.0,0.5"]
    r = CliRunner().invoke(app, [*map(str, args), "-o", str(tmp_path / "one.h5")])
    assert r.exit_code == 0, r.output
    monkeypatch.setattr(rssi, "POINTS_PER_BLOCK", 7)
    monkeypatch.setattr(rssi_checks, "CHECK_BLOCK", 5)
    r2 = CliRunner().invoke(app, [*map(str, args), "-o", str(tmp_path / "blocks.h5")])
    assert r2.exit_code == 0, r2.output
    a, b = read_artifact(tmp_path / "one.h5"), read_artifact(tmp_path / "blocks.h5")
    np.testing.assert_array_equal(a["rx_pos"], b["rx_pos"])
    np.testing.assert_allclose(a["path_gain_db"], b["path_gain_db"], atol=1e-9)
    warn = lambda out: sorted(line for line in out.splitlines() if "warning" in line)  # noqa: E731
    assert warn(r.output) == warn(r2.output)
