"""Trusted checks of chapter 01's exercises: eq. 11's terms (1.1), the episode runner (1.2), the grasping reward (1.3).

The grader draws the states (cups, joint angles, actions, episode seeds, hand poses); the kernel puts its own
environment in each of them and returns what the student's function gave there; the grader puts the library's
environment in the same states and compares with what its ``step`` (eq. 11, the sparse grasping reward) and its
episodes say. Each process builds its pybullet environments once (:func:`environment`).

In the grading kernel both environments' goal tests and rewards are stubs (they are what 1.1 and 1.3 ask for), so
no live ``step`` can run there: the runner of 1.2 is given the grader's own episodes, played back (:class:`Replay`).

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/checks/__init__.py).
"""

from __future__ import annotations

from functools import lru_cache
from types import SimpleNamespace
from typing import Callable

import gymnasium as gym
import numpy as np

from vdtutorial.course.checks import Check, Failures, failing
from vdtutorial.envs import ENV_IDS
from vdtutorial.envs.base import MAX_DELTA
from vdtutorial.envs.grasp import POSITION_TOLERANCE, JacoGraspEnv, grasp_point
from vdtutorial.envs.reach import C_FAILURE, C_SUCCESS
from vdtutorial.envs.scene import CUP_REGION_HIGH, CUP_REGION_LOW, HOME
from vdtutorial.expert import IKExpert, grasp_targets, reach_targets, solution_set, solve_ik

#: Eq. 11's terms, under the keys Exercise 1.1 asks for.
TERMS = ("-|a|", "-d_t", "+c1 succ", "-c2 fail")
#: How an episode ends, under the keys Exercise 1.2 asks for.
OUTCOMES = ("success", "failure", "truncated")
#: An action that folds joint 3 into the table at once: a collision at the first step, from home.
DOWN = np.array([0.0, 0.0, -MAX_DELTA, 0.0, 0.0, 0.0])
#: The joints with end stops (2, 3 and 5): the joint limits clip them.
LIMITED = (1, 2, 4)


@lru_cache(maxsize=None)
def environment(task: str, owner: str) -> gym.Env:
    """A state-mode environment of ``task`` ("reach" or "grasp") for ``owner`` ("probe" or "grader"), made once per
    process: when a notebook checks itself both parts run in one process, and the student's code must not touch the
    grader's scene."""
    return gym.make(ENV_IDS[task], obs_mode="state")


def _cup(rng) -> np.ndarray:
    return rng.uniform(CUP_REGION_LOW, CUP_REGION_HIGH)


def episode(env: gym.Env, act: Callable, seed: int) -> dict:
    """One episode in the grader's ``env`` from ``env.reset(seed=seed)``, each action ``act(obs)``, as
    :class:`Replay` plays it back: the cup, the joint angles, observations and info after the reset and each step
    (index 0: the reset), and the actions, rewards and ends of the steps."""
    obs, info = env.reset(seed=int(seed))
    base = env.unwrapped
    found = {"joints": [base.joints], "obs": [obs], "infos": [info], "action": [], "reward": []}
    found.update(cup_xy=base.cup_position[:2], terminated=[], truncated=[])
    done = False
    while not done:
        action = np.asarray(act(obs), dtype=np.float64)
        obs, reward, terminated, truncated, info = env.step(action)
        for key, value in zip(
            ("joints", "obs", "infos", "action", "reward", "terminated", "truncated"),
            (base.joints, obs, info, action, reward, terminated, truncated),
        ):
            found[key].append(value)
        done = terminated or truncated
    infos = found.pop("infos")
    found["info"] = {key: np.array([i[key] for i in infos]) for key in infos[-1]}
    return {key: value if isinstance(value, dict) else np.array(value) for key, value in found.items()}


class Replay(gym.Wrapper):
    """The grader's episodes (:func:`episode`, by seed), played back as the environment a runner exercise is given.

    The environment's goal test and reward are stubs in the grading kernel, so a live ``step`` cannot run there;
    what a runner computes -- how an episode ends, its length, its return -- is a function of what ``reset`` and
    ``step`` return, which the grader computed. ``reset(seed=s)`` starts the episode of seed ``s`` (another seed
    is not one the grader played); each ``step`` returns that episode's next transition and puts the kernel's scene
    in its state (the cup at the reset, the joint angles after each step), so that a policy which reads the scene,
    such as the IK expert, sees the state it would see live. The episode does not depend on the actions: they are
    kept in :attr:`actions` for the verdict to compare with the ones that made it."""

    def __init__(self, env: gym.Env, episodes: dict):
        super().__init__(env)
        self.episodes, self.actions, self._episode, self._t = episodes, [], None, 0

    def reset(self, *, seed=None, options=None):
        if seed is None or str(int(seed)) not in self.episodes:
            raise ValueError(f"this check's episodes start from env.reset(seed=s) for its seeds, not seed={seed!r}")
        self._episode, self._t = self.episodes[str(int(seed))], 0
        self.env.unwrapped.set_state(self._episode["joints"][0], self._episode["cup_xy"])
        return self._transition(0)

    def step(self, action):
        self.env.unwrapped.check_action(action)  # the same ValueError as the live environment for a malformed action
        self.actions.append(np.asarray(action, dtype=np.float64))
        if self._episode is None or self._t >= len(self._episode["reward"]):
            raise RuntimeError("env.step after the episode ended, or before env.reset")
        self._t += 1
        self.env.unwrapped.scene.set_joints(self._episode["joints"][self._t])
        return self._transition(self._t)

    def _transition(self, t: int) -> tuple:
        found = self._episode
        info = {key: value[t].item() for key, value in found["info"].items()}
        obs = found["obs"][t].copy()
        if t == 0:
            return obs, info
        return (
            obs,
            float(found["reward"][t - 1]),
            bool(found["terminated"][t - 1]),
            bool(found["truncated"][t - 1]),
            info,
        )


# -- Exercise 1.1: eq. 11 from the scene -------------------------------------------------------------------------
def reward_inputs(rng: np.random.Generator) -> dict:
    """Three cups, each with ten steps: two small steps that end in a goal configuration (successes), one that folds
    the arm into the table (a failure), one pushed past a joint limit, six random ones from around home."""
    scene = environment("reach", "grader").unwrapped.scene
    lower, upper = scene.lower, scene.upper
    cups, qs, actions = [], [], []
    while len(cups) < 30:
        cup = _cup(rng)
        scene.set_cup(cup)
        goals = solution_set(scene, reach_targets(scene.cup_position))
        if len(goals) == 0:
            continue
        for g in goals[rng.integers(len(goals), size=2)]:
            a = rng.uniform(-0.05, 0.05, 6)
            qs.append(g - a)
            actions.append(a)
        qs.append(HOME.copy())
        actions.append(DOWN)
        q, a, i = rng.uniform(lower, upper), rng.uniform(-MAX_DELTA, MAX_DELTA, 6), rng.choice(LIMITED)
        side = rng.choice([-1, 1])
        q[i] = (upper[i] if side > 0 else lower[i]) - side * rng.uniform(0, 0.1)
        a[i] = side * MAX_DELTA
        qs.append(q)
        actions.append(a)
        for _ in range(6):
            qs.append(np.clip(HOME + rng.uniform(-1.5, 1.5, 6), lower, upper))
            actions.append(rng.uniform(-MAX_DELTA, MAX_DELTA, 6))
        cups += [cup] * 10
    return {"cup_xy": np.array(cups), "q": np.array(qs), "action": np.array(actions)}


def reward_probe(namespace: dict, inputs: dict) -> dict:
    base = environment("reach", "probe").unwrapped
    keys, terms, joints, hands = [], [], [], []
    for cup_xy, q, action in zip(inputs["cup_xy"], inputs["q"], inputs["action"]):
        base.set_state(q, cup_xy)
        got = namespace["eq11_terms"](base.scene, q.copy(), action.copy())
        keys.append(set(got) == set(TERMS))
        terms.append([float(got[k]) if k in got else np.nan for k in TERMS])
        joints.append(base.scene.joints.copy())
        hands.append(base.scene.tcp_pose()[0])
    return {"keys": keys, "terms": terms, "joints": joints, "hand": hands}


def reward_reference(inputs: dict) -> dict:
    """The library's terms of eq. 11 (the reaching env's ``step``), the joint angles and the hand after each step."""
    base = environment("reach", "grader").unwrapped
    terms, joints, hands = [], [], []
    for cup_xy, q, action in zip(inputs["cup_xy"], inputs["q"], inputs["action"]):
        base.set_state(q, cup_xy)
        _, _, _, _, info = base.step(action)
        terms.append(
            [
                -np.linalg.norm(base.check_action(action)),
                -info["distance"],
                C_SUCCESS * info["is_success"],
                -C_FAILURE * info["is_failure"],
            ]
        )
        joints.append(base.scene.joints.copy())
        hands.append(base.scene.tcp_pose()[0])
    return {"terms": np.array(terms), "joints": np.array(joints), "hand": np.array(hands)}


def reward_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    want = reward_reference(inputs)
    n = len(inputs["q"])
    if not failures.true(
        np.shape(outputs["terms"]) == (n, len(TERMS)) and np.shape(outputs["keys"]) == (n,),
        "eq11_terms must return one dict of the four terms per step (case)",
    ):
        return failures
    failures.true(
        outputs["keys"],
        f"cases {failing(outputs['keys'])}: return the four terms of eq. 11 under the keys "
        + ", ".join(repr(k) for k in TERMS),
    )
    for k, (term, meaning) in enumerate(
        zip(
            TERMS,
            (
                "minus the action's length",
                "minus the hand centre's distance from the goal point after the move",
                "the success bonus",
                "the collision penalty, for a collision anywhere on the way",
            ),
        )
    ):
        ok = np.isclose(np.asarray(outputs["terms"], dtype=float)[:, k], want["terms"][:, k], rtol=0, atol=1e-9)
        failures.true(ok, f"cases {failing(ok)}: {term} ({meaning}) differs from the environment's")
    ok = np.isclose(np.asarray(outputs["joints"], dtype=float), want["joints"], rtol=0, atol=1e-9).all(
        axis=1
    ) & np.isclose(np.asarray(outputs["hand"], dtype=float), want["hand"], rtol=0, atol=1e-9).all(axis=1)
    failures.true(ok, f"cases {failing(ok)}: leave the arm at the new joint angles, within the joint limits")
    return failures


# -- Exercise 1.2: an episode runner ------------------------------------------------------------------------------
#: The policies the runner is checked with, and how many episodes each runs.
POLICIES = {"still": 1, "down": 2, "wide": 6, "narrow": 3, "expert": 4}
_NAMES = {
    "still": "the policy that stands still",
    "down": "the policy that collides at once",
    "wide": "random actions over the whole range",
    "narrow": "small random actions",
    "expert": "the IK expert",
}


class ExpertPolicy:
    """The IK expert as a policy of the observation (joints, then the cup): a new goal set whenever the cup moves."""

    def __init__(self, env):
        self.expert, self.cup = IKExpert(env), None

    def __call__(self, obs):
        obs = np.asarray(obs, dtype=float)
        if self.cup is None or not np.allclose(obs[6:], self.cup):
            self.expert.reset()
            self.cup = obs[6:].copy()
        return self.expert.action(obs[:6])


class Recorded:
    """A policy that keeps every observation it is asked about: the grader sees which ones the runner passed."""

    def __init__(self, policy):
        self.policy, self.seen = policy, []

    def __call__(self, obs):
        self.seen.append(np.asarray(obs, dtype=float))
        return self.policy(obs)


def policy(name: str, env, seed: int) -> Recorded:
    """The policy ``name`` of :data:`POLICIES` (random ones drawn from ``seed``), recorded."""
    if name == "expert":
        return Recorded(ExpertPolicy(env))
    if name in ("still", "down"):
        action = np.zeros(6) if name == "still" else DOWN
        return Recorded(lambda obs: action)
    rng, scale = np.random.default_rng(seed), MAX_DELTA if name == "wide" else 0.1
    return Recorded(lambda obs: rng.uniform(-scale, scale, 6))


def runner_inputs(rng: np.random.Generator) -> dict:
    """Distinct episode seeds for each policy of :data:`POLICIES`, the random policies' seed, and each policy's
    episodes in the grader's environment (:func:`episode`), which the kernel plays back (:class:`Replay`)."""
    seeds = rng.choice(2**31, size=sum(POLICIES.values()), replace=False)
    ends = np.cumsum(list(POLICIES.values()))
    found = {
        "seeds": {name: seeds[end - n : end] for (name, n), end in zip(POLICIES.items(), ends)},
        "policy_seed": int(rng.integers(2**31)),
    }
    env, found["episodes"] = environment("reach", "grader"), {}
    for name in POLICIES:
        act = policy(name, env, found["policy_seed"])
        found["episodes"][name] = {str(int(seed)): episode(env, act, seed) for seed in found["seeds"][name]}
    return found


def runner_probe(namespace: dict, inputs: dict) -> dict:
    out = {}
    for name in POLICIES:
        env = Replay(environment("reach", "probe"), inputs["episodes"][name])
        recorded = policy(name, env, int(inputs["policy_seed"]))
        outcomes, lengths = namespace["run_episodes"](env, recorded, [int(s) for s in inputs["seeds"][name]])
        outcomes = dict(outcomes)
        out[name] = {
            "keys": set(outcomes) == set(OUTCOMES),
            "counts": [int(outcomes.get(k, -1)) for k in OUTCOMES],
            "lengths": [int(n) for n in lengths],
            "seen": np.array(recorded.seen).reshape(-1, 9),
            "actions": np.array(env.actions).reshape(-1, 6),
        }
    return out


def runner_reference(inputs: dict) -> dict:
    """Each policy's episodes as the grader played them: how they ended, their lengths, what the policy saw (every
    observation but the last of each episode) and the actions that made them."""
    out = {}
    for name in POLICIES:
        played = [inputs["episodes"][name][str(int(seed))] for seed in inputs["seeds"][name]]
        counts = dict.fromkeys(OUTCOMES, 0)
        for one in played:
            success, failure = bool(one["info"]["is_success"][-1]), bool(one["info"]["is_failure"][-1])
            counts["success" if success else "failure" if failure else "truncated"] += 1
        out[name] = {
            "counts": [counts[k] for k in OUTCOMES],
            "lengths": [len(one["reward"]) for one in played],
            "seen": np.concatenate([one["obs"][:-1] for one in played]),
            "actions": np.concatenate([one["action"] for one in played]),
        }
    return out


def runner_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    want = runner_reference(inputs)
    for name in POLICIES:
        got, where = outputs[name], _NAMES[name]
        failures.true(
            got["keys"],
            f"{where}: the outcomes dict must have the keys 'success', 'failure' and "
            "'truncated' (zeros included), nothing else",
        )
        failures.equal(got["counts"], want[name]["counts"], f"{where}: the counts of how the episodes ended")
        failures.equal(got["lengths"], want[name]["lengths"], f"{where}: the episodes' lengths in steps")
        same = [
            np.shape(got[key]) == want[name][key].shape
            and np.allclose(np.asarray(got[key], dtype=float), want[name][key], rtol=0, atol=1e-6)
            for key in ("seen", "actions")
        ]
        failures.true(
            all(same),
            f"{where}: one episode per seed, on that seed's cup, each action policy(obs) from the latest "
            "observation, once per step and passed to env.step, until the episode ends",
        )
    return failures


# -- Exercise 1.3: the grasping task's reward and its end ----------------------------------------------------------
class Pose:
    """A scene that only answers ``tcp_pose()`` and ``cup_position``: a hand pose anywhere, without an arm."""

    def __init__(self, tcp, approach, cup):
        self._pose, self.cup_position = (np.asarray(tcp), np.asarray(approach)), np.asarray(cup)

    def tcp_pose(self):
        return self._pose


def grasp_inputs(rng: np.random.Generator) -> dict:
    """300 hand poses around the grasp point (about a tenth of them successes), and arm states in the grasping
    scene: home (with and without a collision), for three cups two grasp configurations found by IK, the same moved
    a little and a random one, each with a collision flag drawn at random."""
    n = 300
    cups = np.column_stack([rng.uniform(CUP_REGION_LOW, CUP_REGION_HIGH, (n, 2)), np.zeros(n)])
    axes = rng.normal(size=(n, 3)) * np.array([1.0, 1.0, 0.3])
    tcp = np.array([grasp_point(cup) for cup in cups]) + rng.normal(0, POSITION_TOLERANCE, (n, 3))
    poses = {
        "cup": cups,
        "tcp": tcp,
        "approach": axes / np.linalg.norm(axes, axis=1, keepdims=True),
        "failure": rng.integers(2, size=n),
    }
    scene = environment("grasp", "grader").unwrapped.scene
    cups, qs, flags = [_cup(rng)] * 2, [HOME, HOME], [0, 1]
    while len(qs) < 17:
        scene.set_cup(_cup(rng))
        found = [
            solve_ik(scene, grasp_point(scene.cup_position), orientation, HOME)
            for _, orientation in grasp_targets(scene.cup_position, standoff=0.0)
        ]
        found = [q for q in found if q is not None][:2]
        if len(found) < 2:
            continue
        for q in found + [q + rng.normal(0, 0.02, 6) for q in found] + [HOME + rng.uniform(-1, 1, 6)]:
            cups.append(scene.cup_position[:2])
            qs.append(q)
            flags.append(int(rng.integers(2)))
    return {"poses": poses, "states": {"cup_xy": np.array(cups), "q": np.array(qs), "failure": np.array(flags)}}


def grasp_probe(namespace: dict, inputs: dict) -> dict:
    poses, states = inputs["poses"], inputs["states"]
    results = [
        namespace["grasp_outcome"](Pose(*case[:3]), bool(case[3]))
        for case in zip(poses["tcp"], poses["approach"], poses["cup"], poses["failure"])
    ]
    out = {"poses": results, "states": []}
    base = environment("grasp", "probe").unwrapped
    for q, cup_xy, flag in zip(states["q"], states["cup_xy"], states["failure"]):
        base.set_state(q, cup_xy)
        out["states"].append(namespace["grasp_outcome"](base.scene, bool(flag)))
    return {
        key: {"reward": [float(r) for r, _ in rows], "terminated": [bool(t) for _, t in rows]}
        for key, rows in out.items()
    }


def _outcome(env, failure: bool) -> tuple[float, bool]:
    """The library's (reward, terminated) after a step that collided or not, as ``JacoEnv.step`` makes them."""
    success, info = JacoGraspEnv._goal_status(env)
    success = success and not failure
    return JacoGraspEnv._reward(env, None, success, failure, info), success or failure


def grasp_verdict(inputs: dict, outputs: dict) -> list[str]:
    failures = Failures()
    poses, states = inputs["poses"], inputs["states"]
    base = environment("grasp", "grader").unwrapped
    want = {
        "poses": [
            _outcome(SimpleNamespace(scene=Pose(*case[:3])), bool(case[3]))
            for case in zip(poses["tcp"], poses["approach"], poses["cup"], poses["failure"])
        ],
        "states": [],
    }
    for q, cup_xy, flag in zip(states["q"], states["cup_xy"], states["failure"]):
        base.set_state(q, cup_xy)
        want["states"].append(_outcome(base, bool(flag)))
    for key, where in (("poses", "hand poses"), ("states", "arm states in the grasping scene")):
        reward, ended = np.array(want[key], dtype=float).T
        got_reward, got_ended = np.asarray(outputs[key]["reward"], float), np.asarray(outputs[key]["terminated"])
        if not failures.true(
            got_reward.shape == reward.shape and got_ended.shape == ended.shape, f"{where}: return (reward, terminated)"
        ):
            continue
        ok = np.isclose(got_reward, reward, rtol=0, atol=1e-9)
        failures.true(ok, f"{where} {failing(ok)}: the reward differs from the grasping task's")
        ok = got_ended == ended.astype(bool)
        failures.true(ok, f"{where} {failing(ok)}: whether the episode ends differs from the grasping task's")
    return failures


CHECKS = [
    Check("ch01_reward_eq11", reward_inputs, reward_probe, reward_verdict),
    Check("ch01_collision_share", runner_inputs, runner_probe, runner_verdict),
    Check("ch01_grasp_reward", grasp_inputs, grasp_probe, grasp_verdict),
]
