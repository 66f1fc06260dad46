"""Ctrl-C in the iterative solvers: stop between two steps, never inside JAX.

A KeyboardInterrupt raised while JAX runs a computation (its host callbacks
apply the sparse matrices on other threads) leaves that computation running
behind the interpreter: the command prints its message and then crashes
(segmentation fault) while Python shuts down.  The solvers therefore run
under :func:`stop_between_steps`: the first Ctrl-C only records the request
(and says so on stderr); the solver loops and the host callbacks call
:func:`check_interrupt` between steps, which raises :class:`Interrupted`
(a KeyboardInterrupt) where no JAX computation is left running.  A second
Ctrl-C raises KeyboardInterrupt at once.

Outside :func:`stop_between_steps` (another thread, or a function not
decorated) Ctrl-C behaves as usual and :func:`check_interrupt` does nothing.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import sys
import threading
from collections.abc import Iterator

__all__ = ["Interrupted", "check_interrupt", "stop_between_steps"]

_STATE = {"depth": 0, "what": ""}
_REQUESTED = threading.Event()


class Interrupted(KeyboardInterrupt):
    """Ctrl-C honoured between two steps of an iterative computation."""


def _not_an_interrupt(record: logging.LogRecord) -> bool:
    """Logging filter: drop the traceback JAX logs when a host callback stops on Ctrl-C."""
    return not (record.exc_info and isinstance(record.exc_info[1], Interrupted))


#: JAX logs every exception of a host callback with its traceback; an Interrupted is no error.
logging.getLogger("jax._src.callback").addFilter(_not_an_interrupt)


def _message() -> str:
    return f"Ctrl-C: {_STATE['what']} stopped between two steps"


def check_interrupt() -> None:
    """Raise :class:`Interrupted` if Ctrl-C was pressed under :func:`stop_between_steps`.

    Safe to call from any thread (e.g. a JAX host callback, where the error
    ends the computation and reaches the caller as JAX's runtime error, which
    :func:`stop_between_steps` turns back into :class:`Interrupted`).
    """
    if _REQUESTED.is_set():
        raise Interrupted(_message())


@contextlib.contextmanager
def stop_between_steps(what: str) -> Iterator[None]:
    """Defer Ctrl-C inside the block to the next :func:`check_interrupt`.

    Parameters
    ----------
    what : str
        The computation, for the messages ("the reconstruction").

    Raises
    ------
    Interrupted
        After a Ctrl-C: from the next :func:`check_interrupt`, from an error a
        host callback's check caused, or at the end of the block.

    Notes
    -----
    Nested blocks share the outermost block's handler.  Only the main thread
    can handle signals; elsewhere the block does nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if _STATE["depth"] > 0:  # inside another block: its handler serves both
        _STATE["depth"] += 1
        try:
            yield
        finally:
            _STATE["depth"] -= 1
        return

    def on_sigint(signum, frame):
        if _REQUESTED.is_set():  # the second Ctrl-C: at once
            signal.signal(signal.SIGINT, previous)
            raise KeyboardInterrupt
        _REQUESTED.set()
        print(f"lftomo: Ctrl-C: stopping {what} after the current step (Ctrl-C again to stop at once)",
              file=sys.stderr, flush=True)

    _STATE.update(depth=1, what=what)
    _REQUESTED.clear()
    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        yield
    except Interrupted:
        raise
    except Exception as exc:
        # a check in a host callback ends the JAX computation with JAX's own error type
        if _REQUESTED.is_set() and Interrupted.__name__ in str(exc):
            raise Interrupted(_message()) from None
        raise
    finally:
        signal.signal(signal.SIGINT, previous)
        requested = _REQUESTED.is_set()
        _REQUESTED.clear()
        _STATE.update(depth=0, what="")
    if requested:  # pressed during the last step: stop all the same
        raise Interrupted(f"Ctrl-C: {what} stopped after its last step")

