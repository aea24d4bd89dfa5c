"""``python -m vdtutorial``: the command line of :mod:`vdtutorial.cli`.

Taught in chapter 00.
"""

import sys

from vdtutorial.cli import build_parser, main
from vdtutorial.cli.shadowing import step_around_a_shadowing_folder

__all__ = ["build_parser", "main"]

if __name__ == "__main__":
    step_around_a_shadowing_folder()  # first: a clone's folder may have been taken for the package
    sys.exit(main())
