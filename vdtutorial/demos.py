"""Expert demonstrations: the rollouts of eqs. 5-8 and the data set D.

Each trajectory starts from p0 (eq. 5: arm at home, cup uniform on the table), the arm executes the
expert's action plus Gaussian noise of standard deviation Sigma radians per joint (eq. 6), the scene
moves (eq. 7), and every visited state is paired with the *noiseless* expert action (eq. 8). The noise
spreads the visited states around the expert's path, so the cloned policy sees how to come back when
it drifts; the labels stay the expert's own decisions.

A data set stores low-dimensional states (6 joint angles + cup position) and actions, not images: an
RGBD observation is a deterministic function of the state (the camera is fixed), so
:meth:`Demos.observations` re-renders it on demand, and ``data/`` stays small.

Files are zip archives of ``.npy`` arrays plus a JSON metadata record, written with fixed timestamps
(same seed -> byte-identical file) and atomically (written aside, then renamed).

Taught in chapter 03.
"""

from __future__ import annotations

import io
import json
import os
import re
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
import pybullet
from tqdm.auto import tqdm

import vdtutorial
from vdtutorial.envs import ENV_IDS
from vdtutorial.expert import IKExpert
from vdtutorial.settings import data_dir

FORMAT_VERSION = 1
#: Sigma of each task's shipped data sets. Reaching: the paper's 0.5 (Figs. 4, 5; Fig. 6 adds 0.25 and 0.05).
#: Grasping: the paper gives none; ours is the largest Sigma on a grid at which the noisy expert still succeeds
#: in at least 30% of episodes (docs/results.md, "Measurements behind the code").
SHIPPED_NOISE = {"reach": 0.5, "grasp": 0.03}
ARRAYS = ("joints", "cup", "actions", "episode", "t")
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)


class DemoFileError(ValueError):
    """A demonstrations file is missing, unreadable or not the one that was asked for."""


def demo_command(task: str, samples: int, noise: float, seed: int) -> str:
    """The command line that (re)generates a data set."""
    return f"python -m vdtutorial demos --task {task} --samples {samples} --noise {noise:g} --seed {seed}"


def data_set_name(task: str, samples: int, noise: float) -> str:
    """The data set's part of a file name, ``TASK_nSAMPLES_sigmaSIGMA``: a demonstrations file adds its seed
    (:func:`demo_path`), a checkpoint cloned from it adds its own settings
    (``experiments.checkpoints.checkpoint_path``)."""
    return f"{task}_n{samples}_sigma{noise:g}"


#: :func:`data_set_name` read back (groups ``task``, ``samples``, ``noise``): the start of both file-name patterns.
DATA_SET_PATTERN = r"(?P<task>[a-z]+)_n(?P<samples>\d+)_sigma(?P<noise>[0-9.e-]+)"


def demo_path(task: str, samples: int, noise: float, seed: int = 0, root: Path | None = None) -> Path:
    """Conventional file name of a data set under ``data/demos``."""
    return Path(root or data_dir()) / "demos" / f"{data_set_name(task, samples, noise)}_seed{seed}.npz"


@dataclass
class Demos:
    """The data set D of eq. 8: states (joints, cup position), noiseless expert actions, and where each
    sample comes from (episode index, time step). ``meta`` records how it was made."""

    joints: np.ndarray
    cup: np.ndarray
    actions: np.ndarray
    episode: np.ndarray
    t: np.ndarray
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.actions)

    @property
    def states(self) -> np.ndarray:
        """State observations as the envs give them with ``obs_mode="state"``: joints then cup position."""
        return np.concatenate([self.joints, self.cup], axis=1).astype(np.float32)

    def observations(self, env: gym.Env, indices=None, depth_dtype=np.float32, progress: bool = False):
        """Re-render the ``rgbd`` observations of the given samples in ``env`` (same task, ``obs_mode="rgbd"``)
        as one batch (a dict of arrays). ``depth_dtype``: float16 halves the memory of a data set's depth."""
        base = env.unwrapped
        idx = np.arange(len(self)) if indices is None else np.asarray(indices)
        batch = {}
        for k, i in enumerate(tqdm(idx, desc="rendering demonstration images", disable=not progress)):
            for key, value in base.observation_at(self.joints[i], self.cup[i, :2]).items():
                dtype = depth_dtype if key == "depth" else np.asarray(value).dtype
                batch.setdefault(key, np.empty((len(idx), *np.shape(value)), dtype))[k] = value
        return batch

    # -- files ---------------------------------------------------------------------------------------
    def save(self, path) -> Path:
        """Write atomically and reproducibly (fixed zip timestamps, sorted metadata)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            for name in ARRAYS:
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.ascontiguousarray(getattr(self, name)), allow_pickle=False)
                zf.writestr(zipfile.ZipInfo(f"{name}.npy", _ZIP_TIME), buf.getvalue(), zipfile.ZIP_DEFLATED)
            zf.writestr(
                zipfile.ZipInfo("meta.json", _ZIP_TIME),
                json.dumps(self.meta, sort_keys=True, indent=1),
                zipfile.ZIP_DEFLATED,
            )
        os.replace(tmp, path)
        return path

    @classmethod
    def load(cls, path, **expected) -> "Demos":
        """Load a data set; ``expected`` metadata (e.g. ``task="reach", noise=0.5``) must match.

        Raises :class:`DemoFileError` naming the file and the command that regenerates it when the
        file is missing, corrupt, of another format version, or not what was expected."""
        path = Path(path)
        hint = _regenerate_hint(path, expected)
        if not path.exists():
            raise DemoFileError(f"demonstrations file {path} does not exist. {hint}")
        try:
            with zipfile.ZipFile(path) as zf:
                meta = json.loads(zf.read("meta.json"))
                arrays = {
                    n: np.lib.format.read_array(io.BytesIO(zf.read(f"{n}.npy")), allow_pickle=False) for n in ARRAYS
                }
        except (zipfile.BadZipFile, KeyError, ValueError, OSError, EOFError) as exc:
            raise DemoFileError(
                f"demonstrations file {path} is corrupt or not a demonstrations file ({exc}). {hint}"
            ) from exc
        if meta.get("format_version") != FORMAT_VERSION:
            raise DemoFileError(
                f"demonstrations file {path} has format version {meta.get('format_version')}, "
                f"this package reads version {FORMAT_VERSION}. {_regenerate_hint(path, meta)}"
            )
        for key, want in expected.items():
            if meta.get(key) != want:
                raise DemoFileError(
                    f"demonstrations file {path} has {key}={meta.get(key)!r}, expected {want!r}. "
                    f"{_regenerate_hint(path, {**meta, **expected})}"
                )
        n = len(arrays["actions"])
        if n != meta.get("samples") or any(len(a) != n for a in arrays.values()):
            raise DemoFileError(
                f"demonstrations file {path} is inconsistent (array lengths vs samples={meta.get('samples')}). {hint}"
            )
        return cls(meta=meta, **arrays)


#: The conventional file name of :func:`demo_path`, read back to fill in a regenerate hint.
_NAME = re.compile(DATA_SET_PATTERN + r"_seed(?P<seed>\d+)\.npz")


def _regenerate_hint(path: Path, meta: dict) -> str:
    """The command that makes ``path`` again, with the task, size, Sigma and seed of the file's metadata or the
    caller's expectations, else of the conventional file name."""
    keys = ("task", "samples", "noise", "seed")
    values = dict(meta)
    match = _NAME.fullmatch(path.name)
    if match and not all(k in values for k in keys):
        parsed = {
            "task": match["task"],
            "samples": int(match["samples"]),
            "noise": float(match["noise"]),
            "seed": int(match["seed"]),
        }
        values = {**parsed, **{k: v for k, v in values.items() if k in keys}}
    if all(k in values for k in keys) and values["task"] in ENV_IDS:
        return f"Regenerate it with: {demo_command(*(values[k] for k in keys))} --out {path}"
    return (
        "Make it with: python -m vdtutorial demos --task {reach,grasp} --samples N --noise SIGMA --seed SEED "
        f"--out {path}"
    )


def generate_demos(
    task: str = "reach", samples: int = 8000, noise: float = 0.5, seed: int = 0, progress: bool = True
) -> Demos:
    """Roll out the noisy expert (eqs. 5-7) until ``samples`` state-action pairs (eq. 8) are collected.

    Parameters
    ----------
    task: ``"reach"`` or ``"grasp"``.
    samples: size of D, in state-action pairs (the paper's 2000, 4000, 8000).
    noise: Sigma, the standard deviation (radians, every joint) of the noise added to the executed
        action (eq. 6); the stored label is the noiseless expert action (eq. 8).
    seed: seeds the cup positions and the noise; same seed -> identical data set.
    """
    if not np.isfinite(noise) or noise < 0:
        raise ValueError(f"noise (Sigma) must be a finite standard deviation >= 0, got {noise!r}")
    demos, record = collect(
        task,
        samples,
        seed,
        lambda state, a_exp, rng: a_exp + rng.normal(0.0, noise, size=a_exp.shape),
        progress,
        f"{task} demos (Sigma={noise:g})",
    )
    demos.meta = {
        "format_version": FORMAT_VERSION,
        "task": task,
        "samples": int(samples),
        "noise": float(noise),
        "seed": int(seed),
        "episodes": record["episodes"],
        "noisy_success_rate": success_rate(record),
        "env_id": ENV_IDS[task],
        "image_size": record["image_size"],
        "vdtutorial": vdtutorial.__version__,
        "gymnasium": gym.__version__,
        "pybullet": pybullet.getAPIVersion(),
        "command": demo_command(task, samples, noise, seed),
    }
    return demos


def success_rate(record: dict) -> float:
    """The fraction of the finished episodes of a :func:`collect` record that succeeded (NaN if none finished)."""
    return record["successes"] / record["finished"] if record["finished"] else float("nan")


def collect(task: str, samples: int, seed: int, behaviour, progress: bool = False, desc: str = "rollouts"):
    """Roll out ``behaviour`` until ``samples`` states are visited, labelling each with the noiseless expert.

    The loop of eqs. 5-8 with the executed action left open, so that every way of visiting states
    (the noisy expert of eq. 6, DART's learned noise, DAgger's mixture of expert and learner) shares one
    rollout and one labelling: ``behaviour(state, a_exp, rng)`` returns the action executed in the
    state (the env's ``obs_mode="state"`` vector) whose expert label is ``a_exp``; ``rng`` is the
    generator seeded by ``seed`` that also draws the cups.

    Returns the data set (``meta`` empty: the caller says how it was made) and a record of the rollout:
    ``episodes`` (in the data set), ``finished`` (those that ended: the last one is cut off when the data set is
    full, and has neither succeeded nor failed), ``successes`` (among the finished), ``expert_queries`` (labels
    asked of the expert, one per state) and ``expert_seconds`` (wall time spent in the expert: building G per
    episode and eq. 10 per state). :func:`success_rate` divides the two counts.
    """
    if task not in ENV_IDS:
        raise ValueError(f"task must be one of {sorted(ENV_IDS)}, got {task!r}")
    if int(samples) != samples or samples < 1:
        raise ValueError(f"samples must be a positive integer, got {samples!r}")
    rng = np.random.default_rng(seed)
    env = gym.make(ENV_IDS[task], obs_mode="state")
    expert = IKExpert(env)
    rows = {name: [] for name in ARRAYS}
    episodes = finished = successes = 0
    expert_seconds = 0.0
    bar = tqdm(total=samples, desc=desc, disable=not progress, unit="sample")
    n = 0
    try:
        while n < samples:
            env.reset(seed=int(rng.integers(2**31 - 1)))
            start = time.perf_counter()
            expert.reset()
            expert_seconds += time.perf_counter() - start
            for t in range(10**6):
                base = env.unwrapped
                start = time.perf_counter()
                a_exp = expert.action()
                expert_seconds += time.perf_counter() - start
                rows["joints"].append(base.joints)
                rows["cup"].append(base.cup_position)
                rows["actions"].append(a_exp)
                rows["episode"].append(episodes)
                rows["t"].append(t)
                n += 1
                bar.update(1)
                state = np.concatenate([base.joints, base.cup_position]).astype(np.float32)
                _, _, terminated, truncated, info = env.step(behaviour(state, a_exp, rng))
                if terminated or truncated or n >= samples:
                    break
            ended = terminated or truncated
            finished += ended
            successes += ended and bool(info["is_success"])
            episodes += 1
    finally:
        bar.close()
        env.close()
    record = {
        "episodes": episodes,
        "finished": finished,
        "successes": successes,
        "expert_queries": n,
        "expert_seconds": expert_seconds,
        "image_size": env.unwrapped.scene.image_size,
    }
    dtypes = {"joints": np.float32, "cup": np.float32, "actions": np.float32, "episode": np.int32, "t": np.int16}
    return Demos(**{k: np.asarray(v, dtype=dtypes[k]) for k, v in rows.items()}), record
