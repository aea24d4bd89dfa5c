"""Resumable runs: the state of a run saved atomically every few iterations, and checked before reuse.

A run is resumable when it is a pure function of its settings and its state after iteration k continues
it exactly (a TRPO run is: it derives each iteration's resets and action noise from (seed, iteration);
its state is :meth:`TRPO.checkpoint <vdtutorial.trpo.TRPO.checkpoint>`, see
:mod:`vdtutorial.experiments.runs`). The state file holds the run's own checkpoint (a dict with its
``rows``) plus:

* ``run_settings``: everything that determines the run's numbers, as plain data. A state is only ever
  resumed by a run with equal settings; otherwise :class:`ResumeError` says which settings differ, so
  that one folder never silently mixes two configurations.
* ``rng``: the global torch, numpy and Python random states, restored on resume, so that a resumed run
  stays exact even if some part of it draws from them.

States are written whole and gzip-compressed (:mod:`vdtutorial.runner.compressed`): a run killed at any moment
(SIGKILL included) leaves the previous state or the new one, never half a file, and a long grid's states, committed
as it goes, take a third of the room or less. Uncompressed states are still read.
Taught in chapter 07.
"""

from __future__ import annotations

import os
import random
from pathlib import Path

import numpy as np
import torch

from vdtutorial.runner.compressed import load_compressed, save_compressed
from vdtutorial.runner.kernels import kernel_settings


class ResumeError(ValueError):
    """A saved run cannot continue the requested one: other settings, or more iterations than asked for."""


def _rng_state() -> dict:
    kind, keys, position, has_gauss, gauss = np.random.get_state()
    return {
        "torch": torch.get_rng_state(),
        "python": random.getstate(),
        "numpy": (kind, torch.from_numpy(keys.astype(np.int64)), position, has_gauss, gauss),
    }


def _set_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    random.setstate(state["python"])
    kind, keys, position, has_gauss, gauss = state["numpy"]
    np.random.set_state((kind, keys.numpy().astype(np.uint32), position, has_gauss, gauss))


def numerics() -> dict[str, str]:
    """What, besides a run's settings, decides its last digits: the torch and numpy versions and the CPU
    kernels in use (:func:`vdtutorial.runner.kernels.kernel_settings`). Another value does not change what the
    run is, so it is not a setting; it only voids the promise of rows equal to an uninterrupted run's."""
    return {"torch": str(torch.__version__), "numpy": str(np.__version__), **kernel_settings()}


def numerics_warning(state: dict) -> str | None:
    """A warning if ``state`` was saved under other numerics than this process's (None: the same, or a
    state from before they were saved). Only what the state recorded is compared: a state saved before the CPU
    model was kept says nothing about its machine."""
    saved, now = state.get("numerics", {}), numerics()
    differences = settings_differences(saved, {key: now[key] for key in saved if key in now})
    if not differences:
        return None
    return (
        f"resuming a run saved under other numerics ({'; '.join(differences)}): it continues, but its rows "
        "may differ in the last digits from those of an uninterrupted run"
    )


def numerics_stretches(saved: dict | None, iteration: int) -> list[dict]:
    """The numerics each stretch of a run was computed under, as ``{"from_iteration": k, **numerics}`` entries:
    ``saved``'s stretches (None: a new run), then this process's numerics from ``iteration`` on where they differ
    from the last stretch's. A run continued in another session may have moved to another machine; the stretches
    say where, which the last saved numerics alone cannot. A state saved before stretches were kept counts as one
    stretch of its last numerics from an unknown iteration (``None``)."""
    stretches = list((saved or {}).get("numerics_stretches") or [])
    if not stretches and saved is not None and "numerics" in saved:
        stretches = [{"from_iteration": None, **saved["numerics"]}]
    now = numerics()
    if not stretches or {k: v for k, v in stretches[-1].items() if k != "from_iteration"} != now:
        stretches.append({"from_iteration": iteration, **now})
    return stretches


def save_run_state(
    checkpoint: dict, path: str | os.PathLike, settings: dict, seconds: float, stretches: list[dict]
) -> None:
    """Write a run's ``checkpoint`` (a dict with its ``rows``, e.g. :meth:`TRPO.checkpoint
    <vdtutorial.trpo.TRPO.checkpoint>`) with the run's settings, the global random states, the numerics
    (:func:`numerics`) and those of each of its stretches (:func:`numerics_stretches`), and the run's compute
    time so far (``seconds``), atomically."""
    save_compressed(
        {
            **checkpoint,
            "run_settings": settings,
            "rng": _rng_state(),
            "numerics": numerics(),
            "numerics_stretches": stretches,
            "seconds": seconds,
        },
        Path(path),
    )


def save_finished_rows(path: str | os.PathLike, settings: dict, rows: list[dict], seconds: float) -> None:
    """The state of a run computed in one piece (the expert's reference): its settings, all its rows, and the
    numerics of its one stretch."""
    here = numerics()
    save_compressed(
        {
            "run_settings": settings,
            "rows": rows,
            "numerics": here,
            "numerics_stretches": [{"from_iteration": 0, **here}],
            "seconds": seconds,
        },
        path,
    )


def read_run_state(path: str | os.PathLike) -> dict:
    """A state file as written by :func:`save_run_state` or :func:`save_finished_rows`."""
    try:
        state = load_compressed(path)
    except Exception as exc:  # truncated or not a state file: say which file, and what to do
        raise ResumeError(f"{path} is not a readable run state ({exc}); delete it or rerun with --restart") from exc
    if not isinstance(state, dict) or "run_settings" not in state:
        raise ResumeError(f"{path} is not a run state written by vdtutorial; delete it or rerun with --restart")
    return state


def settings_differences(saved: dict, wanted: dict, prefix: str = "") -> list[str]:
    """The settings that differ, as ``"name: saved -> wanted"`` (nested dicts by dotted name)."""
    differences = []
    for key in dict.fromkeys([*saved, *wanted]):
        old, new = saved.get(key), wanted.get(key)
        if isinstance(old, dict) and isinstance(new, dict):
            differences += settings_differences(old, new, f"{prefix}{key}.")
        elif old != new:
            differences.append(f"{prefix}{key}: {old!r} -> {new!r}")
    return differences


def check_resumable(path: str | os.PathLike, state: dict, settings: dict, iterations: int) -> None:
    """Raise :class:`ResumeError` unless the saved ``state`` continues a run with ``settings`` that
    should end after ``iterations`` rows (fewer saved rows: it resumes; as many: it is finished)."""
    differences = settings_differences(state["run_settings"], settings)
    if differences:
        raise ResumeError(
            f"{path} holds a run with other settings ({'; '.join(differences)}): rerun with "
            "--restart to discard the saved runs of this experiment, or choose another --out "
            "(another --state-dir if you named one)"
        )
    if len(state["rows"]) > iterations:
        raise ResumeError(
            f"{path} holds {len(state['rows'])} iterations, more than the {iterations} asked for: "
            "rerun with --restart, or ask for at least as many steps"
        )


def restore_random_states(state: dict) -> None:
    """Set the global random states saved with a state read by :func:`read_run_state` (the run restores
    its own checkpoint)."""
    _set_rng_state(state["rng"])
