"""Execute every study notebook in ``notebooks/`` and fail on any cell error.

Notebooks are discovered by name (``notebooks/*.ipynb``) and run in sorted
order (they are numbered ``01_…``, ``02_…``), each in a fresh ``python3``
kernel whose working directory is a temporary folder, so a notebook can write
files without touching the checkout.  The notebooks check their own
conclusions with ``assert`` cells, so a notebook whose numbers stop supporting
its text fails here too.

Each kernel imports the same ``lftomo`` as this test process (its folder goes first on the
kernel's ``PYTHONPATH``).  Under ``python -m pytest`` in the checkout that is the checkout, while a
bare kernel started in a temporary folder would import the installed copy: different code from
what the other tests check, and numba's ``cache=True`` kernels, cached per source file, compiled a
second time (about 100 s of the first notebook in a fresh CI venv).

A second test keeps the committed notebooks stripped: no outputs and no
execution counts (regenerate or clear them before committing).
"""

import os
from pathlib import Path

import pytest

import lftomo

NOTEBOOK_DIR = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
CELL_TIMEOUT_S = 600
#: the folder holding the ``lftomo`` package this process imported
LFTOMO_ROOT = Path(lftomo.__file__).resolve().parents[1]


def _ids(paths):
    return [p.stem for p in paths]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_ids(NOTEBOOKS))
def test_notebook_executes_without_errors(path, tmp_path, monkeypatch):
    nbformat = pytest.importorskip("nbformat", reason="nbformat is not installed (pip install '.[test]')")
    nbclient = pytest.importorskip("nbclient", reason="nbclient is not installed (pip install '.[test]')")
    # The notebooks' dense linear algebra is small (<= 512 x 512); a multi-threaded BLAS gains
    # nothing on it and, on a busy 2-core runner, its spinning threads made it up to 100x slower.
    # Unless the caller chose otherwise, the kernel (which inherits this environment) uses one
    # BLAS thread; numba's parallel kernels are not affected.
    for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        if var not in os.environ:
            monkeypatch.setenv(var, "1")
    pythonpath = [str(LFTOMO_ROOT)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(pythonpath))
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        nb,
        timeout=CELL_TIMEOUT_S,
        kernel_name="python3",
        resources={"metadata": {"path": str(tmp_path)}},
    )
    # raises nbclient.exceptions.CellExecutionError (with the cell's traceback) on any failing cell
    client.execute()


@pytest.mark.parametrize("path", NOTEBOOKS, ids=_ids(NOTEBOOKS))
def test_notebook_is_committed_without_outputs(path):
    nbformat = pytest.importorskip("nbformat", reason="nbformat is not installed (pip install '.[test]')")
    nb = nbformat.read(path, as_version=4)
    dirty = [k for k, c in enumerate(nb.cells)
             if c.cell_type == "code" and (c.get("outputs") or c.get("execution_count") is not None)]
    assert not dirty, f"{path.name}: code cells {dirty} have outputs or execution counts; strip them before committing"


def test_notebooks_are_numbered():
    assert NOTEBOOKS, f"no notebooks found in {NOTEBOOK_DIR}"
    bad = [p.name for p in NOTEBOOKS if not (p.name[:2].isdigit() and p.name[2] == "_")]
    assert not bad, f"notebooks must be named NN_topic.ipynb so they run in order: {bad}"
