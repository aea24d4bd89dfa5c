"""Progress of a grid: one live line (runs done of total, env steps/s, ETA) and one line per finished run.

The live line is a tqdm bar over the grid's env steps, so its rate is the grid's env steps per second
summed over the runs in flight and its ETA is the steps left at that rate; its label counts the runs.
``tqdm.auto`` draws it as a widget in a notebook and as a text line in a terminal. It is on by
default only there (a terminal on stderr, or a notebook kernel); elsewhere -- a log file, CI, pytest --
only the per-run lines are printed, one per finished run, so that a long grid is never silent and a log
never fills with redrawn bars. ``progress=False`` silences both, ``progress=True`` forces both.

Taught in chapter 07.
"""

from __future__ import annotations

import sys

from tqdm.auto import tqdm


def _in_notebook() -> bool:
    try:
        from IPython import get_ipython
    except ImportError:
        return False
    shell = get_ipython()
    return shell is not None and type(shell).__name__ == "ZMQInteractiveShell"


def live_by_default() -> bool:
    """Whether a live line makes sense here: stderr is a terminal, or this is a notebook kernel."""
    return sys.stderr.isatty() or _in_notebook()


class GridProgress:
    """The listener of :func:`~vdtutorial.runner.backends.run_jobs` for a grid of runs.

    name: the experiment's name, the line's label.
    names: the name of each pending run (in the order of the jobs).
    steps: the env steps each pending run still has to do.
    done, total: runs already finished before this start (skipped), and all runs of the grid.
    progress: None (default: live line where it makes sense: module docstring, "It is on by default only there"), True
    or False.
    """

    def __init__(
        self, name: str, names: list[str], steps: list[int], done: int, total: int, progress: bool | None = None
    ):
        self.name = name
        self.names = names
        self.done = done
        self.total = total
        self.lines = progress is not False
        live = live_by_default() if progress is None else progress
        self.bar = tqdm(
            total=sum(steps),
            unit="step",
            unit_scale=True,
            dynamic_ncols=True,
            disable=not live,
            desc=self._label(),
            bar_format="{desc}: {percentage:3.0f}% | {n_fmt}/{total_fmt} env steps [{elapsed}<{remaining}, {rate_fmt}]",
        )

    def _label(self) -> str:
        return f"{self.name}: runs {self.done}/{self.total}"

    def report(self, index: int, report: dict) -> None:
        """A run's report: ``env_steps`` done since its previous report."""
        self.bar.update(report.get("env_steps", 0))

    def tick(self) -> None:
        self.bar.refresh()  # keep the clock and the ETA moving between reports

    def finished(self, index: int, result: dict) -> None:
        """A run has finished: count it and print its line."""
        self.done += 1
        self.bar.set_description_str(self._label())
        if self.lines:
            resumed = f", resumed at iteration {result['resumed_at']}" if result.get("resumed_at") else ""
            tqdm.write(
                f"{self.name}: run {self.done}/{self.total} finished: {self.names[index]} "
                f"({result['summary']}; {result['seconds']:.0f} s{resumed})",
                file=sys.stdout,
            )

    def note(self, text: str) -> None:
        """A line about the grid as a whole (e.g. the runs found finished), when lines are on."""
        if self.lines:
            tqdm.write(f"{self.name}: {text}", file=sys.stdout)

    def close(self) -> None:
        self.bar.close()
