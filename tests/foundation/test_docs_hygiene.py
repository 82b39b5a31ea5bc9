"""Docs and results describe the project, not a machine or a work history; the physics spec is cited.

- No file under docs/ or results/ (text: .md .csv .json .txt) holds an absolute machine path or
  work-log wording.
- No .py/.md/.toml file of the project cites the old design note by name: the physics spec is
  docs/physics.md, cited by its numbered sections, and every cited section exists.
"""
from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TEXT_SUFFIXES = {".md", ".csv", ".json", ".txt"}
SOURCE_SUFFIXES = {".py", ".md", ".toml"}
SKIP_DIRS = {".git", ".venv", "__pycache__", "build", "dist", "data", "demo_out", "node_modules"}

# An absolute path into a machine's own folders (not one inside the repository, such as data/tmp/).
MACHINE_PATH = re.compile(r"(?<![\w.~-])/(?:work|tmp|root|home|opt)/")
WORK_LOG = [re.compile(p, re.IGNORECASE) for p in (
    r"\bsessions?\b",
    r"\bsession[- ]?\d",
    r"\bwork[- ]?logs?\b",
    r"\bthis run\b",
)]

OLD_SPEC = "PHYSICS" + ".md"  # spelled in two parts so that this file does not cite it
CITATION = re.compile(r"docs/physics\.md,? sections? (\d+(?:\.\d+)?(?:(?:-|, | and )\d+(?:\.\d+)?)*)")
HEADING = re.compile(r"^#{2,4} (\d+(?:\.\d+)?)\.? ", re.MULTILINE)


def _walk(top: Path, suffixes: set[str]) -> list[Path]:
    out = []
    for dirpath, dirnames, filenames in os.walk(top):
        dirnames[:] = [d for d in dirnames if d not in SKIP_DIRS and not d.startswith(".") and not d.endswith(".egg-info")]
        out += [Path(dirpath) / f for f in filenames if Path(f).suffix in suffixes]
    return out


def _project_files(suffixes: set[str]) -> list[Path]:
    """Tracked files and untracked files git does not ignore; a plain walk where git is missing."""
    try:
        listed = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"], cwd=ROOT,
                                capture_output=True, check=True, timeout=60).stdout.decode().split("\0")
    except (OSError, subprocess.SubprocessError):
        return _walk(ROOT, suffixes)
    files = {ROOT / p for p in listed if p and Path(p).suffix in suffixes}
    return sorted(p for p in files if p.is_file() and not set(p.relative_to(ROOT).parts) & {".venv", ".git"})


def _docs_and_results() -> list[Path]:
    return sorted(p for top in ("docs", "results") for p in _walk(ROOT / top, TEXT_SUFFIXES))


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def _offending_lines(path: Path, patterns) -> list[str]:
    text = path.read_text(encoding="utf-8", errors="replace")
    return [f"{_rel(path)}:{n}: {line.strip()[:160]}" for n, line in enumerate(text.splitlines(), 1)
            if any(p.search(line) for p in patterns)]


def test_docs_and_results_hold_no_absolute_machine_paths():
    files = _docs_and_results()
    assert files, "found no docs or results"
    bad = [hit for f in files for hit in _offending_lines(f, [MACHINE_PATH])]
    assert not bad, "absolute machine paths (write paths relative to the repository or a data folder):\n" + "\n".join(bad)


def test_docs_and_results_hold_no_work_log_wording():
    bad = [hit for f in _docs_and_results() for hit in _offending_lines(f, WORK_LOG)]
    assert not bad, "work-log wording (describe the current state, not who ran what when):\n" + "\n".join(bad)


def test_patterns_catch_what_they_are_for():
    root = "/"   # the examples are assembled so that this file holds no machine path itself
    assert MACHINE_PATH.search(f'"rf": "{root}work/data/rf.h5"') and MACHINE_PATH.search(f"see {root}tmp/x and")
    assert MACHINE_PATH.search(f"({root}root/.cache)") and MACHINE_PATH.search(f"`{root}home/u/d`")
    assert not MACHINE_PATH.search("data/tmp/x.h5") and not MACHINE_PATH.search("results/reproduce/json/a.json")
    assert any(p.search("re-run in " + "Sess" + "ion 7") for p in WORK_LOG)
    assert any(p.search("the session-4 run") for p in WORK_LOG)
    assert any(p.search("as the work-log says") for p in WORK_LOG)
    assert not any(p.search("a successful fit, possession of data") for p in WORK_LOG)


def test_no_file_cites_the_old_design_note():
    bad = []
    for path in _project_files(SOURCE_SUFFIXES):
        bad += [hit for hit in _offending_lines(path, [re.compile(re.escape(OLD_SPEC))])]
    assert not bad, f"cite docs/physics.md sections instead of {OLD_SPEC}:\n" + "\n".join(bad)


def test_physics_spec_has_numbered_sections_and_citations_point_to_them():
    text = (ROOT / "docs" / "physics.md").read_text()
    sections = set(HEADING.findall(text))
    for required in ("1", "2", "3", "4", "5", "6", "7", "8", "9"):
        assert required in sections, f"docs/physics.md lacks section {required}"
    assert re.search(r"^## 8\. Physical materials$", text, re.MULTILINE)
    bad = []
    for path in _project_files(SOURCE_SUFFIXES):
        for n, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            for group in CITATION.findall(line):
                missing = [s for s in re.findall(r"\d+(?:\.\d+)?", group) if s not in sections]
                if missing:
                    bad.append(f"{_rel(path)}:{n}: section {', '.join(missing)} not in docs/physics.md")
    assert not bad, "\n".join(bad)
