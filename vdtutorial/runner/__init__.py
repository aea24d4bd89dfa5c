"""The grid runner: named jobs run on local processes or Ray, resumed from their saved states, locked so
that no run is computed twice, and reported as they go. It knows nothing of VD, TRPO or policies: the
paper's runs become its jobs in :mod:`vdtutorial.experiments.jobs`.

Modules, one idea each: :mod:`~vdtutorial.runner.grid` (a restartable grid of jobs),
:mod:`~vdtutorial.runner.backends` (where jobs execute), :mod:`~vdtutorial.runner.resume` (a run's saved
state), :mod:`~vdtutorial.runner.run_lock` (one process at a time per run),
:mod:`~vdtutorial.runner.progress` (the grid's progress lines), :mod:`~vdtutorial.runner.rows` (CSV
files), :mod:`~vdtutorial.runner.compressed` (torch files written whole and gzip-compressed: run states and
checkpoints) and :mod:`~vdtutorial.runner.kernels` (the CPU kernels pinned for exact re-runs).

Taught in chapter 07.
"""

from vdtutorial.runner.backends import run_jobs
from vdtutorial.runner.grid import GridJob, SavedInStateDir, run_grid
from vdtutorial.runner.resume import ResumeError
from vdtutorial.runner.rows import read_rows, results_file, stored_rows, write_csv

__all__ = [
    "GridJob",
    "ResumeError",
    "SavedInStateDir",
    "read_rows",
    "results_file",
    "run_grid",
    "run_jobs",
    "stored_rows",
    "write_csv",
]
