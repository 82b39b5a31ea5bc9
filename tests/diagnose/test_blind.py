"""The blind set end to end, reduced (--quick: 4 cases): simulated once, cases made, diagnosed without
the answers, scored; every case right and the negative clean."""
import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _cli():
    """scripts/diagnose_blind.py, the blind set's command line, loaded by path."""
    spec = importlib.util.spec_from_file_location("diagnose_blind_cli", ROOT / "scripts" / "diagnose_blind.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
def test_blind_quick_set(tmp_path):
    assert _cli().main(["run", str(tmp_path / "data"), str(tmp_path / "out"), "--quick"]) == 0
    res = json.loads((tmp_path / "out" / "diagnose_blind.json").read_text())
    assert res["summary"]["cases"] == 4
    assert res["summary"]["right"] == 4, [(r["key"], r["named"], r["headline"]) for r in res["cases"]]
    assert res["summary"]["false_positives_on_negatives"] == 0 and res["summary"]["gap_shrinks_for_every_named"]
    assert res["summary"]["max_seconds"] < 30
    answers = json.loads((tmp_path / "data" / "answers.json").read_text())
    case_files = {p.name for p in (tmp_path / "data" / "cases" / "case_01").iterdir()}
    assert case_files == {"model.h5", "measurements.h5"} and len(answers) == 4   # answers kept apart


def test_scoring_reads_the_answers_only_to_score():
    from rfir_stages.diagnose.blind import score

    answers = {"case_01": {"key": "a", "scene": "room", "effects": ["gain_offset"], "axis": None, "what": ""},
               "case_02": {"key": "b", "scene": "lego", "effects": [], "axis": "aspect", "what": ""},
               "case_03": {"key": "c", "scene": "room", "effects": [], "axis": None, "what": ""}}
    said = {"case_01": {"named": ["gain_offset"], "headline": "named gain_offset", "lacking": [],
                        "steps": [("gain_offset", 3.0, 0.4)], "mae_before_db": 3.0, "mae_after_db": 0.4, "seconds": 1},
            "case_02": {"named": [], "headline": "structure the model lacks, not in the catalogue: by range",
                        "lacking": ["range"], "steps": [], "mae_before_db": 1, "mae_after_db": 1, "seconds": 1},
            "case_03": {"named": ["noise_floor"], "headline": "named noise_floor", "lacking": [],
                        "steps": [("noise_floor", 0.5, 0.6)], "mae_before_db": 0.5, "mae_after_db": 0.6, "seconds": 1}}
    rows = {r["case"]: r for r in score(said, answers)}
    assert rows["case_01"]["right"] and rows["case_01"]["gap_shrinks"]
    assert not rows["case_02"]["right"]          # the wrong axis
    assert not rows["case_03"]["right"] and not rows["case_03"]["gap_shrinks"]
