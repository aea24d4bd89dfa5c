"""The learning-curve figure of Figs. 4-7: one panel per measure, each seed thin behind the mean. Taught in chapter
07."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from PIL import Image

from vdtutorial.experiments.evaluation import EPISODE_STEPS
from vdtutorial.experiments.curves import CONFIDENCE, Curve, smooth_window
from vdtutorial.experiments.measures import MEASURES
from vdtutorial.methods import method

METRIC_LABELS = {name: measure.label for name, measure in MEASURES.items()}
_LINESTYLES = ("-", "--", ":", "-.", (0, (5, 1)), (0, (3, 1, 1, 1, 1, 1)), (0, (1, 3)), (0, (8, 3, 2, 3)))


def figure_title(
    base: str, obs_mode: str, total_steps: int, seeds: int | str, fvp_subsample: float = 1.0, demo_seed: int = 0
) -> str:
    """A figure's title that tells its variants apart: the paper's figure (``base``), the observation, the
    budget, the seeds (a range, "10 to 23", when the curves have different numbers), a draw of the demonstrations
    other than the shipped seed 0, and, for the control with the
    subsampled Fisher, that it is that control."""
    observation = {"state": "state input", "rgbd": "RGBD images"}[obs_mode]
    control = "" if fvp_subsample == 1.0 else f"\ncontrol: Fisher-vector products on {fvp_subsample:.0%} of each batch"
    budget = f"{total_steps:.2g}".replace("e+0", "e")
    draw = f", demonstrations of seed {demo_seed}" if demo_seed else ""
    return f"{base}\n{observation}, {budget} env steps per run, {seeds} seeds{draw}{control}"


def band_limits(low, high, metric: str) -> tuple[np.ndarray, np.ndarray]:
    """A band clipped to the values ``metric`` can take (a t-interval knows nothing of them)."""
    floor, ceiling = MEASURES[metric].feasible
    return np.clip(low, floor, ceiling), np.clip(high, floor, ceiling)


def draw_band(ax, steps, low, high, metric: str, colour: str) -> None:
    """Shade a curve's band, clipped to the metric's feasible range (:func:`band_limits`)."""
    ax.fill_between(steps, *band_limits(low, high, metric), color=colour, alpha=0.15, linewidth=0)


def _draw_panel(ax, curves: dict[str, Curve], metric: str, legend: bool) -> None:
    """One measure's curves on ``ax``: per seed thin, mean and clipped band over seeds, the expert flat."""
    variants: dict[str, int] = {}
    for curve in curves.values():
        entry = method(curve.method)
        colour = entry.colour
        if not entry.finetuned:
            ax.axhline(
                curve.mean[0],
                color=colour,
                linestyle="--",
                label=f"{curve.label} ({curve.mean[0]:.3g}; band: {CONFIDENCE:.0%} interval of its mean over "
                f"{curve.episodes} evaluation episodes, not seeds)",
            )
            if np.isfinite(curve.low[0]):
                ax.axhspan(*band_limits(curve.low[0], curve.high[0], metric), color=colour, alpha=0.08)
            continue
        style = _LINESTYLES[variants.get(curve.method, 0) % len(_LINESTYLES)]
        variants[curve.method] = variants.get(curve.method, 0) + 1
        if len(curve.per_seed):
            ax.plot(curve.steps, curve.per_seed.T, color=colour, linestyle=style, linewidth=0.5, alpha=0.35)
        ax.plot(curve.steps, curve.mean, color=colour, linestyle=style, label=f"{curve.label} (n={curve.seeds})")
        if np.isfinite(curve.low).any():
            draw_band(ax, curve.steps, curve.low, curve.high, metric, colour)
    lower = "\n(lower is better)" if MEASURES[metric].better < 0 else ""
    ax.set_ylabel(METRIC_LABELS[metric] + lower, fontsize=9)
    ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
    ax.grid(alpha=0.3)
    if legend:
        ax.legend(fontsize=7)


def _smoothing_text(window: int) -> str:
    """The figure's note on smoothing and bands, in lines short enough for the 7-inch single-panel figure."""
    iterations = "iteration" if window == 1 else "iterations"
    return (
        f"(trailing mean over {window} {iterations} = {window * EPISODE_STEPS} steps; thin: each seed;\nband: "
        f"{CONFIDENCE:.0%} t-interval of the mean over seeds, clipped to the measure's possible values)"
    )


def plot_curves(curves: dict[str, Curve], metric: str, title: str, window: int | None = None) -> Figure:
    """Mean (line), each seed (thin lines behind it) and 95% t-interval over seeds (shaded) of each smoothed
    curve of one measure against env steps; the expert as a horizontal dashed line with the interval of its
    mean over all its measured episodes (its seeds pooled, see ``curves_from_rows``). Bands are clipped to the
    measure's possible values. Curves of one method are told apart by line style. ``window``: the curves'
    smoothing, for the axis label (default :func:`smooth_window`). Uses ``matplotlib.figure.Figure`` directly
    (no pyplot state), so it is safe in worker processes and notebooks alike."""
    window = smooth_window() if window is None else window
    fig = Figure(figsize=(7, 4.5), layout="constrained")
    ax = fig.add_subplot()
    _draw_panel(ax, curves, metric, legend=True)
    ax.set_xlabel(f"environment steps\n{_smoothing_text(window)}", fontsize=9)
    ax.set_title(title, fontsize=10)
    return fig


def plot_measures(
    curves_by_measure: dict[str, dict[str, Curve]], title: str, window: int | None = None, columns: int | None = None
) -> Figure:
    """:func:`plot_curves` for several measures, one panel each (the paper's metric first), under one title and one
    legend below them; ``columns`` panels a row (default: all in one row, as the shipped figures are drawn). One
    column keeps every panel and the legend readable at a notebook's width, where a row of three is shrunk."""
    window = smooth_window() if window is None else window
    panels = len(curves_by_measure)
    if columns is None:
        columns, rows, size = panels, 1, (5.2 * panels, 5.5)
    else:
        columns = max(1, min(columns, panels))
        rows = -(-panels // columns)
        size = (7.5 if columns == 1 else 5.2 * columns, 3.3 * rows + 2.2)
    fig = Figure(figsize=size, layout="constrained")
    axes = fig.subplots(rows, columns, squeeze=False).ravel()
    for ax, (metric, curves) in zip(axes, curves_by_measure.items()):
        _draw_panel(ax, curves, metric, legend=False)
        ax.set_xlabel("environment steps", fontsize=9)
    for ax in axes[len(curves_by_measure) :]:
        ax.set_visible(False)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=2, fontsize=8)
    fig.suptitle(f"{title}\n{_smoothing_text(window)}", fontsize=10)
    return fig


def save_png(figure: Figure, path: str | Path, dpi: int) -> Path:
    """Write ``figure`` as a PNG of at most 256 colours (the render's pixels, each mapped to the nearest colour of
    the palette): line plots with light bands need no more, and the file is a fraction of matplotlib's full-colour
    PNG, which keeps the shipped data small."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    buffer.seek(0)
    with Image.open(buffer) as image:
        image.convert("RGB").quantize(colors=256).save(path, format="PNG", optimize=True)
    return Path(path)
