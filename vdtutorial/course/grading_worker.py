"""The grading process that :func:`vdtutorial.course.grading_process.run_each` starts for one submission.

It reads its job from a file, grades it with :func:`vdtutorial.course.classroom.grade_one` and writes the result
whole, then renames it, so that a process killed while writing leaves no half result. Both files sit in a folder
that only the grader's processes can read (never a sandbox's), which is why pickle may carry them. Ctrl-C is
ignored here: answering it is the supervisor's job, which kills every grading process it started.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/classroom.py, notebooks/TEACHING.md).
"""

from __future__ import annotations

import pickle
import signal
import sys
from pathlib import Path

from vdtutorial.course.classroom import grade_one


def main(job_file: str, result_file: str) -> None:
    """One job from ``job_file``, its result into ``result_file``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    result = grade_one(pickle.loads(Path(job_file).read_bytes()))
    partial = Path(result_file + ".partial")
    partial.write_bytes(pickle.dumps(result))
    partial.rename(result_file)


if __name__ == "__main__":
    main(*sys.argv[1:3])
