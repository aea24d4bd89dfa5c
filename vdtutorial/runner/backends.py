"""Where the runs of a grid execute: this process, local worker processes, or a Ray cluster.

Every run is independent and a pure function of its job, and every backend runs it with one torch
thread, so the results do not depend on the backend or on the number of workers (a test checks it).

``"local"`` (the default, nothing to install)
    ``workers`` spawned processes ("spawn": they start clean instead of inheriting the parent's torch
    threads and pybullet clients), or this process when ``workers`` is 1. As with any spawned pool, a
    *script* that uses it with ``workers > 1`` must do so under ``if __name__ == "__main__":``
    (notebooks and ``python -m vdtutorial`` need nothing). A worker whose parent has died (the grid was
    killed) stops at its next report instead of running on unseen.
``"ray"`` (``pip install -e ".[cluster]"``)
    One Ray task per run, asking for one CPU. Without ``address`` a private local Ray is started with
    ``workers`` CPUs (and shut down at the end); with ``address`` (e.g. ``"auto"`` on a cluster node, or
    ``"HEAD_IP:6379"``) the runs go to that cluster and Ray places them on its free CPUs. The cluster's
    nodes need the same vdtutorial installation and must see the same paths (demonstrations,
    checkpoints, the output folder: a shared file system). Quick mode is passed on to the tasks.



Taught in chapter 07.
"""

from __future__ import annotations

import inspect
import logging
import multiprocessing
import os
import queue
import signal
import socket

import torch

from vdtutorial.runner.kernels import PINNED
from vdtutorial.settings import QUICK_ENV, is_quick

BACKENDS = ("local", "ray")
#: Seconds between two ticks of the listener while no report arrives.
_POLL = 0.5


class _Silent:
    def report(self, index, report) -> None:
        pass

    def tick(self) -> None:
        pass

    def finished(self, index, result) -> None:
        pass


def _drive(fn, job, report):
    """Run one job in this process, passing its reports to ``report``; return its result."""
    if not inspect.isgeneratorfunction(fn):
        return fn(job)
    steps = fn(job)
    while True:
        try:
            report(next(steps))
        except StopIteration as finished:
            return finished.value


def run_jobs(
    fn, jobs: list, workers: int = 2, backend: str = "local", address: str | None = None, listener=None
) -> list:
    """``[result of fn(job) for job in jobs]`` on ``backend``
    (module docstring, "Where the runs of a grid execute"); ``fn`` must be a module-level function. ``listener``
    receives the reports (see below).

    A job function is a generator function: it yields progress reports (any picklable value) and its
    ``return`` value is the run's result. :func:`run_jobs` hands each report to ``listener.report(index,
    report)`` as it arrives and each result to ``listener.finished(index, result)`` as its run ends, calls
    ``listener.tick()`` about twice a second while waiting (so that a live line can refresh its clock), and
    returns the results in the order of the jobs. A plain function works
    too (no reports).
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if address is not None and backend != "ray":
        raise ValueError("an address names a Ray cluster: use it with backend 'ray'")
    listener = listener or _Silent()
    if not jobs:
        return []
    if backend == "ray":
        return _run_ray(fn, jobs, workers, address, listener)
    if workers <= 1 or len(jobs) <= 1:
        return _run_here(fn, jobs, listener)
    return _run_pool(fn, jobs, workers, listener)


# ----------------------------------------------------------------------------------------------
# Local: this process, or spawned worker processes
# ----------------------------------------------------------------------------------------------
def _run_here(fn, jobs, listener) -> list:
    """In this process, with one torch thread (restored afterwards) like every worker."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        results = []
        for i, job in enumerate(jobs):
            results.append(_drive(fn, job, lambda report, i=i: listener.report(i, report)))
            listener.finished(i, results[-1])
        return results
    finally:
        torch.set_num_threads(threads)


_reports: multiprocessing.Queue | None = None  # a pool worker's channel to the parent
_parent: int | None = None


def _init_worker(reports, parent: int) -> None:
    global _reports, _parent
    _reports = reports
    _parent = parent
    torch.set_num_threads(1)
    # Ctrl-C reaches the whole process group: the parent alone answers it (it terminates the pool), so that
    # the user sees one line instead of a traceback from every worker
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _pool_task(task) -> None:
    fn, index, job = task

    def report(value) -> None:
        if os.getppid() != _parent:  # the grid was killed: stop rather than run on unseen
            os._exit(1)
        _reports.put((index, "report", value))

    _reports.put((index, "started", os.getpid()))
    _reports.put((index, "result", _drive(fn, job, report)))


def process_exists(pid: int) -> bool:
    """Whether a process with this id runs on this machine (another user's counts)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _run_pool(fn, jobs, workers, listener) -> list:
    """Each job is a task of a spawned pool. A failed run stops the grid as soon as it fails (its exception
    is raised here); so does a worker that dies while it runs a job (killed by the system, out of memory),
    which a pool would otherwise replace silently, leaving the grid waiting for ever."""
    context = multiprocessing.get_context("spawn")
    reports = context.Queue()
    results = {}
    running = {}
    failures = []
    with context.Pool(min(workers, len(jobs)), initializer=_init_worker, initargs=(reports, os.getpid())) as pool:
        for i, job in enumerate(jobs):
            pool.apply_async(_pool_task, ((fn, i, job),), error_callback=failures.append)
        while len(results) < len(jobs):
            if failures:
                raise failures[0]
            try:
                index, kind, value = reports.get(timeout=_POLL)
            except queue.Empty:
                dead = [index for index, pid in running.items() if not process_exists(pid)]
                if dead:
                    name = getattr(getattr(jobs[dead[0]], "spec", None), "name", f"job {dead[0]}")
                    raise RuntimeError(
                        f"the worker process running {name} died without an error (killed by the "
                        "system, out of memory?)"
                    )
                listener.tick()
                continue
            if kind == "started":
                running[index] = value
            elif kind == "report":
                listener.report(index, value)
            else:
                results[index] = value
                running.pop(index, None)
                listener.finished(index, value)
        pool.close()  # let the workers exit on their own: terminating them leaks their semaphores
        pool.join()
    return [results[i] for i in range(len(jobs))]


# ----------------------------------------------------------------------------------------------
# Ray
# ----------------------------------------------------------------------------------------------
def _ray_task(fn, job):
    """The body of a run's Ray task: a generator streaming ("report", value) items, then ("result", value)."""
    torch.set_num_threads(1)
    if not inspect.isgeneratorfunction(fn):
        yield "result", fn(job)
        return
    steps = fn(job)
    while True:
        try:
            yield "report", next(steps)
        except StopIteration as finished:
            yield "result", finished.value
            return


def _import_ray():
    try:
        import ray
    except ImportError as exc:
        message = "the Ray backend needs Ray: pip install -e \".[cluster]\" (or pip install 'ray>=2.9')"
        raise ImportError(message) from exc
    return ray


#: Tries to start a private local Ray. On a heavily loaded machine its raylet gives up when the dashboard
#: agent is slow to start (ray-project/ray issue 65983); a later try may find the machine less busy.
LOCAL_RAY_ATTEMPTS = 3


def _start_local_ray(ray, workers: int, runtime_env: dict) -> None:
    """``ray.init`` of a private local Ray with ``workers`` CPUs, tried up to :data:`LOCAL_RAY_ATTEMPTS`
    times (whatever a failed try left behind is shut down before the next)."""
    for attempt in range(1, LOCAL_RAY_ATTEMPTS + 1):
        try:
            ray.init(
                address="local",
                num_cpus=max(1, workers),
                include_dashboard=False,
                runtime_env=runtime_env,
                logging_level=logging.WARNING,
                object_store_memory=200 * 2**20,
            )
            return
        except Exception as exc:  # Ray raises a bare Exception when its node does not come up
            ray.shutdown()
            if attempt == LOCAL_RAY_ATTEMPTS:
                raise RuntimeError(
                    f"Ray could not start on this machine in {attempt} tries ({exc}). On a heavily loaded machine "
                    "Ray's raylet gives up when its agent process takes more than 15 s to start (ray-project/ray "
                    "issue 65983): retry when the machine is less busy, or use the local backend"
                ) from exc


#: Seconds to wait for a Ray cluster's address to answer before the run is refused. Ray itself keeps retrying an
#: unreachable address for minutes.
RAY_CONNECT_TIMEOUT = 10


def _check_reachable(address: str, timeout: float = RAY_CONNECT_TIMEOUT) -> None:
    """Refuse, in one line, a ``HOST:PORT`` (or ``ray://HOST:PORT``) address nothing answers at; ``"auto"`` and
    other forms Ray resolves itself are left to Ray."""
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not port.isdigit():
        return
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as exc:
        raise ConnectionError(
            f"no Ray cluster answers at {address} ({exc}): start its head node (ray start --head) or check the address"
        ) from None


def _run_ray(fn, jobs, workers, address, listener) -> list:
    ray = _import_ray()
    started = not ray.is_initialized()
    if started:
        # a Ray worker loads numpy before it runs a task, so kernel pins (if set: vdtutorial.runner.kernels)
        # must be in its environment from the start, as must the quick switch
        pins = {name: os.environ[name] for name in PINNED if name in os.environ}
        env = {"env_vars": {QUICK_ENV: "1" if is_quick() else "0", **pins}}
        if address is None:  # a private local Ray, even if another one runs on this machine
            _start_local_ray(ray, workers, env)
        else:
            _check_reachable(address)
            ray.init(address=address, runtime_env=env, logging_level=logging.WARNING)
    try:
        task = ray.remote(num_cpus=1)(_ray_task)
        pending = [(task.remote(fn, job), i) for i, job in enumerate(jobs)]
        results = [None] * len(jobs)
        while pending:
            ready, _ = ray.wait([gen for gen, _ in pending], num_returns=1, timeout=_POLL)
            if not ready:
                listener.tick()
                continue
            position = next(k for k, (gen, _) in enumerate(pending) if gen is ready[0])
            gen, index = pending[position]
            try:
                kind, value = ray.get(next(gen))  # raises the task's exception here
            except StopIteration:
                del pending[position]
                continue
            if kind == "report":
                listener.report(index, value)
            else:
                results[index] = value
                del pending[position]
                listener.finished(index, value)
        return results
    finally:
        if started:
            ray.shutdown()
