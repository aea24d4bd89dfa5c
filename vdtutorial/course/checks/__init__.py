"""Trusted checks: an exercise's points are decided outside the student's kernel.

A submission's code runs in its kernel, and so did the tests that scored it: code in an answer cell could change
what the tests compare. Here every exercise has a :class:`Check` of three parts, split where trust ends:

* ``inputs(rng)`` -- in the grading process: fresh test inputs, as plain arrays, drawn from a seed the grader picks
  for each submission (so that no answer can be computed in advance);
* ``probe(namespace, inputs)`` -- in the student's kernel: calls the student's function (found in the notebook's
  ``namespace``) on those inputs and returns what it gave, as plain arrays; no comparison happens there;
* ``verdict(inputs, outputs)`` -- in the grading process again: recomputes the library's answer from its own copy of
  the inputs and compares it with the outputs, which arrive as a ``.npz`` file read without pickle, so that nothing
  the kernel made (a patched function, an object equal to everything) takes part. It returns the failures in words,
  without the expected values: they become the student's feedback.

Code in the kernel can still change what the kernel sends back, but not what it is compared with: to score, the
numbers must be right for inputs it had not seen. The notebook's hidden tests are one call, :func:`run_check`.
Under ``classroom grade`` (the folder :data:`EXCHANGE_ENV` is set) it only reads the inputs and writes the outputs;
anywhere else (the teacher's notebook run top to bottom, CI's nbmake) it runs all three parts in the notebook, on a
fixed seed, and raises ``AssertionError`` on a failure.

The checks of chapter NN are in ``chNN.py`` (its list ``CHECKS``); :func:`check` finds one by its exercise.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/classroom.py, notebooks/TEACHING.md).
"""

from __future__ import annotations

import contextlib
import importlib
import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

#: The environment variable that holds the folder where the grader puts each exercise's inputs and reads its outputs.
EXCHANGE_ENV = "VDTUTORIAL_CHECKS"
#: The seed of the inputs when a notebook checks itself (the teacher's edition run top to bottom).
SELF_CHECK_SEED = 0
#: The largest outputs file the grader reads (bytes): a check's outputs are a few MB at most.
MAX_OUTPUTS_BYTES = 256 << 20
#: The key under which a probe's outputs say that the student's code raised (the exception's type name).
RAISED = "__raised__"
#: The key under which a probe's outputs carry the line of a library stub the student's code called
#: (:mod:`vdtutorial.course.stubs`): the grader believes it only if its own table would write that line.
STUBBED = "__stubbed__"
#: The failure of a check whose tests cell sent nothing back: the cell raised before the hidden check ran.
NO_ANSWER = "the hidden check got no answer from your code (a cell before it failed, or the kernel stopped)"
_CHAPTERS = ("ch01", "ch02", "ch03", "ch04", "ch05", "ch06", "ch07", "ch08", "ch09", "ch10", "ch11")


@dataclass(frozen=True)
class Check:
    """The trusted check of one exercise (``exercise``: its answer cell's nbgrader ``grade_id``)."""

    exercise: str
    inputs: Callable[[np.random.Generator], dict]
    probe: Callable[[dict, dict], dict]
    verdict: Callable[[dict, dict], list]


def every_check() -> dict[str, Check]:
    """All checks, by exercise."""
    found = {}
    for name in _CHAPTERS:
        for item in importlib.import_module(f"{__name__}.{name}").CHECKS:
            found[item.exercise] = item
    return found


def check(exercise: str) -> Check:
    """The check of ``exercise`` (``KeyError`` naming it if there is none)."""
    module = importlib.import_module(f"{__name__}.{exercise.split('_')[0]}")
    for item in module.CHECKS:
        if item.exercise == exercise:
            return item
    raise KeyError(f"no trusted check for exercise {exercise!r}")


def plain(values: dict, prefix: str = "") -> dict[str, np.ndarray]:
    """``values`` (numbers, strings, arrays, tensors, nested dicts and lists of them) as flat plain numpy arrays,
    keys joined with ``/``; an object that is not a number raises ``TypeError`` (it cannot be sent back)."""
    flat = {}
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(plain(value, f"{name}/"))
            continue
        if hasattr(value, "detach"):  # a tensor (or a subclass of one): its numbers only
            value = value.detach().cpu().numpy()
        array = np.array(value)
        if array.dtype == object:
            raise TypeError(f"{name}: not plain numbers ({type(value).__name__})")
        flat[name] = array
    return flat


def nested(flat: dict) -> dict:
    """The inverse of :func:`plain`'s flattening: ``{"a/b": x}`` -> ``{"a": {"b": x}}``."""
    tree = {}
    for key, value in flat.items():
        *parents, leaf = key.split("/")
        node = tree
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return tree


def save(path: Path, values: dict) -> None:
    np.savez(path, **plain(values))


def load(path: Path) -> dict[str, np.ndarray]:
    """A ``.npz`` written by :func:`save`, read as plain arrays only (no pickle, no symbolic link, bounded size)."""
    info = os.lstat(path)
    if not stat.S_ISREG(info.st_mode) or info.st_size > MAX_OUTPUTS_BYTES:
        raise ValueError(f"{path.name} is not a plain file of at most {MAX_OUTPUTS_BYTES >> 20} MB")
    with np.load(path, allow_pickle=False) as data:
        return {key: data[key] for key in data.files}


def inputs_path(folder: Path, exercise: str) -> Path:
    return Path(folder) / f"{exercise}.inputs.npz"


def outputs_path(folder: Path, exercise: str) -> Path:
    return Path(folder) / f"{exercise}.outputs.npz"


def _stub_line(exc: BaseException) -> str | None:
    """The line of a library stub (:mod:`vdtutorial.course.stubs`) that raised ``exc`` or an exception it was
    raised while handling, or ``None``."""
    from vdtutorial.course import stubs

    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        line = stubs.called(str(exc))
        if line:
            return line
        exc = exc.__cause__ or exc.__context__
    return None


def _probe(item: Check, namespace: dict, inputs: dict) -> dict:
    try:
        return plain(item.probe(namespace, nested(inputs)))
    except Exception as exc:  # the student's code may raise anything: the verdict says it did, nothing more
        found = {RAISED: np.array(type(exc).__name__)}
        if line := _stub_line(exc):
            found[STUBBED] = np.array(line)
        return found


def run_check(exercise: str, namespace: dict) -> None:
    """The hidden tests of ``exercise``, called from its tests cell with the notebook's ``globals()``."""
    item = check(exercise)
    folder = os.environ.get(EXCHANGE_ENV)
    if folder:  # graded: the grader compares, in its own process
        save(outputs_path(folder, exercise), _probe(item, namespace, load(inputs_path(folder, exercise))))
        return
    inputs = plain(item.inputs(np.random.default_rng(SELF_CHECK_SEED)))
    failures = judge(item, inputs, _probe(item, namespace, inputs))
    assert not failures, f"{exercise}: " + "; ".join(failures)


def judge(item: Check, inputs: dict, outputs: dict | None) -> list[str]:
    """The failures of ``outputs`` (``None``: none arrived) against ``inputs``, in words for the student."""
    if outputs is None:
        return [NO_ANSWER]
    if STUBBED in outputs and (line := stubbed(str(outputs[STUBBED]))):
        return [f"your code called a stub: {line}"]
    if RAISED in outputs:
        return [f"your code raised {outputs[RAISED]} on the hidden check's inputs"]
    try:
        return list(item.verdict(nested(inputs), nested(outputs)))
    except Exception as exc:  # outputs of the wrong kind or shape: the verdict cannot read them
        return [f"your code's results could not be checked ({type(exc).__name__}: missing or of the wrong kind)"]


def stubbed(text: str) -> str | None:
    """The stub's line in ``text`` (a probe's report, or a failure of :func:`judge`) when the grader's own table
    (:func:`vdtutorial.course.stubs.targets`) would write it, else ``None``: why an exercise scored nothing that the
    teacher's table names."""
    from vdtutorial.course import stubs

    return stubs.called(text)


class Failures(list):
    """A verdict's list of failures, with the comparisons that add them. Messages say what is wrong, never the
    expected value."""

    def close(self, got, want, what: str, rtol: float = 1e-5, atol: float = 1e-8) -> bool:
        got, want = np.asarray(got, dtype=float), np.asarray(want, dtype=float)
        if got.shape != want.shape:
            self.append(f"{what}: wrong shape {got.shape}")
            return False
        if not np.allclose(got, want, rtol=rtol, atol=atol):
            self.append(f"{what}: differs from the reference")
            return False
        return True

    def equal(self, got, want, what: str) -> bool:
        got, want = np.asarray(got), np.asarray(want)
        if got.shape != want.shape or not np.array_equal(got, want):
            self.append(f"{what}: differs from the reference")
            return False
        return True

    def true(self, condition, what: str) -> bool:
        if not bool(np.all(np.asarray(condition))):
            self.append(what)
            return False
        return True


def failing(ok) -> str:
    """The indices of the cases that failed (``ok`` false there), at most five, for a message."""
    bad = np.flatnonzero(~np.asarray(ok, dtype=bool))
    return ", ".join(str(k) for k in bad[:5]) + (", ..." if len(bad) > 5 else "")


@contextlib.contextmanager
def swapped(namespace: dict, **values):
    """The notebook's globals ``values`` replaced while a probe runs (a stand-in for a function the exercise calls),
    and put back, or removed, after it."""
    saved = {name: namespace[name] for name in values if name in namespace}
    namespace.update(values)
    try:
        yield
    finally:
        for name in values:
            namespace.pop(name, None)
        namespace.update(saved)
