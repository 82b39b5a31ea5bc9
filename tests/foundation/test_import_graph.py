"""The import graph of rfir_cli and rfir_stages, read from the source with `ast`: no new import cycle between files.

Every `import` / `from ... import` of an rfir_cli.* or rfir_stages.* module counts, at module level and inside
functions alike (an import moved into a function to dodge a cycle at import time still ties the two files
together); relative imports are resolved; imports under `if TYPE_CHECKING:` never run and are left out. An edge
goes to the deepest module named (`from rfir_stages.po import solver` -> rfir_stages/po/solver.py), not to the
packages above it. A cycle is a strongly connected component of more than one file.

The test prints the cycles it finds (between files, and between packages: a module standing for the folder it lies
in) and the number of imports made inside functions, and fails when the cycles or what they catch grow beyond
today's (a ratchet: break a cycle, then lower the constants below).
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = {"rfir_core": ROOT / "src" / "rfir_core", "rfir_cli": ROOT / "src" / "rfir_cli", "rfir_stages": ROOT / "stages"}
# The layers, lowest first (docs/architecture.md): a module may import its own layer and those below it, never one
# above. Inside the stage layer the packages may import each other as long as no cycle forms (the tests below).
LAYERS = (
    ("physics", ("rfir_core.physics",)),                        # constants and laws: numpy/torch only
    ("core", ("rfir_core",)),                                    # errors, artifacts, config, progress, provenance
    ("models", ("rfir_stages.model", "rfir_stages.po")),         # the radio models and the PO solver
    ("stages", ("rfir_stages",)),                                # one package per stage
    ("api", ("rfir_stages.api",)),                               # the Python API over the stages
    ("cli", ("rfir_cli",)),                                      # parses and prints
)


def layer_of(module: str) -> int:
    """Index in LAYERS of the most specific layer whose prefix names `module`."""
    best, length = None, -1
    for i, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > length:
                best, length = i, len(prefix)
    assert best is not None, f"{module} is in no layer"
    return best

# Ratchet: the count of import cycles between files (strongly connected components of more than one file) and of
# the files caught in them, and the same between packages (a module counts for the folder it lies in). None today:
# a shared piece lives in the module below both users (rfir_core.physics, rfir_stages.model). Never raise them.
MAX_FILE_CYCLES = 0
MAX_FILES_IN_CYCLES = 0
MAX_PACKAGES_IN_CYCLES = 0


def module_files() -> dict[str, Path]:
    """Dotted module name -> its file, for every .py file of the packages (a package is its __init__.py)."""
    out = {}
    for package, folder in PACKAGES.items():
        for path in sorted(folder.rglob("*.py")):
            parts = path.relative_to(folder).with_suffix("").parts
            if "__pycache__" in parts:
                continue
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join((package, *parts))] = path
    return out


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imports(tree: ast.Module):
    """(node, inside a function) for each import statement that runs (not under `if TYPE_CHECKING:`)."""
    stack = [(node, False) for node in reversed(tree.body)]
    while stack:
        node, in_function = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node, in_function
            continue
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            children = node.orelse
        else:
            children = list(ast.iter_child_nodes(node))
        nested = in_function or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        stack.extend((child, nested) for child in reversed(children))


def _deepest(name: str, modules: dict) -> str | None:
    """The longest prefix of dotted `name` that is one of our modules."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        candidate = ".".join(parts[:i])
        if candidate in modules:
            return candidate
    return None


def _targets(node, module: str, is_package: bool, modules: dict) -> list[str]:
    """Our modules that one import statement of `module` loads."""
    if isinstance(node, ast.Import):
        return [t for t in (_deepest(alias.name, modules) for alias in node.names) if t]
    if node.level:
        package = module.split(".") if is_package else module.split(".")[:-1]
        base_parts = package[: len(package) - (node.level - 1)]
        base = ".".join(base_parts + ([node.module] if node.module else []))
    else:
        base = node.module or ""
    out = []
    for alias in node.names:
        full = f"{base}.{alias.name}"
        target = full if full in modules else _deepest(base, modules)
        if target:
            out.append(target)
    return out


def import_graph() -> tuple[dict[str, set[str]], list[tuple[str, str]]]:
    """(module -> the modules it imports, [(module, target)] for each import made inside a function)."""
    modules = module_files()
    graph: dict[str, set[str]] = {m: set() for m in modules}
    in_functions = []
    for module, path in modules.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        for node, in_function in _imports(tree):
            for target in _targets(node, module, path.name == "__init__.py", modules):
                if target != module:
                    graph[module].add(target)
                    if in_function:
                        in_functions.append((module, target))
    return graph, in_functions


def strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan's algorithm, iterative), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    out = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    out.append(sorted(component))
    return sorted(out, key=lambda c: (-len(c), c))


def package_graph(graph: dict[str, set[str]]) -> dict[str, set[str]]:
    """The import graph between packages: each module stands for the package it lies in (a package for itself)."""
    files = module_files()
    home = {m: m if files[m].name == "__init__.py" else m.rsplit(".", 1)[0] for m in graph}
    out: dict[str, set[str]] = {p: set() for p in home.values()}
    for module, targets in graph.items():
        out[home[module]] |= {home[t] for t in targets if home[t] != home[module]}
    return out


def _short(module: str) -> str:
    return module.replace("rfir_stages.", "stages/").replace("rfir_cli.", "cli/").replace("rfir_core.", "core/")


def test_the_graph_reader_resolves_relative_and_nested_imports(tmp_path, monkeypatch):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from .a import x\n")
    (pkg / "a.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from .b import y\nx = 1\n"
                              "def f():\n    from .sub import c\n")
    (pkg / "b.py").write_text("import pkg.sub.c as c\nfrom . import a\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "c.py").write_text("from ..b import z\nfrom .. import sub\nfrom ...outside import q\n")
    monkeypatch.setitem(globals(), "PACKAGES", {"pkg": pkg})
    graph, in_functions = import_graph()
    assert graph == {"pkg": {"pkg.a"}, "pkg.a": {"pkg.sub.c"}, "pkg.b": {"pkg.sub.c", "pkg.a"},
                     "pkg.sub": set(), "pkg.sub.c": {"pkg.b", "pkg.sub"}}
    assert in_functions == [("pkg.a", "pkg.sub.c")]
    assert strongly_connected(graph) == [["pkg.a", "pkg.b", "pkg.sub.c"]]


def test_no_new_import_cycle_between_files():
    graph, in_functions = import_graph()
    assert len(graph) > 100 and sum(map(len, graph.values())) > 300, "the graph is almost empty: is the reader right?"
    cycles = strongly_connected(graph)
    files = sum(map(len, cycles))
    print(f"\n{len(graph)} files, {sum(map(len, graph.values()))} imports between them, {len(in_functions)} of them "
          f"made inside functions; {len(cycles)} import cycles between files, {files} files in them:")
    for component in cycles:
        inner = sorted((a, b) for a in component for b in graph[a] if b in component)
        print(f"  {len(component)} files: " + ", ".join(map(_short, component)))
        if len(component) <= 6:
            print("    " + "; ".join(f"{_short(a)} -> {_short(b)}" for a, b in inner))
    packages = package_graph(graph)
    package_cycles = strongly_connected(packages)
    in_package_cycles = sum(map(len, package_cycles))
    print(f"{len(package_cycles)} import cycles between packages, {in_package_cycles} packages in them:")
    for component in package_cycles:
        print("  " + "; ".join(f"{_short(a)} -> {', '.join(_short(b) for b in sorted(packages[a]) if b in component)}"
                               for a in component))
    assert in_package_cycles <= MAX_PACKAGES_IN_CYCLES, (
        f"{in_package_cycles} packages in import cycles, more than the {MAX_PACKAGES_IN_CYCLES} of before (see above)")
    assert len(cycles) <= MAX_FILE_CYCLES and files <= MAX_FILES_IN_CYCLES, (
        f"{len(cycles)} import cycles over {files} files, more than the {MAX_FILE_CYCLES} cycles over "
        f"{MAX_FILES_IN_CYCLES} files of before: move the shared piece into the module both import, rather than "
        "importing each other (see the cycles printed above)")


def test_layers_import_only_downwards():
    """The physics layer imports nothing of rfir; the core imports neither the stages nor the CLI; the radio models
    import only the core; no stage imports the Python API or the CLI (the CLI only parses and prints)."""
    graph, _ = import_graph()
    upward = sorted((a, b) for a, targets in graph.items() for b in targets if layer_of(b) > layer_of(a))
    assert not upward, "imports of a layer above: " + "; ".join(f"{_short(a)} -> {_short(b)}" for a, b in upward)


def test_the_layer_check_can_fail(monkeypatch):
    fake = {"rfir_core.x": {"rfir_cli.y"}, "rfir_cli.y": set(), "rfir_core.physics.z": {"rfir_core.x"},
            "rfir_stages.model.m": {"rfir_stages.rf_fit.s"}, "rfir_stages.rf_fit.s": {"rfir_stages.model.m"}}
    monkeypatch.setitem(globals(), "import_graph", lambda: (fake, []))
    try:
        test_layers_import_only_downwards()
    except AssertionError as error:
        for pair in ("core/x -> cli/y", "core/physics.z -> core/x", "stages/model.m -> stages/rf_fit.s"):
            assert pair in str(error), pair
        assert "stages/rf_fit.s -> stages/model.m" not in str(error)
    else:
        raise AssertionError("an upward import was not caught")
