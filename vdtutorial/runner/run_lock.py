"""One process at a time per run: a lock file beside a run's saved state.

Grids that share a state folder share their common runs (Fig. 5's and Fig. 6's 8000-sample, Sigma = 0.5
runs are Fig. 4's). When two such grids run at the same time -- four figures started at once on a
cluster, or the same command typed in two terminals -- the first to reach a run takes its lock
``RUN.pt.lock``; the other waits until the lock is released and then finds the run finished (or, if the
holder was interrupted, continues it from its last state). Without the lock both would compute the run:
the same rows (a run is a pure function of its settings), but twice the compute.

A holder keeps its lock fresh: a thread touches the file every :data:`HEARTBEAT_S` seconds. A lock whose
holder has died (SIGKILL, a lost node) is stale and taken over: on the same machine when its process no
longer exists, on another machine when it has not been touched for :data:`STALE_S` seconds. Two
processes that find the same stale lock within the same instant may both take it over; that only costs
compute, never correctness, since every state is written atomically (:mod:`~vdtutorial.runner.resume`).

Taught in chapter 07.
"""

from __future__ import annotations

import json
import os
import socket
import threading
import time
import uuid
from pathlib import Path

from vdtutorial.runner.backends import process_exists

#: Seconds between two touches of a held lock.
HEARTBEAT_S = 30.0
#: Seconds without a touch after which a lock held from another machine is taken to be dead.
STALE_S = 300.0
#: Seconds between two looks at a lock that another process holds.
WAIT_S = 2.0


def lock_path(state_path: str | os.PathLike) -> Path:
    """The lock file of the run whose state is ``state_path``."""
    state_path = Path(state_path)
    return state_path.with_name(state_path.name + ".lock")


def holder_alive(path: Path, stale_s: float = STALE_S) -> bool:
    """Whether the lock at ``path`` exists and its holder may still be running
    (module docstring, "A lock whose holder has died")."""
    try:
        age = time.time() - path.stat().st_mtime
        holder = json.loads(path.read_text())
    except FileNotFoundError:
        return False
    except ValueError:  # created an instant ago and not yet written: judge by its age alone
        return age < stale_s
    pid = holder.get("pid")
    if holder.get("host") == socket.gethostname() and isinstance(pid, int) and pid > 0 and not process_exists(pid):
        return False
    return age < stale_s


class RunLock:
    """The lock of one run. :meth:`acquire` takes it if it is free or stale and starts the heartbeat;
    :meth:`release` stops the heartbeat and removes the file if it is still this holder's."""

    def __init__(self, state_path: str | os.PathLike, heartbeat_s: float = HEARTBEAT_S, stale_s: float = STALE_S):
        self.path = lock_path(state_path)
        self.heartbeat_s = heartbeat_s
        self.stale_s = stale_s
        self.token = uuid.uuid4().hex
        self._stop: threading.Event | None = None

    def acquire(self) -> bool:
        """Take the lock; False if a live holder has it."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.exists() and not holder_alive(self.path, self.stale_s):
            self.path.unlink(missing_ok=True)  # a dead holder's lock
        try:
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            return False
        with os.fdopen(fd, "w") as file:
            json.dump({"host": socket.gethostname(), "pid": os.getpid(), "token": self.token}, file)
        self._stop = threading.Event()
        threading.Thread(target=self._beat, args=(self._stop,), daemon=True).start()
        return True

    def _beat(self, stop: threading.Event) -> None:
        while not stop.wait(self.heartbeat_s):
            try:
                os.utime(self.path)
            except OSError:  # taken over or removed: nothing left to keep fresh
                return

    def held(self) -> bool:
        """Whether the file is this holder's (not removed, not taken over)."""
        try:
            return json.loads(self.path.read_text()).get("token") == self.token
        except (OSError, ValueError):
            return False

    def release(self) -> None:
        if self._stop is not None:
            self._stop.set()
            self._stop = None
        if self.held():
            self.path.unlink(missing_ok=True)
