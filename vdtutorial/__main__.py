"""``python -m vdtutorial``: the command line of :mod:`vdtutorial.cli`.

Taught in chapter 00.
"""
import sys

from vdtutorial.cli import build_parser, main

__all__ = ["build_parser", "main"]

if __name__ == "__main__":
    sys.exit(main())
