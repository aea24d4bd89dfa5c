"""The Pendulum-v1 comparison of our TRPO with sb3-contrib's (`python -m vdtutorial bench trpo`), on a
tiny budget: the table's rows and columns, and that its settings are the ones it names."""

import inspect

import numpy as np
import pytest

from vdtutorial.experiments.pendulum import (
    PENDULUM_CRITIC_CONFIG,
    PENDULUM_VARIANTS,
    ZOO_PENDULUM_CONFIG,
    ZOO_PENDULUM_NUM_ENVS,
    ZOO_PENDULUM_SB3,
    _late_mean_return,
    bench_trpo_pendulum,
    sb3_trpo_kwargs,
)

pytestmark = pytest.mark.pipeline  # a command, chapter or long run end to end: CI's lock leg only

OURS = [v.name for v in PENDULUM_VARIANTS if v.config is not None]


def check_table(results, names, seeds):
    assert list(results) == names
    for runs in results.values():
        assert set(runs) == {"final_return", "eval_return", "seconds", "cpu_seconds"}
        assert all(len(values) == len(seeds) for values in runs.values())
        # Pendulum's reward per step lies in [-16.3, 0]; 200 steps per episode
        assert all(-3300 < r <= 0 for r in runs["final_return"] + runs["eval_return"])
        assert all(s > 0 for s in runs["seconds"] + runs["cpu_seconds"])


def test_pendulum_table_without_sb3(capsys):
    results = bench_trpo_pendulum(seeds=(5,), total_steps=2048, with_sb3=False)
    check_table(results, OURS, (5,))
    out = capsys.readouterr().out
    assert "(c) ours, RL Zoo tuned, no gSDE" in out and "sb3-contrib, same" not in out


def test_pendulum_table_with_sb3(capsys):
    pytest.importorskip("sb3_contrib")
    results = bench_trpo_pendulum(seeds=(5,), total_steps=2048)
    check_table(results, [v.name for v in PENDULUM_VARIANTS], (5,))
    out = capsys.readouterr().out
    for variant in PENDULUM_VARIANTS:
        assert variant.label in out


def test_our_zoo_settings_are_sb3_contribs_defaults_with_the_zoo_entry():
    sb3_contrib = pytest.importorskip("sb3_contrib")
    defaults = {
        name: p.default
        for name, p in inspect.signature(sb3_contrib.TRPO.__init__).parameters.items()
        if p.default is not inspect.Parameter.empty
    }
    expected = {**defaults, **ZOO_PENDULUM_SB3}
    ours = sb3_trpo_kwargs(ZOO_PENDULUM_CONFIG, ZOO_PENDULUM_NUM_ENVS)
    assert ours.pop("policy_kwargs") == {"net_arch": {"pi": [64, 64], "vf": [64, 64]}}  # sb3's MlpPolicy default
    assert ours == {key: expected[key] for key in ours}
    assert ZOO_PENDULUM_CONFIG.bootstrap_time_limits and PENDULUM_CRITIC_CONFIG.bootstrap_time_limits


def test_final_return_counts_the_episodes_ending_in_the_last_tenth():
    # 2 sub-environments, 200-step episodes: episode k of each ends at global step 400 k
    per_env = [[-1000.0, -900.0, -800.0, -700.0, -600.0], [-1100.0, -1000.0, -900.0, -800.0, -500.0]]
    assert _late_mean_return(per_env, 2, 2000) == np.mean([-600.0, -500.0])  # the episodes ending at 2000 > 1800
    assert _late_mean_return(per_env, 2, 1700) == np.mean([-700.0, -600.0, -800.0, -500.0])  # ends 1600 and 2000 > 1530
