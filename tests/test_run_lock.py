"""Run locks: one process at a time computes a run; a dead holder's lock is taken over; a grid that finds a
run held by another grid waits for it and takes its result instead of computing it again."""

import json
import os
import socket
import subprocess
import sys
import threading
import time

from vdtutorial.experiments import RunSpec, default_trpo_config, run_experiment
from vdtutorial.experiments.jobs import Job
from vdtutorial.runner import grid as grid_module
from vdtutorial.runner.run_lock import STALE_S, RunLock, holder_alive, lock_path
from vdtutorial.trpo import TIMING_COLUMNS


def _dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def _write_lock(state_path, host, pid, age=0.0):
    path = lock_path(state_path)
    path.write_text(json.dumps({"host": host, "pid": pid, "token": "someone else"}))
    os.utime(path, (time.time() - age, time.time() - age))
    return path


def test_a_run_lock_is_exclusive_until_released(tmp_path):
    state = tmp_path / "run.pt"
    first, second = RunLock(state), RunLock(state)
    assert first.acquire() and first.held()
    assert holder_alive(lock_path(state))
    assert not second.acquire()
    first.release()
    assert not lock_path(state).exists() and not holder_alive(lock_path(state))
    assert second.acquire()
    second.release()


def test_a_dead_holders_lock_is_taken_over_and_a_live_ones_is_not(tmp_path):
    state = tmp_path / "run.pt"
    _write_lock(state, socket.gethostname(), _dead_pid())  # this machine, the process is gone
    lock = RunLock(state)
    assert lock.acquire() and lock.held()
    lock.release()

    _write_lock(state, "another-node", 1)  # another machine, touched just now: alive
    assert not RunLock(state).acquire()
    _write_lock(state, "another-node", 1, age=STALE_S + 1)  # not touched for too long: dead
    lock = RunLock(state)
    assert lock.acquire()
    lock.release()


def test_a_holder_keeps_its_lock_fresh_and_never_removes_another_holders(tmp_path):
    state = tmp_path / "run.pt"
    lock = RunLock(state, heartbeat_s=0.05)
    assert lock.acquire()
    os.utime(lock.path, (time.time() - 1000, time.time() - 1000))
    time.sleep(0.5)
    assert time.time() - lock.path.stat().st_mtime < 1
    _write_lock(state, "another-node", 1)  # taken over while it was thought dead
    lock.release()
    assert lock_path(state).exists()


def _specs():
    return [RunSpec("none", "reach", None, None, seed, "state", 400, "none") for seed in (0, 1)]


def _grid(out, progress=False):
    return run_experiment("tiny", _specs(), "tiny", out, 1, window=2, command="test", progress=progress)


def _without_wall_time(rows):
    return [{k: v for k, v in row.items() if k not in TIMING_COLUMNS} for row in rows]


def test_a_job_waits_while_another_process_holds_its_run_then_continues_from_its_state(tmp_path, monkeypatch):
    monkeypatch.setattr(grid_module, "WAIT_S", 0.01)
    plain = _grid(tmp_path / "plain")
    spec = _specs()[0]
    state = tmp_path / "runs" / f"{spec.name}.pt"
    job = Job(spec, state, state.with_suffix(".csv"), None, None, None, default_trpo_config(), 1)
    other = RunLock(state)
    assert other.acquire()
    steps = grid_module.run_job(job)
    assert [next(steps) for _ in range(3)] == [{"env_steps": 0}] * 3  # waiting: no iteration done
    assert not state.exists()
    other.release()
    reports = []
    while True:
        try:
            reports.append(next(steps))
        except StopIteration as finished:
            result = finished.value
            break
    assert [report["iteration"] for report in reports] == [1, 2]
    assert _without_wall_time(result["rows"]) == _without_wall_time([r for r in plain.rows if r["seed"] == 0])
    assert not lock_path(state).exists()


def test_a_grid_puts_a_run_another_grid_holds_last_and_its_rows_are_unchanged(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(grid_module, "WAIT_S", 0.01)
    plain = _grid(tmp_path / "plain")
    specs = _specs()
    other = RunLock(tmp_path / "held" / "runs" / f"{specs[0].name}.pt")
    assert other.acquire()
    releaser = threading.Timer(0.5, other.release)
    releaser.start()
    capsys.readouterr()
    held = _grid(tmp_path / "held", progress=True)
    releaser.join()
    out = capsys.readouterr().out
    assert "1 of them being computed by another grid (waited for last)" in out
    assert out.index(f"finished: {specs[1].name}") < out.index(f"finished: {specs[0].name}")
    assert _without_wall_time(held.rows) == _without_wall_time(plain.rows)
    assert not list((tmp_path / "held" / "runs").glob("*.lock"))
