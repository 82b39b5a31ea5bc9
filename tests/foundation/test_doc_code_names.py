"""Every piece of code and every configuration key the documentation names exists.

docs/*.md and README.md name source files (`stages/model/band.py`, `scripts/edit_validation.sh`, ...)
and dotted modules with an optional attribute (`rfir_stages.model.occlusion.TracerOcclusion`,
`rfir_core.physics.closed_forms.C0`). A file must exist; a dotted name must resolve to a module or
package, and any remaining part to a name defined in that module's source. Globs (`room*.py`) and
bare file names without a folder are not checked. A dotted configuration key (`rf_fit.physical.sharing`,
`predict.rssi.grid`), in the docs or in scripts/*.sh, must be a key or table of configs/*.toml.
"""
from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# repository folders that hold code, configuration or scripts (generated folders such as results/ excluded)
CODE_DIRS = ("stages", "src", "scripts", "tests", "bench", "configs", "ext", "workflow")
FILE_REF = re.compile(r"(?<![\w./-])((?:%s)/[\w./-]*\w\.(?:py|sh|toml))\b" % "|".join(CODE_DIRS))
PACKAGES = {"rfir_stages": ROOT / "stages", "rfir_cli": ROOT / "src" / "rfir_cli", "rfir_core": ROOT / "src" / "rfir_core",
            "rfir_tracer": ROOT / "ext" / "rfir_tracer"}
DOTTED_REF = re.compile(r"\b((?:%s)(?:\.\w+)+)" % "|".join(PACKAGES))
CONFIG_REF = re.compile(r"(?<![\w./-])((?:rf_fit|predict|geom|simulate|calibrate|reproduce|general)(?:\.[a-z_0-9]+)+)")
FILE_SUFFIXES = {"h5", "toml", "py", "png", "json", "md", "ply", "csv", "pt", "sh"}
def _doc_files() -> list[Path]:
    return sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md"]


def _script_files() -> list[Path]:
    return sorted((ROOT / "scripts").glob("*.sh"))


def _defines(source: str, name: str) -> bool:
    """Whether module source defines `name` (def, class, assignment, import) at any level, or exports it
    by name (a string in `__all__` or a lazy module `__getattr__`)."""
    pattern = (rf"^\s*(?:async\s+def|def|class)\s+{name}\b|^\s*{name}\s*(?::[^=]*)?=|"
               rf"^\s*(?:from\s+\S+\s+)?import\s+[^#\n]*\b{name}\b|^\s*\(?[\w\s,]*\b{name}\b[\w\s,]*\)?\s*=")
    return re.search(pattern, source, re.MULTILINE) is not None or re.search(rf"[\"']{name}[\"']", source) is not None


def resolve_dotted(dotted: str) -> str | None:
    """None when `dotted` names an existing module (and attribute), else the reason it does not."""
    parts = dotted.split(".")
    base = PACKAGES[parts[0]]
    module_file, i = None, 1
    while i < len(parts):
        package = base / Path(*parts[1:i + 1])
        if package.is_dir() and (package / "__init__.py").exists():
            module_file, i = package / "__init__.py", i + 1
            continue
        if package.with_suffix(".py").exists():
            module_file, i = package.with_suffix(".py"), i + 1
        break
    if module_file is None and i == 1:
        module_file = base / "__init__.py"
    rest = parts[i:]
    if not rest:
        return None
    if module_file is None or not module_file.exists():
        return f"no module {'.'.join(parts[:i + 1])}"
    if not _defines(module_file.read_text(encoding="utf-8"), rest[0]):
        return f"{module_file.relative_to(ROOT).as_posix()} defines no {rest[0]!r}"
    return None


def config_key_exists(key: str, config: dict) -> bool:
    node = config
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return False
        node = node[part]
    return True


def _configs() -> dict:
    merged = {}
    for path in sorted((ROOT / "configs").glob("*.toml")):
        merged.update(tomllib.loads(path.read_text(encoding="utf-8")))
    return merged


def _references(pattern: re.Pattern, files: list[Path] | None = None) -> list[tuple[str, int, str]]:
    out = []
    for path in _doc_files() if files is None else files:
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            out += [(path.relative_to(ROOT).as_posix(), n, m) for m in pattern.findall(line)]
    return out


def test_every_code_file_the_docs_name_exists():
    refs = _references(FILE_REF)
    assert len(refs) > 10, "found almost no code paths in the docs: is the pattern right?"
    bad = [f"{doc}:{n}: {ref}" for doc, n, ref in refs if not (ROOT / ref).is_file()]
    assert not bad, "the docs name files that do not exist:\n" + "\n".join(bad)


def test_every_module_and_name_the_docs_cite_exists():
    refs = _references(DOTTED_REF)
    assert len(refs) > 10, "found almost no dotted module names in the docs: is the pattern right?"
    bad = []
    for doc, n, ref in refs:
        reason = resolve_dotted(ref.rstrip("."))
        if reason:
            bad.append(f"{doc}:{n}: {ref} ({reason})")
    assert not bad, "the docs cite modules or names that do not exist:\n" + "\n".join(bad)


def test_every_config_key_the_docs_and_scripts_name_exists():
    config = _configs()
    refs = [(doc, n, ref.rstrip(".")) for doc, n, ref in _references(CONFIG_REF, _doc_files() + _script_files())
            if ref.rstrip(".").rsplit(".", 1)[-1] not in FILE_SUFFIXES]
    assert len(refs) > 10, "found almost no configuration keys in the docs: is the pattern right?"
    bad = [f"{doc}:{n}: {ref}" for doc, n, ref in refs if not config_key_exists(ref, config)]
    assert not bad, "the docs or scripts name configuration keys that configs/*.toml does not have:\n" + "\n".join(bad)


def test_the_checks_catch_a_missing_module_file_name_and_key():
    assert resolve_dotted("rfir_core.physics.materials") is None
    assert resolve_dotted("rfir_stages.model.occlusion.TracerOcclusion") is None
    assert resolve_dotted("rfir_core.physics.closed_forms.C0") is None
    assert resolve_dotted("rfir_stages.rf_fit.fit") is not None or not (ROOT / "stages/rf_fit/fit.py").exists()
    assert resolve_dotted("rfir_stages.predict.invariance") is not None
    assert "defines no" in resolve_dotted("rfir_core.physics.materials.no_such_function")
    assert FILE_REF.findall("see `stages/model/link_set.py` and scripts/edit_validation.sh.") == [
        "stages/model/link_set.py", "scripts/edit_validation.sh"]
    assert FILE_REF.findall("results/reproduce/json/a.json, data/x/stages/y.py, `room*.py`") == []
    config = _configs()
    assert config_key_exists("rf_fit.physical.sharing", config) and config_key_exists("rf_fit.room", config)
    assert not config_key_exists("rf_fit.sharing", config) and not config_key_exists("predict.cull_rel", config)
    assert CONFIG_REF.findall("`--set rf_fit.physical.iterations=200`, geom.h5") == ["rf_fit.physical.iterations", "geom.h5"]
