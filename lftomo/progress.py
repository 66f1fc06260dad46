"""Progress bars: a tqdm bar on stderr, or a silent stand-in with the same three methods.

Used by the renderer, the weight-matrix builders and the inverse solvers.
"""

from __future__ import annotations

__all__ = ["NoBar", "progress_bar"]


class NoBar:
    """A progress bar that shows nothing (``update``, ``set_postfix_str``, ``close``)."""

    def update(self, n):
        pass

    def set_postfix_str(self, s):
        pass

    def close(self):
        pass


def progress_bar(total: int | None, show: bool, desc: str, unit: str = "px"):
    """A tqdm bar (stderr; ``total`` None: a counter without an end), or a silent stand-in."""
    if not show:
        return NoBar()
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit=unit, unit_scale=unit == "px", leave=False)
