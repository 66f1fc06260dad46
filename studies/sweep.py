"""Dask plumbing shared by the sweeps in ``studies/``: ``--workers``/``--scheduler`` and the resume settings.

A sweep's draws are independent tasks.  Without ``--workers``/``--scheduler``
they run here, one after the other; with them, as Dask tasks
(:func:`lftomo.series.run_tasks`: the shared inputs — light field, weights,
truth — sent once per worker), recorded in the sweep's rows file
(:class:`lftomo.io.ResumableRows`) as they finish.  The rows file's settings
leave out where the draws ran (:func:`settings`), so a sweep interrupted on a
cluster resumes on a laptop and the other way round.
"""
from __future__ import annotations

import argparse
from typing import Any, Callable, Iterator, Sequence

#: Arguments that say where the draws run, not what they compute.
WHERE = ("scheduler", "workers")


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """``--scheduler ADDRESS`` and ``--workers N`` (mutually exclusive)."""
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--scheduler", default=None, help="Dask scheduler address (tcp://host:8786): the draws run "
                                                    "there as tasks")
    g.add_argument("--workers", type=int, default=None, help="run the draws on a local Dask cluster of this many "
                                                            "single-threaded processes")


def settings(a: argparse.Namespace) -> dict:
    """What the rows depend on: the arguments, less where they are computed."""
    return {k: v for k, v in vars(a).items() if k not in WHERE}


def run(fn: Callable, todo: Sequence[tuple], a: argparse.Namespace, *shared: Any) -> Iterator[tuple]:
    """Yield ``(key, fn(*key, *shared))`` for each key of ``todo``: here in order, or as Dask tasks as they
    finish (``a.scheduler`` / ``a.workers``)."""
    if a.workers is not None and a.workers < 1:
        raise SystemExit(f"--workers must be >= 1, got {a.workers}")
    from lftomo.series import run_tasks

    serial = a.scheduler is None and a.workers is None
    yield from run_tasks(fn, todo, *shared, scheduler=a.scheduler, workers=a.workers, serial=serial)
