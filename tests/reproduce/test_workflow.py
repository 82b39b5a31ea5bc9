"""The Snakemake workflow: a changed setting or input reruns exactly the steps that depend on it; the
real workflow and its cluster profile plan every target (dry runs)."""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SNAKEMAKE = Path(sys.executable).parent / "snakemake"
# make setup installs the workflow extra: a missing snakemake is a failure here, not a skip

# A step that writes "<its command line>" into every file named after --make (stands in for rfir).
MAKE = "import sys; [open(p, 'w').write(' '.join(sys.argv)) for p in sys.argv[sys.argv.index('--make') + 1:]]"

TINY = f'''
from rfir_stages.reproduce.plan import Plan

PLAN = Plan("d", "o")
S = {MAKE!r}
PLAN.step("data", ["python", "-c", S, "simulate", "--make", "d/m.h5", "d/mesh.ply"], "d/m.h5", ["d/mesh.ply"])
PLAN.step("fit", ["python", "-c", S, "rf-fit", "d/m.h5", "--iterations", str(config.get("it", 3)), "--make", "d/f.h5"],
          "d/f.h5")
PLAN.step("pred", ["python", "-c", S, "predict", "d/f.h5", "--make", "o/p.json"], "o/p.json")
PLAN.step("surfels", ["python", "-c", S, "mesh-gaussians", "d/mesh.ply", "--make", "d/s.h5"], "d/s.h5")
PLAN.link_inputs()

include: {str(ROOT / "workflow" / "rules" / "steps.smk")!r}

rule all:
    input: "o/p.json", "d/s.h5"
    default_target: True
'''


def _smk(cwd: Path, *args: str, snakefile: str = "Snakefile") -> str:
    proc = subprocess.run([str(SNAKEMAKE), *args, "-s", snakefile, "--cores", "1", "--rerun-triggers", "mtime",
                           "params", "input", "code"], cwd=cwd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc.stdout + proc.stderr


def _planned(output: str) -> set[str]:
    """Rules of the jobs a dry run would run (the target rule `all` left out)."""
    return set(re.findall(r"^(?:local)?rule ([\w-]+):", output, re.MULTILINE)) - {"all"}


def _tiny_run(folder: Path) -> None:
    (folder / "Snakefile").write_text(TINY)
    assert _planned(_smk(folder, "--config", "it=3")) == {"step_data", "step_fit", "step_pred", "step_surfels"}
    assert "--iterations 3" in (folder / "d" / "f.h5").read_text()
    assert (folder / "o" / "benchmarks" / "fit.tsv").read_text().startswith("s\t")      # the step's wall time


def test_a_changed_setting_reruns_exactly_the_steps_that_depend_on_it(tmp_path):
    _tiny_run(tmp_path)
    out = _smk(tmp_path, "-n", "--config", "it=4")
    assert _planned(out) == {"step_fit", "step_pred"}           # not the data, not the unrelated surfels
    assert "Params have changed" in out


@pytest.mark.slow
def test_nothing_reruns_unchanged_and_a_changed_input_reruns_its_consumers(tmp_path):
    _tiny_run(tmp_path)
    assert _planned(_smk(tmp_path, "-n", "--config", "it=3")) == set()
    (tmp_path / "d" / "mesh.ply").write_text("a new mesh")      # newer than the surfels made from it
    assert _planned(_smk(tmp_path, "-n", "--config", "it=3")) == {"step_surfels"}
    _smk(tmp_path, "--config", "it=4")
    assert "--iterations 4" in (tmp_path / "d" / "f.h5").read_text()


@pytest.fixture
def repo_copy(tmp_path):
    """The real Snakefile in a scratch folder (its .snakemake/ stays out of the repository)."""
    shutil.copytree(ROOT / "workflow", tmp_path / "workflow")
    return tmp_path


@pytest.mark.slow
@pytest.mark.parametrize("quick", ["true", "false"])
def test_the_workflow_plans_every_target(repo_copy, quick):
    out = _smk(repo_copy, "-n", "--config", f"quick={quick}", snakefile="workflow/Snakefile")
    jobs = _planned(out)
    assert {f"table_{t}" for t in ("rcs", "rcs-po", "wideband", "rssi", "extrapolation", "edit", "ablation")} <= jobs
    assert "step_wideband_htarget__rfir_fit" in jobs
    assert ("step_data__classroom_geom" in jobs) == (quick == "false")   # photos -> geom only in the full run


def test_the_slurm_profile_dry_runs(repo_copy):
    out = _smk(repo_copy, "rcs", "-n", "--profile", "workflow/profiles/slurm", "--config", "quick=true",
               snakefile="workflow/Snakefile")
    assert "table_rcs" in _planned(out) and "step_rcs_lego_2p4_data__rfir_fit" in _planned(out)


def test_the_physics_rows_dry_run(repo_copy):
    """`make reproduce-rcs-po`: the physical-optics data of both objects, the physical fits and the
    unseen-frequency prediction, and nothing of the other targets."""
    jobs = _planned(_smk(repo_copy, "rcs-po", "-n", snakefile="workflow/Snakefile"))
    assert {"table_rcs-po", "step_data__lego_po", "step_data__trio_po", "step_rcs_po_trio_2p4_every_30__rfir_fit",
            "step_rcs_po_lego_2p4to5p8_data__rfir_predict", "step_rcs_po_trio_2p4_sector_45_135__wrfgs"} <= jobs
    assert not any(j.startswith(("table_rcs", "step_rcs_lego")) and j != "table_rcs-po" for j in jobs)
