"""A kill -9 in the middle of `rfir rf-fit` leaves the previous rf.h5 whole (or none) and a checkpoint
that `--resume` continues from."""
import hashlib
import os
import signal
import subprocess
import sys
import time

import pytest
import torch

from rfir_cli.artifacts import read_artifact
from rfir_stages.geom import write_scene_artifact

from .helpers import box_fields
from .test_stage import _measurements

SETTINGS = ["rf_fit.occlusion=brute-force", "rf_fit.grid_step_deg=10.0", "rf_fit.model=free",
            "rf_fit.scattering=coherent", "rf_fit.sharing=gaussian", "rf_fit.checkpoint_every=2"]


def _rfir(args, iterations: int, *extra) -> list[str]:
    sets = [a for s in SETTINGS + [f"rf_fit.iterations={iterations}"] for a in ("--set", s)]
    return [sys.executable, "-m", "rfir_cli.main", *sets, "rf-fit", *args, *extra]


def _digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.slow   # three CLI processes (~1 min on 2 cores)
def test_kill_9_mid_fit_keeps_the_old_artifact_and_resume_finishes(tmp_path):
    fields = box_fields(0.05, 0.05)
    write_scene_artifact(tmp_path / "scene.h5", fields)
    _measurements(tmp_path / "meas.h5", fields)
    args = [str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"), "-o", str(tmp_path / "rf.h5")]
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    done = subprocess.run(_rfir(args, 2), cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr + done.stdout
    old = _digest(tmp_path / "rf.h5")
    ckpt = tmp_path / "rf.h5.ckpt.pt"
    ckpt.unlink()

    proc = subprocess.Popen(_rfir(args, 1_000_000), cwd=tmp_path, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 120
        while not ckpt.exists() and time.time() < deadline and proc.poll() is None:
            time.sleep(0.05)
        assert ckpt.exists(), "no checkpoint was written"
        time.sleep(0.3)                                  # a few more steps: the kill lands mid-fit
        assert proc.poll() is None
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert _digest(tmp_path / "rf.h5") == old            # the earlier artifact, whole and untouched
    assert read_artifact(tmp_path / "rf.h5", "rf").free["training@attrs"]["iterations"] == 2
    assert not [p.name for p in tmp_path.iterdir() if "partial" in p.name]   # no temporary left behind

    at = int(torch.load(ckpt, weights_only=True)["iteration"])
    assert at >= 2 and at % 2 == 0
    resumed = subprocess.run(_rfir(args, at + 3, "--resume"), cwd=tmp_path, env=env, capture_output=True,
                             text=True, timeout=120)
    assert resumed.returncode == 0, resumed.stderr + resumed.stdout
    assert f"at iteration {at}" in " ".join((resumed.stdout + resumed.stderr).split())
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    attrs = rf.free["training@attrs"]
    assert attrs["resumed_at"] == at and len(rf.free["training"]["loss_curve"]) == at + 3
