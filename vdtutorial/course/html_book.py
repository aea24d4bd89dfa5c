"""The chapters as a static HTML book that reads offline: ``python -m vdtutorial book OUT``.

A teacher links a chapter, a student previews it on a phone or on a train: the book is the chapters
executed (quick mode by default, the paper's budgets with ``full=True``) and exported to HTML, one page per
chapter with previous/next links, and an index with the chapter table and each chapter's learning goal
(read from ``notebooks/TEACHING.md``, the one place they are written).

The tool is nbconvert (executing with nbclient, exporting with its JupyterLab template), with our own
index: it is the Jupyter project's own exporter, already installed with Jupyter, and every offline gap is
a setting of its exporter (the MathJax and widget-manager URLs) or a small template block, so nothing
needs the network at build time or when the book is read (:mod:`vdtutorial.course.offline_assets`). Sphinx with
myst-nb or Jupyter Book would add a site generator whose themes and widget support load the same scripts
from CDNs, to be undone one by one.

Two things an exported notebook cannot do are said on the page instead of being left broken: a widget
whose controls run Python callbacks (every slider in the chapters redraws a figure in the kernel) keeps
the picture it was saved with, its controls are greyed out, and a note above it says that moving them
needs a running kernel. A chapter's link to a file
of the repository (``../docs/results.md``) would point outside the book: the file is copied in and linked there;
a link to another chapter or an appendix (``05_pretraining.ipynb``) points at its page.

Not taught in a chapter: it renders the chapters themselves (README, "As a book that reads offline").
"""

from __future__ import annotations

import html
import os
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import nbformat

from vdtutorial.course.offline_assets import MATHJAX_SETTINGS, copy_assets
from vdtutorial.settings import QUICK_ENV, shipped_dir

#: The nbconvert template of a chapter page (JupyterLab's, with the book's navigation).
TEMPLATE_DIR = Path(__file__).resolve().parent.parent / "web" / "templates"
#: The mime type under which a notebook stores its widgets' saved state, and a widget view in an output.
WIDGET_STATE = "application/vnd.jupyter.widget-state+json"
WIDGET_VIEW = "application/vnd.jupyter.widget-view+json"
#: What a widget with controls says in the book, above the saved picture.
NEEDS_KERNEL = (
    "This control needs a running Python kernel: its callback redraws the output in Python. The page "
    "shows the output as it was saved; open the chapter in Jupyter to move the control."
)
#: The folder of the book's shared scripts and fonts (MathJax, the widget manager).
STATIC = "_static"


@dataclass(frozen=True)
class Chapter:
    """One chapter of the book: its notebook, its number ("04"), its title and its page's file name."""

    source: Path
    number: str
    title: str

    @property
    def page(self) -> str:
        return self.source.with_suffix(".html").name


@dataclass(frozen=True)
class BuiltBook:
    index: Path
    chapters: list[Chapter]
    seconds: dict[str, float]


def _title(notebook) -> str:
    """The chapter's first Markdown heading ("04 · Sparse variational dropout")."""
    for cell in notebook.cells:
        heading = re.search(r"^#\s+(.+)$", cell.source, flags=re.M) if cell.cell_type == "markdown" else None
        if heading:
            return heading.group(1).strip()
    raise ValueError("a chapter has no '# title' heading")


def find_chapters(numbers=None, source: Path | None = None) -> list[Chapter]:
    """The chapters under ``source/notebooks`` (default: :func:`~vdtutorial.settings.shipped_dir`) in their
    order, the appendices (``A1_*.ipynb``, ...) after them, only those whose number is in ``numbers`` (e.g.
    ``["00", "04", "A1"]``) when given."""
    source = Path(source) if source is not None else shipped_dir()
    paths = sorted((source / "notebooks").glob("[0-9][0-9]*_*.ipynb")) + sorted(
        (source / "notebooks").glob("A[0-9]_*.ipynb")
    )
    wanted = {f"{int(n):02d}" if str(n).isdigit() else str(n) for n in numbers} if numbers else None
    chapters = [
        Chapter(path, path.name.split("_", 1)[0], _title(nbformat.read(path, as_version=4)))
        for path in paths
        if wanted is None or path.name.split("_", 1)[0] in wanted
    ]
    missing = sorted((wanted or set()) - {c.number for c in chapters})
    if missing:
        raise ValueError(f"no chapter numbered {', '.join(missing)} in {source / 'notebooks'}")
    return chapters


def learning_goals(teaching: Path) -> dict[str, str]:
    """Chapter number -> "after it, a student can ..." from the table under ``## Learning goals`` in
    TEACHING.md (its rows start ``| 04 sparse VD | ...``, an appendix's ``| A1 ... | ...``)."""
    section = re.search(
        r"^## Learning goals\n(.*?)(?=^## |\Z)", teaching.read_text(encoding="utf-8"), flags=re.M | re.S
    )
    if section is None:
        raise ValueError(f"{teaching} has no '## Learning goals' section")
    rows = re.findall(r"^\|\s*(\d\d[a-z]?|A\d)\b[^|]*\|\s*(.+?)\s*\|\s*$", section.group(1), flags=re.M)
    return dict(rows)


def execute(chapter: Chapter, quick: bool, timeout: int):
    """The chapter run top to bottom on a fresh kernel in its own folder, as a learner runs it; the
    widgets' state is stored in the notebook. A failing cell raises nbclient's ``CellExecutionError``."""
    from nbclient import NotebookClient

    notebook = nbformat.read(chapter.source, as_version=4)
    env = {**os.environ, QUICK_ENV: "1" if quick else "0"}
    env.pop("MPLBACKEND", None)  # the kernel's inline backend shows the figures (Agg would drop them)
    NotebookClient(
        notebook,
        timeout=timeout,
        kernel_name="python3",
        store_widget_state=True,
        resources={"metadata": {"path": str(chapter.source.parent)}},
    ).execute(env=env)
    return notebook


def _references(value) -> list[str]:
    """The widget model ids a saved state names ("IPY_MODEL_<id>"), in lists and dicts too (children, links)."""
    if isinstance(value, str):
        return [value[len("IPY_MODEL_") :]] if value.startswith("IPY_MODEL_") else []
    if isinstance(value, (list, tuple)):
        return [ref for item in value for ref in _references(item)]
    if isinstance(value, dict):
        return [ref for item in value.values() for ref in _references(item)]
    return []


def _control_model_names() -> set[str]:
    """The model names of ipywidgets' controls: the widget classes with a ``disabled`` trait (a saved state
    may leave the trait out when it holds its default)."""
    import ipywidgets

    classes, names = [ipywidgets.DOMWidget], set()
    while classes:
        cls = classes.pop()
        classes.extend(cls.__subclasses__())
        if "disabled" in cls.class_trait_names():
            names.add(cls.class_traits()["_model_name"].default_value)
    return names


def mark_kernel_controls(notebook) -> int:
    """Grey out every widget control whose effect needs the kernel and say so above its widget; return how
    many widget outputs got the note.

    A control is a widget with a ``disabled`` trait (sliders, dropdowns, buttons...). In a static page only a
    control tied to another widget in the browser (``widgets.jslink``) still does something; every other
    control's effect is a Python callback, which a page cannot run."""
    state = notebook.metadata.get("widgets", {}).get(WIDGET_STATE, {}).get("state", {})
    linked = {
        ref
        for model in state.values()
        if model["model_name"] in ("LinkModel", "DirectionalLinkModel")
        for ref in _references(model["state"])
    }
    control_models = _control_model_names()
    controls = {
        model_id
        for model_id, model in state.items()
        if (model["model_name"] in control_models or "disabled" in model["state"]) and model_id not in linked
    }
    for model_id in controls:
        state[model_id]["state"]["disabled"] = True

    def holds_control(model_id, seen=()) -> bool:
        if model_id in controls:
            return True
        children = _references(state.get(model_id, {}).get("state", {}).get("children", []))
        return any(holds_control(child, (*seen, model_id)) for child in children if child not in seen)

    marked = 0
    for cell in notebook.cells:
        outputs = []
        for output in cell.get("outputs", []):
            view = output.get("data", {}).get(WIDGET_VIEW)
            if view and holds_control(view["model_id"]):
                outputs.append(
                    nbformat.v4.new_output(
                        "display_data",
                        {
                            "text/html": f'<p class="vdbook-needs-kernel">{html.escape(NEEDS_KERNEL)}</p>',
                            "text/plain": NEEDS_KERNEL,
                        },
                    )
                )
                marked += 1
            outputs.append(output)
        if "outputs" in cell:
            cell.outputs = outputs
    return marked


#: A markdown link from a chapter to a file of the repository outside ``notebooks/``: ``](../docs/results.md)``.
REPOSITORY_LINK = re.compile(r"\]\(\.\./([^)#\s]+)(#[^)\s]*)?\)")


def repository_links(notebook, source: Path, out: Path) -> list[str]:
    """Point the chapter's links to repository files (``../docs/results.md``, relative to ``notebooks/``) at
    copies inside the book (``OUT/docs/results.md``), so that they work next to the book's pages and offline.
    A link whose file is not under ``source`` (an installed package carries no ``docs/``) stays as it is.
    Returns the files copied, as paths relative to ``source``."""
    root, copied = source.resolve(), []

    def relink(match):
        target = (source / match.group(1)).resolve()
        if root not in target.parents or not target.is_file():
            return match.group(0)
        relative = target.relative_to(root)
        (out / relative).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(target, out / relative)
        copied.append(relative.as_posix())
        return f"]({relative.as_posix()}{match.group(2) or ''})"

    for cell in notebook.cells:
        if cell.cell_type == "markdown":
            cell.source = REPOSITORY_LINK.sub(relink, cell.source)
    return copied


#: A Markdown link from one chapter to another: ``](05_pretraining.ipynb#anchor)``.
CHAPTER_LINK = re.compile(r"\]\(([\w-]+)\.ipynb(#[^)\s]*)?\)")


def chapter_links(notebook, pages: set[str]) -> None:
    """Point the chapter's links to other chapters and appendices (``05_pretraining.ipynb``) at their pages in the
    book (``05_pretraining.html``); a link to a notebook the book does not hold stays as it is."""

    def relink(match):
        page = f"{match.group(1)}.html"
        return f"]({page}{match.group(2) or ''})" if page in pages else match.group(0)

    for cell in notebook.cells:
        if cell.cell_type == "markdown":
            cell.source = CHAPTER_LINK.sub(relink, cell.source)


def _exporter(urls: dict[str, str]):
    from nbconvert import HTMLExporter

    return HTMLExporter(extra_template_basedirs=[str(TEMPLATE_DIR)], template_name="vdbook", **urls)


def _index_page(chapters: list[Chapter], goals: dict[str, str], quick: bool, mathjax_url: str) -> str:
    """The book's first page: what it is, and the chapters (their titles may hold TeX) with their goals."""
    rows = "\n".join(
        f'<tr><td><a href="{html.escape(c.page)}">{html.escape(c.title)}</a></td>'
        f"<td>{html.escape(goals.get(c.number, ''))}</td></tr>"
        for c in chapters
    )
    mode = (
        "quick mode (small budgets: the same code as the paper's runs, in seconds)" if quick else "the paper's budgets"
    )
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><meta name="viewport" content="width=device-width, initial-scale=1">
<title>vdtutorial: the book</title>
{MATHJAX_SETTINGS}
<script src="{html.escape(mathjax_url)}"></script>
<style>
  body {{ font-family: sans-serif; max-width: 1000px; margin: 2em auto; padding: 0 1em; line-height: 1.45; }}
  table {{ border-collapse: collapse; width: 100%; }}
  td, th {{ border-bottom: 1px solid #ddd; padding: 0.4em 0.6em; text-align: left; vertical-align: top; }}
</style></head>
<body>
<h1>vdtutorial: the book</h1>
<p>A rebuild, chapter by chapter, of J. Blau, L. Ott, F. Ramos, <em>Improving Reinforcement Learning
Pre-Training with Variational Dropout</em>, IROS 2018. Each page is a chapter as it ran in {mode}, with its
outputs; to change and run the code, open the notebooks in Jupyter
(<code>python -m vdtutorial notebooks DEST</code>).</p>
<table>
<thead><tr><th>chapter</th><th>after it, a student can</th></tr></thead>
<tbody>
{rows}
</tbody></table>
</body></html>
"""


def build_book(
    out, numbers=None, quick: bool = True, timeout: int = 3600, source: Path | None = None, log=print
) -> BuiltBook:
    """Execute the chapters (all, or those in ``numbers``) and write the book into ``out``: ``index.html``,
    one page per chapter and ``_static`` (MathJax, the widget manager). ``log`` gets one line per chapter."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise NotADirectoryError(f"{out} is a file, not a folder: name a folder for the book")
    source = Path(source) if source is not None else shipped_dir()
    chapters = find_chapters(numbers, source)
    goals = learning_goals(source / "notebooks" / "TEACHING.md")
    out.mkdir(parents=True, exist_ok=True)
    urls = copy_assets(out / STATIC)
    exporter = _exporter(urls)
    seconds = {}
    for k, chapter in enumerate(chapters):
        start = time.perf_counter()
        notebook = execute(chapter, quick, timeout)
        seconds[chapter.number] = time.perf_counter() - start
        notebook.metadata["title"] = chapter.title  # the page's <title>; nbconvert's default is "Notebook"
        marked = mark_kernel_controls(notebook)
        repository_links(notebook, source, out)
        chapter_links(notebook, {c.page for c in chapters})
        book = {
            "previous": chapters[k - 1] if k > 0 else None,
            "next": chapters[k + 1] if k + 1 < len(chapters) else None,
            "mathjax_settings": MATHJAX_SETTINGS,
        }
        body, _ = exporter.from_notebook_node(notebook, resources={"book": book})
        (out / chapter.page).write_text(body, encoding="utf-8")
        log(
            f"{chapter.page}: ran in {seconds[chapter.number]:.0f} s"
            + (f", {marked} widget(s) marked as needing a kernel" if marked else "")
        )
    index = out / "index.html"
    index.write_text(_index_page(chapters, goals, quick, urls["mathjax_url"]), encoding="utf-8")
    return BuiltBook(index, chapters, seconds)
