"""A kill -9 in the middle of `rfir rf-fit` leaves the previous rf.h5 whole (or none) and no temporary
file; the next run (`--resume` reuses a recorded model selection, tests/rf_fit/test_stage.py) finishes."""
import hashlib
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from rfir_core.artifacts import read_artifact
from rfir_stages.geom import gaussians_from_mesh, write_scene_artifact

from .test_stage import BOX, _measurements

SETTINGS = ["rf_fit.occlusion=brute-force", "rf_fit.antenna=isotropic", "rf_fit.physical.start_iterations=5",
            "rf_fit.physical.residual=off"]


def _rfir(args, iterations: int, *extra) -> list[str]:
    sets = [a for s in SETTINGS + [f"rf_fit.physical.iterations={iterations}"] for a in ("--set", s)]
    return [sys.executable, "-m", "rfir_cli.main", *sets, "rf-fit", *args, *extra]


def _digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.slow   # three CLI processes (~1 min on 2 cores)
def test_kill_9_mid_fit_keeps_the_old_artifact_and_the_next_run_finishes(tmp_path):
    v, f = BOX
    labels = (v[f].mean(1)[:, 0] > 0).astype(np.int64)     # two labels: the sharing is chosen by validation
    write_scene_artifact(tmp_path / "scene.h5", gaussians_from_mesh(v, f, 0.03, labels=labels))
    _measurements(tmp_path / "meas.h5", split=np.zeros(18))
    args = [str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"), "-o", str(tmp_path / "rf.h5")]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    done = subprocess.run(_rfir(args, 2), cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr + done.stdout
    old = _digest(tmp_path / "rf.h5")
    (tmp_path / "rf.h5.ckpt.pt.selection").unlink()

    log = tmp_path / "run.log"
    with open(log, "w") as handle:
        proc = subprocess.Popen(_rfir(args, 1_000_000), cwd=tmp_path, env=env, stdout=handle, stderr=handle)
    try:
        deadline = time.time() + 120
        while "physical/" not in log.read_text() and time.time() < deadline and proc.poll() is None:
            time.sleep(0.05)
        assert "physical/" in log.read_text(), log.read_text()   # the material fits have begun
        time.sleep(0.5)
        assert proc.poll() is None
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert _digest(tmp_path / "rf.h5") == old            # the earlier artifact, whole and untouched
    assert read_artifact(tmp_path / "rf.h5", "rf").free["training@attrs"]["iterations"] == 2
    assert not [p.name for p in tmp_path.iterdir() if "partial" in p.name]   # no temporary left behind

    resumed = subprocess.run(_rfir(args, 3, "--resume"), cwd=tmp_path, env=env, capture_output=True,
                             text=True, timeout=120)
    assert resumed.returncode == 0, resumed.stderr + resumed.stdout
    out = " ".join((resumed.stdout + resumed.stderr).split())
    assert "wrote" in out
    assert read_artifact(tmp_path / "rf.h5", "rf").free["training@attrs"]["iterations"] == 3
