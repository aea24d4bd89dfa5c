"""The grading process that :func:`vdtutorial.course.grading_process.run_each` starts for one submission.

It reads its job from a file, grades it with :func:`vdtutorial.course.classroom.grade_one` and writes the result
whole, then renames it, so that a process killed while writing leaves no half result. Both files sit in a folder
that only the grader's processes can read (never a sandbox's), which is why pickle may carry them. Ctrl-C is
ignored here: answering it is the supervisor's job, which kills every grading process it started. A supervisor
killed outright (``kill -9``) cannot: then this process ends its own process group, the kernel's sandbox with it
(:func:`end_with`), instead of grading on for nobody beside the grader that a teacher starts again.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/classroom.py, notebooks/TEACHING.md).
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import threading
import time
from pathlib import Path

from vdtutorial.course.classroom import grade_one


#: How often the process looks whether its supervisor is still there (seconds).
WATCH_SECONDS = 0.5


def end_with(supervisor: int) -> threading.Thread:
    """Watch, in a daemon thread, that the parent is still the process ``supervisor``; once it is not (it died, and
    this process was handed to another parent), kill this process's whole group: the grading process, the kernel's
    sandbox launcher and anything else it started (bubblewrap then ends the sandbox). Returns the thread."""

    def watch() -> None:
        while os.getppid() == supervisor:
            time.sleep(WATCH_SECONDS)
        os.killpg(os.getpgrp(), signal.SIGKILL)

    thread = threading.Thread(target=watch, name="end-with-supervisor", daemon=True)
    thread.start()
    return thread


def main(job_file: str, result_file: str, supervisor: str) -> None:
    """One job from ``job_file``, its result into ``result_file``, for as long as ``supervisor`` (a pid) lives."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    end_with(int(supervisor))
    result = grade_one(pickle.loads(Path(job_file).read_bytes()))
    partial = Path(result_file + ".partial")
    partial.write_bytes(pickle.dumps(result))
    partial.rename(result_file)


if __name__ == "__main__":
    main(*sys.argv[1:4])
