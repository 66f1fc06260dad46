"""The one error type of lftomo.

Every check of an argument, a scene file or a saved file raises
:class:`LftomoError`.  It subclasses :class:`ValueError`, so code written
against the earlier ``except ValueError`` keeps working.  The ``lftomo``
command prints it as ``lftomo: error: <message>`` and exits with status 2.
"""

from __future__ import annotations

__all__ = ["LftomoError"]


class LftomoError(ValueError):
    """A bad argument, scene file, saved file or output location.

    The message names the argument, key or file (and member), the value
    found and what is allowed.
    """
