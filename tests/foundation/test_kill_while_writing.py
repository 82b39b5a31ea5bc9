"""A writer killed mid-write leaves no partial file at the target and the earlier artifact intact."""
import os
import signal
import subprocess
import sys
import time

import numpy as np

from rfir_core.artifacts import read_artifact

WRITER = r"""
import sys, numpy as np
from rfir_core.artifacts import write_artifact
links = 3_000_000   # ~ 150 MB: long enough to be killed mid-write
write_artifact(sys.argv[1], "measurements",
               {"tx_pos": np.ones((links, 3)), "rx_pos": np.zeros((links, 3)), "freq_hz": np.array([2.4e9]),
                "path_gain_db": np.full((links, 1), -50.0)}, attrs={"task": "rssi", "scene": "big"})
"""


def test_killed_writer_leaves_earlier_artifact_intact(tmp_path, measurements_file):
    before = measurements_file.read_bytes()
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(measurements_file)])
    deadline = time.time() + 120
    partial = []
    while time.time() < deadline and proc.poll() is None:
        partial = [p for p in tmp_path.iterdir() if p.name.startswith(".m.h5.partial-")]
        if partial and partial[0].stat().st_size > 1_000_000:
            break
        time.sleep(0.01)
    assert partial, "the writer never started writing its temporary file"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL, "writer finished before it could be killed; make it bigger"
    assert measurements_file.read_bytes() == before
    art = read_artifact(measurements_file)
    assert art.attrs["scene"] == "unit" and art["tx_pos"].shape == (5, 3)
    assert np.all(np.isfinite(art["path_gain_db"]))
