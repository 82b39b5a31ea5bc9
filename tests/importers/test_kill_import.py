"""`rfir import csv` killed (SIGKILL) part-way through a large file leaves nothing half-written at -o:
the path is absent, or holds the artifact that was there before, byte for byte, or a complete valid
artifact (the import finished first). A temporary file (".NAME.partial-PID") may remain beside it."""
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from rfir_core.artifacts import validate_artifact, write_artifact

ROWS = 100_000          # ~ 4 MB of CSV: seconds to parse, so a kill lands mid-way
IMPORT = [sys.executable, "-m", "rfir_cli.main", "import", "csv"]


@pytest.fixture(scope="module")
def big_csv(tmp_path_factory):
    """ROWS links from two transmitters in a room, each sampled twice (for --average), path gains under free space."""
    path = tmp_path_factory.mktemp("big") / "survey.csv"
    rng = np.random.default_rng(0)
    rx = np.column_stack([rng.uniform(0, 6, ROWS // 2), rng.uniform(0, 5, ROWS // 2), np.full(ROWS // 2, 1.0)])
    tx = np.where(np.arange(ROWS // 2)[:, None] % 2 == 0, [0.5, 0.5, 2.0], [5.0, 4.0, 2.0])
    d = np.linalg.norm(rx - tx, axis=1)
    pg = 20 * np.log10(299792458.0 / 2.4e9 / (4 * math.pi * d)) - 5
    with open(path, "w") as handle:
        handle.write("tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz,power_db\n")
        for shift in (0.0, -1.0):
            for t, r, g in zip(tx, rx, pg):
                handle.write(f"{t[0]},{t[1]},{t[2]},{r[0]:.6f},{r[1]:.6f},{r[2]},2.4e9,{g + shift:.3f}\n")
    return path


def _kill_after(args, delay_s: float, watch_dir, out_name: str):
    """Start an import, SIGKILL it after delay_s (or, for delay_s < 0, as soon as its temporary file
    appears); returns the process's return code."""
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    start = time.time()
    try:
        while proc.poll() is None and time.time() - start < 120:
            if delay_s >= 0 and time.time() - start >= delay_s:
                break
            if delay_s < 0 and any(p.name.startswith(f".{out_name}.partial-") for p in watch_dir.iterdir()):
                break
            time.sleep(0.002)
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    return proc.returncode


def _assert_nothing_partial(out, before):
    """-o is absent, byte-identical to what was there, or a complete valid artifact of the import."""
    if not out.exists():
        assert before is None, "a killed import removed the artifact that was at -o"
        return
    if before is not None and out.read_bytes() == before:
        return
    assert validate_artifact(out) == [], "a killed import left a broken file at -o"
    import h5py

    with h5py.File(out, "r") as h5:
        assert h5.attrs["scene"] == "imported" and h5["path_gain_db"].shape == (ROWS // 2, 1)


@pytest.mark.parametrize("delay_s, existing", [(0.3, False), (1.5, True), (3.0, False), (-1, True)])
def test_killed_import_leaves_no_partial_artifact(big_csv, tmp_path, delay_s, existing):
    out = tmp_path / "m.h5"
    before = None
    if existing:
        write_artifact(out, "measurements", {"tx_pos": np.zeros((1, 3)), "rx_pos": np.ones((1, 3)),
                                             "freq_hz": np.array([2.4e9]), "path_gain_db": np.array([[-50.0]])},
                       attrs={"task": "rssi", "scene": "before"})
        before = out.read_bytes()
    code = _kill_after(IMPORT + [str(big_csv), "-o", str(out), "--average", "mean-db", "--split", "random:0.2"],
                       delay_s, tmp_path, out.name)
    if delay_s == 0.3:
        assert code == -signal.SIGKILL, "the import finished before it could be killed; make the file bigger"
    _assert_nothing_partial(out, before)
    leftovers = [p.name for p in tmp_path.iterdir() if p.name != out.name]
    assert all(n.startswith(f".{out.name}.partial-") for n in leftovers), leftovers


def test_the_large_file_imports_when_left_alone(big_csv, tmp_path):
    """The same command, not killed, writes a valid artifact (so the kills above interrupt real work)."""
    out = tmp_path / "m.h5"
    result = subprocess.run(IMPORT + [str(big_csv), "-o", str(out), "--average", "mean-db", "--split", "random:0.2"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert validate_artifact(out) == []
    assert "averaged from 100000 rows" in result.stdout
