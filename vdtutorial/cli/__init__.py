"""The command line, ``python -m vdtutorial COMMAND`` (or ``vdtutorial COMMAND``): the pipeline's steps, the
paper's experiments, the benchmarks, the chapters written out and the classroom.

Modules, one idea each: :mod:`~vdtutorial.cli.parser` (the commands and their options),
:mod:`~vdtutorial.cli.commands` (what each command does), :mod:`~vdtutorial.cli.arguments` (argument types
and shared options), :mod:`~vdtutorial.cli.bench` (the benchmarks) and :mod:`~vdtutorial.cli.shadowing` (a clone's
folder taken for the package). Commands import the library when they run, so ``--help`` loads no torch. :func:`main`
runs one command and
turns an error the user can fix into one line and exit code 2.

Taught in chapter 00.
"""

from __future__ import annotations

import os
import sys

from vdtutorial.cli.arguments import TRACEBACK_VARIABLE, CommandError
from vdtutorial.cli.parser import build_parser
from vdtutorial.settings import is_quick

__all__ = ["CommandError", "build_parser", "main"]


def _exact_kernels(args, argv) -> None:
    """``--exact-kernels``: start this command again with the AVX2 pins of :mod:`vdtutorial.runner.kernels` in its
    environment. numpy is already loaded when the arguments are parsed, and its OpenBLAS chose its kernels then, so
    setting the variables here would reach torch but not numpy: only a new process gets both."""
    from vdtutorial.runner.kernels import can_pin, pin_vector_kernels, pinned

    if not getattr(args, "exact_kernels", False) or pinned():
        return
    if not can_pin():
        print("note: --exact-kernels: this CPU has no AVX2 kernels to pin, so it runs its own", file=sys.stderr)
        return
    if argv is not None:
        raise CommandError(
            "--exact-kernels restarts the command: run it as a program (python -m vdtutorial ...), "
            "or set the variables of vdtutorial.runner.kernels.PINNED before Python starts"
        )
    env = dict(os.environ)
    pin_vector_kernels(env)
    sys.stdout.flush()
    os.execve(sys.executable, [sys.executable, "-m", "vdtutorial", *sys.argv[1:]], env)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        _exact_kernels(args, argv)  # first: it may start the command again
        if is_quick():
            print("[quick mode: small budgets]", file=sys.stderr)
        args.func(args)
    except KeyboardInterrupt:  # Ctrl-C: one line saying what survives, and the shell's code for SIGINT
        hint = getattr(args, "on_interrupt", None)
        print(f"interrupted{': ' + hint if hint else ''}", file=sys.stderr)
        return 130
    except (
        CommandError,
        ValueError,
        OSError,
        ImportError,
    ) as exc:  # expected: bad path, corrupt file, bad value, Ray not installed
        if os.environ.get(TRACEBACK_VARIABLE):
            raise
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"error: {message}", file=sys.stderr)
        return 2
    return 0
