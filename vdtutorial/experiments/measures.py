"""What a point of a learning curve measures: the paper's metric and the two numbers it is made of.

The paper counts the successful trajectories of a 200-step iteration. Trajectories end on success, so that
count rises both when more trajectories succeed and when they succeed sooner: a policy that always succeeds
but slowly scores lower than one that always succeeds fast. Every row holds ``successes`` (trajectories that
ended in success), ``episodes`` (all trajectories that ended: success, failure or the 25-step horizon) and the
env steps of the iteration, so the count splits exactly into

* **success rate** = successes / episodes: does the arm get there?
* **steps per trajectory** = steps of the iteration / episodes: how long does a trajectory take?

and successes = success rate x steps of the iteration / steps per trajectory. Steps per trajectory counts the
steps of the trajectories still running when the iteration stops, which did not end and so are not in
``episodes``; it is therefore an upper bound on the mean length of the trajectories that ended. When nearly
every trajectory succeeds, as the pre-trained policies' do, it is the mean length of a successful trajectory
plus that cut-off share (the rows do not hold the lengths of the successful trajectories alone).

Taught in chapter 07.
"""

from __future__ import annotations

from dataclasses import dataclass

from vdtutorial.envs.base import HORIZON
from vdtutorial.experiments.evaluation import EPISODE_STEPS


@dataclass(frozen=True)
class Measure:
    """One quantity per iteration: its name (a row column or a derived one), axis label, the sign that means
    better (+1: higher is better) and the values it can take (a band is drawn only inside them)."""

    name: str
    label: str
    better: int
    feasible: tuple[float, float]
    question: str


#: Every measure a curve can show. Successes are counts, at least 0 and at most one per env step of the 200-step
#: iteration; a trajectory lasts 1 to HORIZON steps; returns are not clipped (their bounds depend on the task).
MEASURES = {
    "successes": Measure(
        "successes",
        "successful trajectories per 200-step episode",
        1,
        (0.0, float(EPISODE_STEPS)),
        "how many successful trajectories fit in 200 steps (the paper's metric)",
    ),
    "mean_return": Measure(
        "mean_return",
        "cumulative reward per trajectory",
        1,
        (float("-inf"), float("inf")),
        "the reward a trajectory collects (the paper's grasping metric)",
    ),
    "success_rate": Measure(
        "success_rate",
        "success rate (successes / trajectories)",
        1,
        (0.0, 1.0),
        "whether a trajectory gets there at all",
    ),
    "steps_per_trajectory": Measure(
        "steps_per_trajectory",
        "env steps per trajectory (200 / trajectories)",
        -1,
        (1.0, float(HORIZON)),
        "how fast a trajectory ends (fewer steps is better)",
    ),
}
#: The measures each experiment is judged on: its paper metric first, then the two the count is made of.
DERIVED = ("success_rate", "steps_per_trajectory")


def measures_of(metric: str) -> tuple[str, ...]:
    """The measures shown and tested for an experiment whose paper metric is ``metric``."""
    return (metric, *DERIVED)


def iteration_steps(row: dict) -> float:
    """The env steps a row covers: a TRPO iteration (every iteration has the same, so the cumulative
    ``env_steps`` over the iteration count), or the expert's 200-step evaluation episode."""
    if row.get("iteration") is None:
        return float(EPISODE_STEPS)
    return row["env_steps"] / (row["iteration"] + 1)


def value(row: dict, measure: str) -> float:
    """A row's value of ``measure``: a stored column, or one derived from ``successes``, ``episodes`` and the
    iteration's steps (NaN when no trajectory ended, which the 25-step horizon rules out in a 200-step
    iteration of 8 sub-environments)."""
    if measure not in DERIVED:
        return row[measure]
    episodes = row["episodes"]
    if not episodes:
        return float("nan")
    if measure == "success_rate":
        return row["successes"] / episodes
    return iteration_steps(row) / episodes
