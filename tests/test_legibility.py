"""Figures legible at the width JupyterLab shows them: the text of a chapter's picture, in pixels on the page.

A PNG wider than the output area is shrunk to fit, and its text with it; a PNG narrower than the widget box it fills
is blown up and soft. JupyterLab's output area is about 830 px wide in a 1280-px window with the file browser open
and about 960 px with it folded away (tests/test_lab.py measures the pictures of the chapters with sliders there).
Here the figures are drawn as the chapters draw them, at the dpi their cells use, and the smallest text is measured
as it lands on the narrower page.
"""

import io
import json
import re
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import nbformat
import pytest
from matplotlib.text import Text
from PIL import Image

from vdtutorial.experiments import (
    curves_from_rows,
    plot_curves,
    plot_measures,
    read_rows,
    results_file,
)
from vdtutorial.experiments.beyond import RL
from vdtutorial.settings import data_dir

ROOT = Path(__file__).resolve().parent.parent
#: The width (px) of JupyterLab's output area in a 1280-px window with the file browser open.
OUTPUT_WIDTH = 830
#: The smallest text a reader is asked to read on a figure, in pixels of its height as shown.
SMALLEST_TEXT_PX = 8.5


def _cell(chapter: str, cell_id: str) -> str:
    notebook = nbformat.read(ROOT / "notebooks" / f"{chapter}.ipynb", as_version=4)
    return next(cell.source for cell in notebook.cells if cell.get("id") == cell_id)


def shown_text_px(figure, dpi: float) -> tuple[int, float]:
    """The PNG's width at ``dpi`` and the height on the page (px) of the figure's smallest visible text, shown at
    its own width capped at the output area's."""
    png = io.BytesIO()
    figure.savefig(png, format="png", dpi=dpi)
    width = Image.open(png).size[0]
    shown = min(width, OUTPUT_WIDTH)
    sizes = [t.get_fontsize() for t in figure.findobj(Text) if t.get_visible() and t.get_text().strip()]
    return width, min(sizes) * dpi / 72 * shown / width


@pytest.fixture(scope="module")
def beyond():
    folder = data_dir() / "results" / "beyond"
    if not (folder / "beyond.json").exists():
        pytest.skip("data/results/beyond is not in this copy")
    record = json.loads((folder / "beyond.json").read_text())
    rows = [row for row in read_rows(results_file(folder, "beyond")) if row["stage"] == RL]
    return {m: curves_from_rows(rows, m, record["rl"]["window"]) for m in record["rl"]["measures"]}, record


def test_chapter_09_draws_the_rl_curves_readable_at_the_notebook_width(beyond):
    """The three measures side by side (the shipped beyond_rl.png, 110 dpi) shrink to about 6-px text; chapter 09
    redraws them one a row at the dpi its cell names."""
    by_measure, record = beyond
    source = _cell("09_beyond_the_paper", "ch09-results-print")
    assert "columns=1" in source
    dpi = int(re.search(r"rl_figure\.savefig\([^)]*dpi=(\d+)", source).group(1))
    side_by_side = shown_text_px(plot_measures(by_measure, "RL", record["rl"]["window"]), 110)
    stacked = shown_text_px(plot_measures(by_measure, "RL", record["rl"]["window"], columns=1), dpi)
    assert side_by_side[1] < SMALLEST_TEXT_PX, side_by_side
    assert stacked[0] <= 1.1 * OUTPUT_WIDTH and stacked[1] >= SMALLEST_TEXT_PX, stacked


def test_chapter_07_draws_the_smoothing_picture_about_as_wide_as_the_output_area(beyond):
    """The slider's picture is shown at its own width (capped at the output area's): at the chapter's dpi it is about
    as wide as the output area and its text readable. (The curves are the shipped beyond experiment's:
    plot_curves's figure size and fonts do not depend on the data.)"""
    by_measure, record = beyond
    source = _cell("07_finetuning", "141f86fd")
    assert 'align_self="flex-start"' in source, "the picture keeps its own width in the widget box"
    dpi = int(re.search(r"^WINDOW_DPI = (\d+)$", source, re.MULTILINE).group(1))
    curves = by_measure[record["rl"]["metric"]]
    width, text = shown_text_px(plot_curves(curves, record["rl"]["metric"], "a title", 25), dpi)
    assert 0.9 * OUTPUT_WIDTH <= width <= 1.3 * OUTPUT_WIDTH, width
    assert text >= SMALLEST_TEXT_PX, text


def test_plot_measures_lays_panels_out_in_rows():
    """``columns`` sets the panels a row; no empty panel shows."""
    curves = {"successes": {}, "success_rate": {}, "steps_per_trajectory": {}}
    row = plot_measures(curves, "t", 5)
    assert row.get_size_inches().tolist() == pytest.approx([15.6, 5.5]) and len(row.axes) == 3
    two = plot_measures(curves, "t", 5, columns=2)
    assert [ax.get_visible() for ax in two.axes] == [True, True, True, False]
    positions = [ax.get_subplotspec().get_geometry()[:2] for ax in two.axes]
    assert positions == [(2, 2)] * 4
