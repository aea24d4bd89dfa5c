"""The learning-curve figure of Figs. 4-7."""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from vdtutorial.evaluation import EPISODE_STEPS
from vdtutorial.experiments.curves import CONFIDENCE, Curve, smooth_window

METRIC_LABELS = {"successes": "successful trajectories per 200-step episode",
                 "mean_return": "cumulative reward per trajectory"}
_COLOURS = {"vd": "tab:blue", "l2": "tab:orange", "none": "tab:gray", "expert": "black"}
_LINESTYLES = ("-", "--", ":", "-.")
#: The values a metric can take, so that a band (a t-interval, which knows nothing of them) is drawn only where a
#: mean could lie: successes are counts, at least 0 and at most one per env step of the 200-step episode (a
#: trajectory succeeds after one step at the earliest). Returns are not clipped: their bounds depend on the task.
FEASIBLE = {"successes": (0.0, float(EPISODE_STEPS))}


def draw_band(ax, steps, low, high, metric: str, colour: str) -> None:
    """Shade a curve's band, clipped to the metric's :data:`FEASIBLE` range."""
    floor, ceiling = FEASIBLE.get(metric, (-np.inf, np.inf))
    ax.fill_between(steps, np.clip(low, floor, ceiling), np.clip(high, floor, ceiling), color=colour, alpha=0.15,
                    linewidth=0)


def plot_curves(curves: dict[str, Curve], metric: str, title: str, window: int | None = None) -> Figure:
    """Mean (line) and 95% t-interval over seeds (shaded) of each smoothed curve against env steps; the
    expert as a horizontal dashed line with the interval of its mean over all its measured episodes (its seeds
    pooled, see ``curves_from_rows``). Bands are clipped to the metric's :data:`FEASIBLE` range. Curves of one
    method are told apart by line style. ``window``: the curves' smoothing, for the axis label (default
    :func:`smooth_window`). Uses ``matplotlib.figure.Figure`` directly (no pyplot state), so it is safe in worker
    processes and notebooks alike."""
    window = smooth_window() if window is None else window
    fig = Figure(figsize=(7, 4.5), layout="constrained")
    ax = fig.add_subplot()
    variants: dict[str, int] = {}
    for curve in curves.values():
        colour = _COLOURS[curve.method]
        if curve.method == "expert":
            ax.axhline(curve.mean[0], color=colour, linestyle="--",
                       label=f"{curve.label} ({curve.mean[0]:.1f}; band over its episodes, seeds pooled)")
            if np.isfinite(curve.low[0]):
                ax.axhspan(*np.clip([curve.low[0], curve.high[0]], *FEASIBLE.get(metric, (-np.inf, np.inf))),
                           color=colour, alpha=0.08)
            continue
        style = _LINESTYLES[variants.get(curve.method, 0) % len(_LINESTYLES)]
        variants[curve.method] = variants.get(curve.method, 0) + 1
        ax.plot(curve.steps, curve.mean, color=colour, linestyle=style, label=f"{curve.label} (n={curve.seeds})")
        if np.isfinite(curve.low).any():
            draw_band(ax, curve.steps, curve.low, curve.high, metric, colour)
    ax.set_xlabel(f"environment steps\n(trailing mean over {window} iterations = {window * EPISODE_STEPS} steps; "
                  f"band: {CONFIDENCE:.0%} t-interval of the mean over seeds,\nclipped to the metric's possible values)", fontsize=9)
    ax.set_ylabel(METRIC_LABELS[metric])
    ax.set_title(title)
    ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig

