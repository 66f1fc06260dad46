"""The benchmark and study scripts import cleanly and the scripts define their entry point.

They are run by hand (docs/performance.md, docs/accuracy.md), not by the test suite, so a renamed
or moved library name would otherwise go unnoticed until someone reruns a measurement.
"""
from __future__ import annotations

import ast
import importlib
import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(p for d in ("benchmarks", "studies") for p in (ROOT / d).glob("*.py") if p.name != "__init__.py")


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_script_imports_and_has_main(path, monkeypatch):
    monkeypatch.syspath_prepend(str(path.parent))  # studies import their sibling helpers (sweep)
    spec = importlib.util.spec_from_file_location(f"_script_{path.parent.name}_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)
    spec.loader.exec_module(module)  # runs the module body only: each script guards main() by __name__
    if "__main__" in path.read_text():  # a script, not a helper module such as studies/sweep.py
        assert callable(getattr(module, "main", None)), f"{path.name} has no main()"


def _library_names(tree: ast.AST) -> list[tuple[str, int, str]]:
    """``(module, line, name)`` of each library name a script uses: ``from lftomo... import name``
    anywhere (function bodies included) and each ``lt.a.b`` chain (``import lftomo as lt``) and its prefixes."""
    aliases = {a.asname or a.name for node in ast.walk(tree) if isinstance(node, ast.Import)
               for a in node.names if a.name == "lftomo"}
    used = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "lftomo":
            used += [(node.module, node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.Attribute):
            chain, value = [node.attr], node.value
            while isinstance(value, ast.Attribute):
                chain.insert(0, value.attr)
                value = value.value
            if isinstance(value, ast.Name) and value.id in aliases:
                used.append(("lftomo", node.lineno, ".".join(chain)))
    return used


@pytest.mark.parametrize("path", SCRIPTS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_script_library_names_exist(path):
    """Imports inside functions run only when a measurement is rerun; resolve them all now."""
    missing = []
    for module, line, name in _library_names(ast.parse(path.read_text())):
        obj = importlib.import_module(module)
        for part in name.split("."):
            if not hasattr(obj, part):
                try:  # a submodule not imported by its package
                    obj = importlib.import_module(f"{obj.__name__}.{part}")
                    continue
                except (ImportError, AttributeError):
                    missing.append(f"line {line}: {module}.{name}")
                    break
            obj = getattr(obj, part)
    assert not missing, f"{path.name} uses library names that do not exist: {missing}"
