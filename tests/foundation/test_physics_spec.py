"""docs/physics.md names the code that evaluates each equation, and stays a spec a reader can hold.

- Every dotted name it writes under one of rfir's packages, in prose or beside an equation
  (`rfir_core.physics.materials.fresnel`, `rfir_core.physics.closed_forms.C0`, `rfir_stages.model.room.RoomLinks.power`),
  resolves: the longest prefix that is a module is imported and the rest looked up on it attribute by attribute. A
  rename in the code then fails here until the spec follows.
- It is under 500 lines.
"""
from __future__ import annotations

import importlib
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SPEC = ROOT / "docs" / "physics.md"
MAX_LINES = 500
PACKAGES = ("rfir_stages", "rfir_core", "rfir_cli", "rfir_tracer")
# a dotted name starting with a package, not the tail of a longer name or path
NAME = re.compile(r"(?<![\w./-])((?:%s)(?:\.\w+)+)" % "|".join(PACKAGES))


def spec_names(text: str) -> list[str]:
    """The dotted names under rfir's packages that `text` writes, in order, each once."""
    return list(dict.fromkeys(NAME.findall(text)))


def resolve(dotted: str) -> str | None:
    """None when `dotted` is an importable module, or a module followed by attributes that exist; else why not."""
    parts = dotted.split(".")
    module, i = None, len(parts)
    while i > 0:
        try:
            module = importlib.import_module(".".join(parts[:i]))
            break
        except ModuleNotFoundError as err:
            # only "this prefix is not a module" moves on to a shorter prefix; a missing dependency inside an
            # existing module is a failure of its own
            if err.name is None or not ".".join(parts[:i]).startswith(err.name):
                return f"importing {'.'.join(parts[:i])} failed: {err}"
            i -= 1
        except ImportError as err:   # the module exists but cannot be imported: report it, do not hide it
            return f"importing {'.'.join(parts[:i])} failed: {err}"
    if module is None:
        return f"no module {parts[0]}"
    obj = module
    for j in range(i, len(parts)):
        if not hasattr(obj, parts[j]):
            return f"{'.'.join(parts[:j])} has no attribute {parts[j]!r}"
        obj = getattr(obj, parts[j])
    return None


def test_spec_names_the_code_that_evaluates_its_equations():
    names = spec_names(SPEC.read_text(encoding="utf-8"))
    assert len(names) > 40, f"docs/physics.md names only {len(names)} functions: is the pattern right?"
    bad = [f"{name}: {why}" for name in names if (why := resolve(name))]
    assert not bad, "docs/physics.md names code that does not exist:\n" + "\n".join(bad)


def test_spec_is_under_the_line_limit():
    lines = len(SPEC.read_text(encoding="utf-8").splitlines())
    assert lines < MAX_LINES, f"docs/physics.md has {lines} lines; the spec stays under {MAX_LINES}"


def test_the_check_finds_names_and_catches_missing_ones():
    text = ("(`rfir_core.physics.materials.fresnel`, `rfir_core.physics.closed_forms.C0`; `rfir_stages.model` and "
            "`rfir_stages.model.room.RoomLinks.power`)\n    T = ...    (rfir_core.physics.materials.slab_transmission)\n"
            "not x.rfir_stages.model, stages/rfir_stages.po nor `numpy.sinc`; `rfir_core.physics.materials.fresnel` again")
    assert spec_names(text) == ["rfir_core.physics.materials.fresnel", "rfir_core.physics.closed_forms.C0",
                                "rfir_stages.model", "rfir_stages.model.room.RoomLinks.power",
                                "rfir_core.physics.materials.slab_transmission"]
    assert all(resolve(n) is None for n in spec_names(text))
    assert "has no attribute 'no_such_function'" in resolve("rfir_core.physics.materials.no_such_function")
    assert "has no attribute 'no_such_method'" in resolve("rfir_stages.model.room.RoomLinks.no_such_method")
    assert resolve("rfir_stages.no_such_module.f") is not None
