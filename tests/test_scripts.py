"""The benchmark and study scripts import cleanly and the scripts define their entry point.

They are run by hand (docs/performance.md, docs/accuracy.md), not by the test suite, so a renamed
or moved library name would otherwise go unnoticed until someone reruns a measurement.
"""
from __future__ import annotations

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
