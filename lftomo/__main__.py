"""``python -m lftomo``: the ``lftomo`` command (:func:`lftomo.cli.console_main`)."""

from lftomo.cli import console_main

if __name__ == "__main__":
    console_main()
