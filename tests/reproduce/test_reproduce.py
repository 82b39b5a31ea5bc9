"""The reproduce driver: table output and the step runner (cache, times, failures)."""
from __future__ import annotations

import csv
import json
import sys

import pytest

from rfir_cli.errors import StageError
from rfir_stages.reproduce.__main__ import main
from rfir_stages.reproduce.runner import Runner
from rfir_stages.reproduce.tables import Cell, Table, to_markdown, write_table


def _table() -> Table:
    t = Table("demo", ["rfir", "NeRF2-style", "nearest"])
    t.add("row A", {"rfir": Cell(1.5, 90.0), "NeRF2-style": Cell(2.5, 30.0), "nearest": Cell(1.9)})
    t.add("row B", {"rfir": Cell(3.0, 10.0), "NeRF2-style": Cell(note="cannot edit"), "nearest": Cell(2.0)})
    return t


def test_markdown_bolds_the_lowest_and_counts_rows_won():
    md = to_markdown(_table())
    assert "| row A | **1.50** | 2.50 | 1.90 |" in md
    assert "| row B | 3.00 | cannot edit | **2.00** |" in md
    assert "rfir lowest on 1 of 2 rows (not on: row B)." in md
    assert "| row A | 1.5 | 0.50 |  |" in md          # wall times in minutes, empty when unknown


def test_write_table_files(tmp_path):
    md, csv_path, png = write_table(_table(), tmp_path, "demo")
    assert md.read_text().startswith("## demo")
    rows = list(csv.DictReader(csv_path.open()))
    assert len(rows) == 6
    assert rows[4] == {"row": "row B", "method": "NeRF2-style", "mae_db": "", "wall_s": "", "note": "cannot edit"}
    assert png.stat().st_size > 1000 and png.read_bytes()[:4] == b"\x89PNG"


def test_step_runs_once_then_is_cached(tmp_path):
    r = Runner(tmp_path / "data", tmp_path / "out", echo=False)
    target = tmp_path / "made.txt"
    argv = [sys.executable, "-c", f"open({str(target)!r}, 'a').write('x')"]
    wall = r.step("make", argv, target)
    assert target.read_text() == "x" and wall > 0
    assert r.step("make", argv, target) == pytest.approx(wall)      # cached: not run again
    assert target.read_text() == "x"
    times = json.loads((tmp_path / "out" / "times.json").read_text())
    assert times["make"] == pytest.approx(wall)
    again = Runner(tmp_path / "data", tmp_path / "out", echo=False, force=True)
    again.step("make", argv, target)
    assert target.read_text() == "xx"                                # --force reruns


def test_outputs_that_came_without_this_data_folders_stamp_are_rerun(tmp_path):
    """A fresh clone holds results/reproduce/json but no generated data: its steps must run."""
    target = tmp_path / "out" / "json" / "committed.json"
    target.parent.mkdir(parents=True)
    target.write_text("old")
    argv = [sys.executable, "-c", f"open({str(target)!r}, 'w').write('new')"]
    r = Runner(tmp_path / "fresh_data", tmp_path / "out", echo=False)
    r.step("committed", argv, target)
    assert target.read_text() == "new"
    assert (tmp_path / "fresh_data" / "steps" / "committed.done").exists()
    target.write_text("kept")
    r.step("committed", argv, target)                                # stamped now: cached
    assert target.read_text() == "kept"


def test_a_changed_command_line_reruns_the_step(tmp_path):
    """A new option (say a config default spelled out in the command) must not reuse old outputs."""
    r = Runner(tmp_path / "data", tmp_path / "out", echo=False)
    target = tmp_path / "made.txt"
    argv = [sys.executable, "-c", f"open({str(target)!r}, 'a').write('x')", "--old"]
    r.step("make", argv, target)
    r.step("make", argv, target)
    assert target.read_text() == "x"
    r.step("make", argv[:-1] + ["--new"], target)
    assert target.read_text() == "xx"
    (tmp_path / "data" / "steps" / "make.done").write_text("made.txt\n1.0 s\n")   # a stamp without its command
    r.step("make", argv[:-1] + ["--new"], target)
    assert target.read_text() == "xxx"


def test_failed_step_names_its_log(tmp_path):
    r = Runner(tmp_path / "data", tmp_path / "out", echo=False)
    with pytest.raises(StageError, match=r"make\.log.*exit 3"):
        r.step("make", [sys.executable, "-c", "print('boom'); raise SystemExit(3)"], tmp_path / "never")
    assert "boom" in (tmp_path / "out" / "logs" / "make.log").read_text()
    with pytest.raises(StageError, match="did not write"):
        r.step("quiet", [sys.executable, "-c", "pass"], tmp_path / "never")


def test_unknown_target_is_a_clear_error(capsys):
    assert main(["nope"]) == 2
    assert "unknown target 'nope'" in capsys.readouterr().err


def test_two_runners_on_one_folder_keep_each_others_times(tmp_path):
    a = Runner(tmp_path / "data", tmp_path / "out", echo=False)
    b = Runner(tmp_path / "data", tmp_path / "out", echo=False)      # started before a wrote anything
    a.step("from_a", [sys.executable, "-c", f"open({str(tmp_path / 'a')!r}, 'w')"], tmp_path / "a")
    b.step("from_b", [sys.executable, "-c", f"open({str(tmp_path / 'b')!r}, 'w')"], tmp_path / "b")
    times = json.loads((tmp_path / "out" / "times.json").read_text())
    assert set(times) == {"from_a", "from_b"}
