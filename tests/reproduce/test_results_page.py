"""docs/results.md is generated from the workflow's tables: regenerated from the committed results, it equals
the committed page; every table's figures, command and machine are on it; its links resolve."""
from __future__ import annotations

import csv
import json
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

from rfir_stages.reproduce.__main__ import main, write_target
from rfir_stages.reproduce.page import PAGE, fullwave_markdown, results_page
from rfir_stages.reproduce.plan import machine_record, reproduce_command
from rfir_stages.reproduce.targets import ABOUT, DIAGNOSE, FULLWAVE, TARGETS, declare

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "results" / "reproduce"


def test_the_results_page_is_what_the_generator_writes_from_the_committed_tables():
    assert (ROOT / PAGE).read_text() == results_page(), (
        "docs/results.md is out of date: python -m rfir_stages.reproduce results-page > docs/results.md")


def _section(page: str, name: str) -> str:
    start = page.index(f'<a id="{name}"></a>')
    end = page.find('<a id="', start + 1)
    return page[start:end if end > 0 else None]


def _mae_cells(section: str) -> dict[tuple[str, str], float]:
    """(row, method) -> MAE of the first table of a section (the MAE table; bold marks stripped)."""
    lines = section.split("| row |", 1)[1].split("\n\n", 1)[0].splitlines()
    methods = [m.strip() for m in lines[0].strip(" |").split("|")]
    cells = {}
    for line in lines[2:]:
        row, *values = [v.strip().strip("*") for v in line.strip().strip("|").split("|")]
        for method, value in zip(methods, values):
            if re.fullmatch(r"-?\d+\.\d+", value):
                cells[(row, method)] = float(value)
    return cells


def test_every_committed_table_is_on_the_page_with_its_figures_command_and_machine():
    page = results_page()
    committed = [n for n in TARGETS if (RESULTS / f"{n}.json").exists()]
    assert len(committed) >= 6, "results/reproduce holds almost no tables"
    for name in committed:
        section = _section(page, name)
        mae = _mae_cells(section)
        with (RESULTS / f"{name}.csv").open() as fh:
            scored = [r for r in csv.DictReader(fh) if r["mae_db"]]
        assert scored, f"{name}.csv has no MAE"
        for r in scored:        # the CSV (4 decimals) and the page (2) are written from the same float
            shown = mae.get((r["row"], r["method"]))
            assert shown is not None and abs(shown - float(r["mae_db"])) <= 0.0051, (
                f"{name}: {r['row']!r} {r['method']}: {r['mae_db']} in the CSV, {shown} on the page")
        prov = json.loads((RESULTS / f"{name}.json").read_text())["provenance"]
        assert f"- Command: `{prov['command']}`" in section
        assert f"{prov['machine']['cores']} cores" in section and prov["machine"]["python"] in section
        assert "Steps of this target" not in section          # per-step times stay in results/reproduce/<name>.md


def test_every_relative_link_on_the_page_resolves():
    page = results_page()
    links = re.findall(r"\]\((?![a-z]+:|#)([^)\s]+)\)", page)
    assert len(links) > 20
    missing = [link for link in links if not (ROOT / PAGE).parent.joinpath(link).resolve().exists()]
    assert not missing, f"links on docs/results.md that resolve to nothing: {missing}"
    anchors = set(re.findall(r'<a id="([\w-]+)"></a>', page))
    assert set(re.findall(r"\]\(#([\w-]+)\)", page)) <= anchors


def test_a_target_without_results_is_listed_with_its_command(tmp_path):
    page = results_page(tmp_path / "empty", Path("docs/results.md"), root=tmp_path)
    for name in TARGETS:
        assert f"## {name}\n\n{ABOUT[name]}\n\nNot run yet: `make reproduce-{name}` writes it." in page
    assert set(ABOUT) == {*TARGETS, DIAGNOSE, FULLWAVE}


def test_the_command_names_the_settings_that_made_the_table():
    assert reproduce_command("rcs", False) == "make reproduce-rcs"
    assert reproduce_command("rcs", True) == "make reproduce-quick"
    sets = ["reproduce.full.po_ranges_m=[3.0]", "reproduce.full.baseline_minutes=1.0"]
    words = shlex.split(reproduce_command("rcs-po", False, sets))
    assert words[:4] == [".venv/bin/snakemake", "-s", "workflow/Snakefile", "rcs-po"] and words[4] == "--config"
    assert json.loads(words[5].removeprefix("set=")) == sets         # what Snakemake's --config parses back
    words = shlex.split(reproduce_command("rcs", True, [], out=Path("o")))
    assert words[-2:] == ["quick=true", "out=o"]


def test_a_written_table_records_its_command_and_machine(tmp_path):
    """The ablation table from hand-written step results (as tests/reproduce/test_reproduce.py) carries its
    provenance, and the page shows it."""
    sets = ["reproduce.quick.iterations=20"]
    plan, _ = declare(["ablation"], True, tmp_path / "d", tmp_path / "o", sets)
    for label in ("rcs_po_lego_2.4_sector_45_135", "ablation_lego_sector_45_135_no_residual",
                  "ablation_lego_sector_45_135_single_bounce"):
        j = plan.json_path(f"{label}__rfir")
        j.parent.mkdir(parents=True, exist_ok=True)
        j.write_text(json.dumps({"metrics": {"mae_db": 1.25}}))
    write_target("ablation", True, tmp_path / "d", tmp_path / "o", sets)
    prov = json.loads((tmp_path / "o" / "ablation.json").read_text())["provenance"]
    assert prov["machine"] == machine_record() and re.fullmatch(r"\d{4}-\d\d-\d\d", prov["date"])
    assert "reproduce.quick.iterations=20" in prov["command"] and f"out={tmp_path / 'o'}" in prov["command"]
    page = results_page(tmp_path / "o", Path("page.md"), root=tmp_path)
    assert f"- Command: `{prov['command']}`" in page and "| **1.25** |" in _section(page, "ablation")


def test_the_cli_prints_and_writes_the_page(tmp_path, capsys):
    assert main(["results-page"]) == 0
    assert capsys.readouterr().out == results_page()
    assert main(["results-page", "--out", str(tmp_path / "none"), "--page", str(tmp_path / "p.md"), "--write"]) == 0
    assert "Not run yet" in (tmp_path / "p.md").read_text()


def test_the_full_wave_table_shows_the_gap_by_region():
    case = {"kind": "plate", "size_m": 0.3, "polarization": "V",
            "timings": {"dofs": 10, "assembly_s": 1.0, "aspects": 2, "solve_s": 2.0, "po_s": 0.1},
            "regions": {"specular": {"aspects": 4, "median_abs_db": 0.125, "p90_abs_db": 0.5, "mean_db": -0.25},
                        "empty": {"aspects": 0}},
            "broadside": {"closed_form_dbsm": 8.14, "bem_dbsm": 8.12, "po_dbsm": 8.14}}
    md = fullwave_markdown({"cases": [case]})
    assert "| plate 0.3 m, V | specular | 4 | 0.12 | 0.50 | -0.25 |" in md
    assert "| plate 0.3 m, V | empty | 0 | | | |" in md
    assert "| plate 0.3 m | broadside | 8.14 | 8.12 | 8.14 |" in md


def test_the_workflow_writes_the_page_beside_other_tables(tmp_path):
    """The real Snakefile's results_page rule (which every target rule runs after its tables) writes the
    page of a non-default folder into that folder, not over docs/results.md."""
    shutil.copytree(ROOT / "workflow", tmp_path / "workflow")
    out = tmp_path / "o"
    out.mkdir()
    shutil.copy(RESULTS / "wideband.json", out)
    shutil.copy(RESULTS / "wideband.md", out)
    proc = subprocess.run([str(Path(sys.executable).parent / "snakemake"), "-s", "workflow/Snakefile", "--cores", "1",
                           "results_page", "--config", "quick=true", f"out={out}"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert not (tmp_path / "docs").exists()
    page = (out / "results.md").read_text()
    assert page == results_page(out, out / "results.md", root=tmp_path)
    first_row = next(line for line in (out / "wideband.md").read_text().splitlines() if line.startswith("| h-target"))
    assert first_row in page and "Not run yet" in page
