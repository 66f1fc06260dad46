"""The project's structural rules, checked on the source: no function over 150 lines, no private name
imported across modules, no import cycle between the library's modules (docs/design.md, *Layout*)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "lftomo"
MAX_FUNCTION_LINES = 150


def _sources(*folders: str) -> list[Path]:
    return sorted(p for d in folders for p in (ROOT / d).rglob("*.py"))


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported_module(node: ast.ImportFrom, path: Path) -> str:
    """The absolute module name an ``ImportFrom`` in ``path`` names."""
    if not node.level:
        return node.module or ""
    package = _module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    base = package[: len(package) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def test_no_function_is_longer_than_150_lines():
    long = [f"{p.relative_to(ROOT)}:{n.lineno} {n.name} ({n.end_lineno - n.lineno + 1} lines)"
            for p in _sources("lftomo", "benchmarks", "studies") for n in ast.walk(ast.parse(p.read_text()))
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))
            and n.end_lineno - n.lineno + 1 > MAX_FUNCTION_LINES]
    assert not long, "functions over 150 lines: " + "; ".join(long)


def test_no_private_name_is_imported_from_another_module():
    found = []
    for p in _sources("lftomo", "benchmarks", "studies"):
        for n in ast.walk(ast.parse(p.read_text())):
            if isinstance(n, ast.ImportFrom) and _imported_module(n, p).split(".")[0] == "lftomo":
                found += [f"{p.relative_to(ROOT)}:{n.lineno} {a.name} from {_imported_module(n, p)}"
                          for a in n.names if a.name.startswith("_") and not a.name.startswith("__")]
    assert not found, "private names imported across modules: " + "; ".join(found)


def _module_level_imports() -> dict[str, set[str]]:
    """Each library module → the library modules it imports at module level (package ``__init__`` files,
    which re-export, left out as importers and as targets)."""
    paths = {_module_name(p): p for p in _sources("lftomo")}
    graph = {}
    for name, p in paths.items():
        if p.name == "__init__.py":
            continue
        deps = set()
        for n in ast.parse(p.read_text()).body:
            if isinstance(n, ast.ImportFrom):
                mod = _imported_module(n, p)
                deps |= {m for m in [mod] + [f"{mod}.{a.name}" for a in n.names] if m in paths}
            elif isinstance(n, ast.Import):
                deps |= {a.name for a in n.names if a.name in paths}
        graph[name] = {d for d in deps if d != name and paths[d].name != "__init__.py"}
    return graph


def test_library_modules_import_each_other_without_a_cycle():
    graph = _module_level_imports()
    assert len(graph) > 50  # the walk found the library
    state: dict[str, int] = {}
    cycles: list[list[str]] = []

    def visit(module: str, stack: list[str]) -> None:
        state[module] = 1
        for dep in sorted(graph[module]):
            if state.get(dep) == 1:
                cycles.append(stack[stack.index(dep):] + [dep])
            elif dep not in state:
                visit(dep, stack + [dep])
        state[module] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module, [module])
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


@pytest.mark.parametrize("source, expected", [
    ("from ._validate import _x\n", ["_x"]),
    ("from lftomo.forward.grid import Grid\n", []),
])
def test_the_private_import_rule_sees_relative_and_absolute_imports(tmp_path, source, expected):
    """The rule's own check: a relative import of a private name inside the package is found."""
    path = PACKAGE / "inverse" / "example.py"   # never written: only its name places the import
    tree = ast.parse(source)
    names = [a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)
             and _imported_module(n, path).startswith("lftomo") for a in n.names if a.name.startswith("_")]
    assert names == expected


def test_the_forward_model_never_imports_the_inverse_side():
    """``lftomo.forward`` is the simulator; the inverse side builds on it, never the reverse (lazy imports
    inside functions included)."""
    found = [f"{p.relative_to(ROOT)}:{n.lineno} {_imported_module(n, p)}"
             for p in _sources("lftomo/forward") for n in ast.walk(ast.parse(p.read_text()))
             if isinstance(n, ast.ImportFrom) and _imported_module(n, p).startswith("lftomo.inverse")]
    found += [f"{p.relative_to(ROOT)}:{n.lineno} {a.name}" for p in _sources("lftomo/forward")
              for n in ast.walk(ast.parse(p.read_text())) if isinstance(n, ast.Import)
              for a in n.names if a.name.startswith("lftomo.inverse")]
    assert not found, "lftomo.forward imports lftomo.inverse: " + "; ".join(found)


def test_docs_and_docstrings_name_the_projects_own_design_document():
    """A user's clone has only docs/design.md, whose sections have names, not numbers: no file the
    project ships may send a reader to the developers' DESIGN.md or its numbered sections."""
    shipped = [*sorted((ROOT / "lftomo").rglob("*.py")), *sorted((ROOT / "tests").rglob("*.py")),
               ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    here = Path(__file__).resolve()
    offenders = [f"{p.relative_to(ROOT)}:{i}" for p in shipped if p.resolve() != here
                 for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
                 if "DESIGN §" in line or "DESIGN.md" in line or "shared/" in line]
    assert not offenders, offenders


def test_docstring_cross_references_resolve():
    """Every ``:func:`/``:class:``/… reference to ``lftomo.…`` in the library's sources names an
    object that exists (a dataclass's fields count as its attributes)."""
    import dataclasses
    import importlib
    import re

    pattern = re.compile(r":(?:func|class|meth|attr|data|mod):`~?(lftomo(?:\.\w+)+)`")
    missing = []
    for path in sorted((ROOT / "lftomo").rglob("*.py")):
        for match in pattern.finditer(path.read_text(encoding="utf-8")):
            parts = match.group(1).split(".")
            for k in range(len(parts), 0, -1):
                try:
                    obj = importlib.import_module(".".join(parts[:k]))
                except ImportError:
                    continue
                break
            for attr in parts[k:]:
                fields = {f.name for f in dataclasses.fields(obj)} if dataclasses.is_dataclass(obj) else set()
                if not hasattr(obj, attr) and attr not in fields:
                    missing.append(f"{path.relative_to(ROOT)}: {match.group(1)}")
                    break
                obj = getattr(obj, attr, None)
    assert not missing, missing
