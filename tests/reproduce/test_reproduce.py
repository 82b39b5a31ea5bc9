"""The reproduce targets as data: tables, the plan of steps (inputs, code versions), the table CLI."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from rfir_core.errors import ConfigError, StageError
from rfir_stages.reproduce.__main__ import main, write_target
from rfir_stages.reproduce.plan import Plan, code_version, read_benchmark, rule_name
from rfir_stages.reproduce.tables import Cell, Table, to_markdown, write_table
from rfir_stages.reproduce.targets import TARGETS, declare


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


def test_deferred_cells_and_labels_are_read_when_resolved():
    seen = []
    t = Table("demo", ["rfir"])
    t.add(lambda: "late label", {"rfir": lambda: seen.append(1) or Cell(0.5)})
    assert seen == []                                                # declaring reads nothing
    r = t.resolved()
    assert r.rows == [("late label", {"rfir": Cell(0.5)})] and seen == [1]


def test_plan_links_inputs_through_files_folders_and_shell_substitutions(tmp_path):
    p = Plan(tmp_path / "d", tmp_path / "o")
    p.step("make", ["rfir", "simulate", "lego", "d/lego"], "d/lego/m.h5", ["d/lego/images/"])
    p.step("use", ["rfir", "calibrate", "d/lego/images/cam0.png", "--x", "$(python -m tool d/lego/m.h5 8)"],
           "d/c.h5")
    p.step("alone", ["rfir", "geom", "elsewhere.h5"], "d/g.h5")
    p.link_inputs()
    assert p.steps["use"].inputs == ["d/lego/images/", "d/lego/m.h5"]
    assert p.steps["alone"].inputs == [] and p.steps["make"].inputs == []
    assert p.steps["use"].command.endswith('--x "$(python -m tool d/lego/m.h5 8)"')


def test_a_step_declared_twice_must_keep_its_command(tmp_path):
    p = Plan(tmp_path / "d", tmp_path / "o")
    p.step("a", ["rfir", "geom", "x"], "y")
    p.step("a", ["rfir", "geom", "x"], "y")                          # shared by two targets: fine
    with pytest.raises(StageError, match="declared twice"):
        p.step("a", ["rfir", "geom", "z"], "y")


def test_code_version_follows_the_content_of_the_commands_sources(tmp_path):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "a.py").write_text("x = 1\n")
    (tmp_path / "pkg" / "notes.txt").write_text("ignored")
    v1 = code_version(("pkg",), tmp_path)
    (tmp_path / "pkg" / "notes.txt").write_text("changed, not source")
    assert code_version(("pkg",), tmp_path) == v1
    (tmp_path / "pkg" / "a.py").write_text("x = 2\n")
    assert code_version(("pkg",), tmp_path) != v1


@pytest.mark.parametrize("quick", [True, False])
def test_every_target_declares_steps_with_known_code_and_unique_rules(quick):
    plan, tables = declare(list(TARGETS), quick)
    assert set(tables) == set(TARGETS)
    names = [rule_name(label) for label in plan.steps]
    assert len(set(names)) == len(names)
    owners = {o for s in plan.steps.values() for o in s.outputs}
    for step in plan.steps.values():
        assert step.code_files                                        # raises for a command CODE lacks
        assert set(step.inputs) <= owners
        assert not any(a.startswith("/") for a in step.argv), step.command   # no machine path in a rule
    fit = plan.steps["rcs_lego_2.4_data__rfir_fit"]
    assert fit.inputs == ["data/reproduce%s/lego/scene.h5" % ("-quick" if quick else ""),
                          "data/reproduce%s/lego/measurements.h5" % ("-quick" if quick else "")]
    assert f"rf_fit.physical.iterations={30 if quick else 200}" in fit.command   # configs/reproduce.toml
    assert "--iterations" not in fit.command and "rf_fit.model" not in fit.command   # one model


def test_sizes_come_from_the_config_and_overrides_are_checked():
    plan, _ = declare(["rcs"], True, overrides=["reproduce.quick.baseline_minutes=0.5"])
    assert "--minutes 0.5" in plan.steps["rcs_lego_2.4_data__nerf2"].command
    with pytest.raises(ConfigError, match="unknown config key"):
        declare(["rcs"], True, overrides=["reproduce.quick.nope=1"])
    with pytest.raises(ConfigError, match="only reproduce"):
        declare(["rcs"], True, overrides=["rf_fit.iterations=3"])
    with pytest.raises(ConfigError, match="unknown reproduce target 'nope'"):
        declare(["nope"], True)


def test_benchmark_files_are_read_and_missing_ones_are_none(tmp_path):
    b = tmp_path / "x.tsv"
    b.write_text("s\th:m:s\tmax_rss\n12.5\t0:00:12\t100.0\n")
    assert read_benchmark(b) == 12.5
    assert read_benchmark(tmp_path / "missing.tsv") is None


def test_table_cli_fills_a_target_from_results_and_benchmarks(tmp_path):
    """The ablation table from hand-written results: MAEs from the JSON, times from benchmark files."""
    plan, tables = declare(["ablation"], True, tmp_path / "d", tmp_path / "o")
    for i, label in enumerate(["rcs_po_lego_2.4_sector_45_135", "ablation_lego_sector_45_135_no_residual",
                               "ablation_lego_sector_45_135_single_bounce"]):
        j = plan.json_path(f"{label}__rfir")
        j.parent.mkdir(parents=True, exist_ok=True)
        j.write_text(json.dumps({"metrics": {"mae_db": 1.0 + i}}))
        for step in (f"{label}__rfir_fit", f"{label}__rfir_predict"):
            b = plan.benchmark_path(step)
            b.parent.mkdir(parents=True, exist_ok=True)
            b.write_text(f"s\th:m:s\n{30 * (i + 1)}\t0:00:30\n")
    paths = write_target("ablation", True, tmp_path / "d", tmp_path / "o")
    md = paths[0].read_text()
    row = "| lego 2.4 GHz RCS (physical optics), sector:45:135 |"
    assert row + " **1.00** | 2.00 | 3.00 | one object class (bricks): one material already |" in md
    assert row + " 1.0 | 2.0 | 3.0 |  |" in md      # fit + predict, minutes
    summary = json.loads((tmp_path / "o" / "ablation.json").read_text())
    assert summary["step_s"]["ablation_lego_sector_45_135_single_bounce__rfir_fit"] == 90.0
    assert summary["step_s"]["data__lego"] is None and summary["step_s_total"] == 360.0


def test_table_cli_names_a_missing_result(tmp_path, capsys):
    assert main(["table", "ablation", "--quick", "--data", str(tmp_path / "d"), "--out", str(tmp_path / "o")]) == 5
    err = capsys.readouterr().err
    assert "rcs_po_lego_2.4_sector_45_135__rfir.json" in err and "cannot read the step result" in err
    assert not (tmp_path / "o" / "ablation.md").exists()


def test_the_po_target_declares_the_physics_rows():
    """rcs-po: lego, trio and car on physical-optics data, the physical model on four protocols at 2.4 GHz and
    the even/odd fit predicted at 5.8 GHz; the quick variant adds one row on the rcs target's data."""
    plan, tables = declare(["rcs-po"], False, overrides=["reproduce.full.po_ranges_m=[3.0]"])
    table, labels = tables["rcs-po"]
    rows = [label for label, _ in table.rows]
    assert len(rows) == 15 and "trio 2.4 GHz, sector 45-135 deg held out" in rows
    assert "lego, fit 2.4 GHz, predict 5.8 GHz (odd aspects)" in rows
    assert rows[10:] == ["car 2.4 GHz, even/odd aspects", "car 2.4 GHz, every 10th aspect trains",
                         "car 2.4 GHz, every 30th aspect trains", "car 2.4 GHz, sector 45-135 deg held out",
                         "car, fit 2.4 GHz, predict 5.8 GHz (odd aspects)"]
    car = plan.steps["data__car_po"]                                        # the metal body, PO like the others
    assert "simulate car" in car.command and "--rcs-backend po" in car.command
    assert plan.steps["data__car_po_surfels"].inputs[0] == "data/reproduce/car_po/meshes/car_gt.ply"
    data = plan.steps["data__trio_po"]
    assert "--rcs-backend po" in data.command and "simulate.rcs.freqs_hz=[2.4e9,5.8e9]" in data.command
    assert "simulate.rcs.ranges_m=[3]" in data.command                       # configs/reproduce.toml, overridden
    fits = [plan.steps[lbl] for lbl in labels if lbl.endswith("__rfir_fit")]
    assert len(fits) == 12
    for fit in fits:
        assert "--set rf_fit.physical.iterations=200" in fit.command and "--freq-hz 2.4e+09" in fit.command
        assert "--iterations" not in fit.command       # the physical model's steps (rf_fit.physical)
    unseen = plan.steps["rcs_po_trio_2.4to5.8_data__rfir_predict"]
    assert unseen.inputs == ["data/reproduce/fits/rcs_po_trio_2.4_data.h5", "data/reproduce/trio_po/measurements.h5"]
    assert "--freqs 5.8e+09" in unseen.command
    assert any("physical optics" in n for n in table.notes) and any("the physical model" in n for n in table.notes)
    quick, qtables = declare(["rcs", "rcs-po"], True)
    qlabels = qtables["rcs-po"][1]
    assert [label for label, _ in qtables["rcs-po"][0].rows] == ["lego 2.4 GHz, sector 45-135 deg held out"]
    assert "data__lego" in qlabels and "data__lego" in qtables["rcs"][1]    # the rcs target's data, no new run
    assert len([lbl for lbl in qlabels if not lbl.startswith("data__")]) == 2
    # the full-wave check of the PO backend is a step of the full variant only (the `fullwave` rule)
    assert plan.steps["fullwave_po"].outputs == ["results/reproduce/fullwave/fullwave_vs_po.json",
                                                 "results/reproduce/fullwave/fullwave_vs_po.png"]
    assert "fullwave_po" not in quick.steps
    assert not any(lbl.endswith("range_3__rfir_fit") for lbl in labels)        # one range: no unseen-range rows
    assert any("no unseen-range rows" in n for n in table.notes)
    assert not any("held out" in n or "unseen-range" in n for n in qtables["rcs-po"][0].notes)


def test_the_po_target_holds_out_an_interior_range():
    """At the data's six ranges (configs/reproduce.toml) each object gets the row range:3: fit on the other
    five ranges at 2.4 GHz, predicted at 3 m, the fields trained on the same split."""
    plan, tables = declare(["rcs-po"], False)
    table, labels = tables["rcs-po"]
    rows = [label for label, _ in table.rows]
    assert len(rows) == 18 and rows.index("trio 2.4 GHz, 3 m held out") == rows.index("trio 2.4 GHz, sector 45-135 "
                                                                                     "deg held out") + 1
    for obj in ("lego", "trio", "car"):
        fit = plan.steps[f"rcs_po_{obj}_2.4_range_3__rfir_fit"]
        assert "--split range:3 --freq-hz 2.4e+09" in fit.command
        assert f"data/reproduce/{obj}_po/measurements.h5" in fit.command
        assert "simulate.rcs.ranges_m=[2,2.5,3,4,4.5,5]" in plan.steps[f"data__{obj}_po"].command
        for field in ("nerf2", "wrfgs"):
            assert "--protocol range:3" in plan.steps[f"rcs_po_{obj}_2.4_range_3__{field}"].command
    assert any(n.startswith("3 m held out: the other ranges (2, 2.5, 4, 4.5, 5 m) train") for n in table.notes)


def test_the_po_table_marks_what_cannot_predict_an_unfitted_frequency(tmp_path):
    plan, tables = declare(["rcs-po"], False, tmp_path / "d", tmp_path / "o")
    for step in plan.steps.values():
        if step.outputs[0].endswith(".json"):
            j = Path(step.outputs[0])
            j.parent.mkdir(parents=True, exist_ok=True)
            metrics = {"mae_db": 2.0, "baseline_nearest_mae_db": 3.0, "baseline_linear_mae_db": 1.5}
            if "range_3" in j.name:     # predict's JSON on a range split: only the range baselines
                metrics = {"mae_db": 2.0, "baseline_nearest_range_mae_db": 2.5, "baseline_linear_range_mae_db": 1.0}
            j.write_text(json.dumps({"metrics": metrics}))
    md = to_markdown(tables["rcs-po"][0].resolved())
    row = next(line for line in md.splitlines() if line.startswith("| trio, fit 2.4 GHz, predict 5.8 GHz"))
    cells = [c.strip() for c in row.split("|")[2:-1]]
    assert cells[0] == "**2.00**"                                       # the only prediction of the row
    assert cells[1] == cells[2] == "not run: predicts only the frequency it was trained on"
    assert cells[3].startswith("not run") and "(3.00 with the 5.8 GHz training rows" in cells[3]
    assert "| trio 2.4 GHz, even/odd aspects | 2.00 | 2.00 | 2.00 | 3.00 | **1.50** |" in md
    assert "| trio 2.4 GHz, 3 m held out | 2.00 | 2.00 | 2.00 | 2.50 | **1.00** |" in md
    assert "rfir lowest on 3 of 18 rows" in md


def test_code_paths_exist_and_simulators_do_not_follow_the_fitted_model():
    """Every source path a step's code version hashes exists (a missing one would be skipped silently,
    and its changes would never rerun the step), and the simulators' steps hash the material laws they
    use, not the fitted model: a change of the model reruns the fits, not the data."""
    from rfir_stages.reproduce.plan import CODE, ROOT

    for command, paths in CODE.items():
        for rel in paths:
            assert (ROOT / rel).exists(), f"{command}: {rel} does not exist"

    def covers(paths, rel):
        return any(rel == p or rel.startswith(p.rstrip("/") + "/") for p in paths)

    for command in ("simulate", "scripts/fullwave_compare.py"):
        assert covers(CODE[command], "src/rfir_core/physics/materials.py")
        assert not covers(CODE[command], "stages/model/physical.py")
        assert not covers(CODE[command], "stages/model/room.py")
    for command in ("rf-fit", "predict", "scripts/edit_validate.py"):
        assert covers(CODE[command], "stages/model/physical.py")


def test_simulators_import_only_the_material_laws_of_the_model_package():
    """The premise of the simulators' code paths above, checked on their source."""
    import re

    from rfir_stages.reproduce.plan import ROOT

    # the split protocols are the one other module of the package they use; plan.CODE hashes it for simulate
    allowed = ("rfir_core.physics.materials", "rfir_stages.model import materials", "rfir_stages.model.split_protocols")
    for folder in ("stages/simulate", "stages/po", "stages/fullwave"):
        for f in (ROOT / folder).rglob("*.py"):
            for m in re.finditer(r"^\s*(?:from|import)\s+(rfir_stages\.model[\w.]*(?: import \w+)?)", f.read_text(), re.M):
                name = m.group(1)
                ok = name.startswith(allowed) and not name.startswith("rfir_stages.model.materials_")
                assert ok, f"{f.relative_to(ROOT)} imports {name}"
