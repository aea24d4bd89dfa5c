"""The command line's shared pieces: argument types that refuse bad values at parse time, one-line usage
errors, where a command may write, and the options several commands share.

Not taught in a chapter: the command line's plumbing (chapter 00 shows the commands, vdtutorial/cli/).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from vdtutorial.settings import data_dir

TRACEBACK_VARIABLE = "VDTUTORIAL_TRACEBACK"


class CommandError(Exception):
    """An error the user can fix: printed as one line, exit code 2."""


# -- argument types: bad values are refused at parse time ------------------------------------------------
def _number_type(convert, accept, expected: str):
    """An argparse type: ``convert(text)``, refused with "expected EXPECTED" unless ``accept(value)``."""

    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            value = None
        if value is None or not accept(value):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value

    parse.__name__ = expected  # argparse names the type in some messages
    return parse


positive_int = _number_type(int, lambda v: v >= 1, "a positive integer")
nonnegative_int = _number_type(int, lambda v: v >= 0, "an integer >= 0")
nonnegative_float = _number_type(float, lambda v: math.isfinite(v) and v >= 0, "a finite number >= 0")
fraction = _number_type(float, lambda v: 0 < v <= 1, "a number in (0, 1]")


def plan_name(text: str) -> str:
    """An argparse type: the name of a pre-registered plan, refused with the names there are. The plans' registry
    is imported only when the option is given (it sits in the experiments package, which loads torch)."""
    from vdtutorial.experiments.plans import plan_named

    try:
        return plan_named(text).name
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def plan_help() -> str:
    from vdtutorial.experiments.plans import PLANS

    return (
        f"the pre-registered plan the folder's runs were made under ({', '.join(sorted(PLANS))}; "
        "vdtutorial/experiments/plans.py): its claims become the primary family, tested as the plan fixed; refused "
        "unless every run of the plan is there and finished"
    )


class OneLineParser(argparse.ArgumentParser):
    """argparse, but a usage error is one line (``error: ...``, exit code 2) instead of the usage
    block followed by the message: ``--help`` shows the usage."""

    def error(self, message):
        self.exit(2, f"error: {self.prog}: {message} (see {self.prog} --help)\n")


# -- where outputs go ------------------------------------------------------------------------------------
def _inside(path: Path, folder: Path) -> bool:
    return path.resolve().is_relative_to(folder.resolve())


def output_path(out: str | None, default: Path, force: bool) -> Path:
    """``--out`` if given, else ``default`` (under runs/). Refuses to replace an existing file in data/
    unless ``force``: the notebooks and figures rely on the shipped files."""
    path = Path(out) if out else default
    if path.exists() and _inside(path, data_dir()) and not force:
        raise CommandError(f"{path} is a shipped file in data/; pass --force to replace it, or --out another path")
    return path


def device_of(args):
    """``--device`` as a torch.device, refused in one line (exit code 2) when this machine has no such device."""
    from vdtutorial.policy import torch_device

    return torch_device(args.device, "--device")


def progress_of(args) -> bool:
    """Progress bars: on in a terminal, off in logs and pipes, unless --progress / --no-progress says."""
    return sys.stderr.isatty() if args.progress is None else args.progress


# -- options several commands share ----------------------------------------------------------------------
def help_when_shown(text_of):
    """An argparse action that stores its value as the default action does and whose help is ``text_of()``, called
    only when help is shown: a help text computed from the library (which loads torch) then costs nothing to a
    command, to a usage error or to the top-level ``--help``."""

    class StoreWithLateHelp(argparse._StoreAction):
        help = property(lambda self: text_of(), lambda self, value: None)

    return StoreWithLateHelp


def epochs_help() -> str:
    from vdtutorial.experiments.checkpoints import default_config

    return (
        f"passes over the training split (default: {default_config('vd', 'state').epochs} with --obs state, "
        f"{default_config('vd', 'rgbd').epochs} with --obs rgbd)"
    )


def add_progress(p) -> None:
    p.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bars on standard error (default: only in a terminal)",
    )


def add_force(p) -> None:
    p.add_argument("--force", action="store_true", help="allow replacing an existing file in data/")


def add_exact_kernels(p) -> None:
    p.add_argument(
        "--exact-kernels",
        action="store_true",
        help="pin torch's and numpy's CPU kernels to AVX2 (the command starts again with them pinned), "
        "so that shipped results regenerate bit for bit; default: this CPU's own, faster kernels",
    )
