"""Diagnose on simulated data with hidden effects (scripts/diagnose_hidden.sh, quick sizes, Sionna RT
and the physical-optics solver): the right effect is named from the two files alone, the held-out
gap shrinks by at least half; with no hidden effect nothing is named."""
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]

CASES = [  # (model, measurements, effect that must be named; None: nothing)
    ("room_clean", "room_gain", "gain_offset"),
    ("room_clean", "room_noise_floor", "noise_floor"),
    ("room_out_no_transmission", "room_out_clean", "wall_transmission"),
    ("lego_clean", "lego_turntable", "turntable_offset"),
    ("lego_clean", "lego_leakage", "leakage"),
    ("lego_specular_only", "lego_clean", "diffuse_lobe"),
    ("lego_clean", "lego_gain", "gain_offset"),
    ("htarget_clean", "htarget_ripple", "ripple"),
    ("room_clean", "room_other_seed", None),
    ("lego_clean", "lego_other_seed", None),
]


@pytest.fixture(scope="module")
def hidden(tmp_path_factory):
    out = tmp_path_factory.mktemp("hidden")
    rfir = str(Path(sys.executable).with_name("rfir"))
    subprocess.run(["bash", str(ROOT / "scripts" / "diagnose_hidden.sh"), str(out), "quick"], cwd=ROOT, check=True,
                   env={**os.environ, "RFIR": rfir})
    return out


@pytest.mark.parametrize("model, meas, effect", CASES, ids=[f"{c[1]}" for c in CASES])
def test_diagnose_names_the_hidden_effect(hidden, model, meas, effect, tmp_path):
    from rfir_stages.diagnose import run

    geometry = hidden / "room_geometry.h5" if model.startswith("room") else None
    res = run(hidden / model / "measurements.h5", hidden / meas / "measurements.h5", tmp_path / "rep",
              geometry_path=geometry)
    found = [n["effect"] for n in res.named]
    if effect is None:
        assert found == [], json.dumps(res.steps[0]["candidates"], default=str)[:2000]
    else:
        assert found and found[0] == effect, (found, json.dumps(res.steps[0]["candidates"], default=str)[:2000])
        assert res.mae_after_db <= 0.5 * res.mae_before_db
