"""What a book page needs from the web, shipped instead: MathJax and the widget manager.

An exported notebook normally loads two things from a CDN: MathJax for the equations and the ipywidgets
manager that draws the widgets' saved state. Opened with no network (on a train, in an exam room) it then
shows raw TeX and blank widgets. :func:`copy_assets` puts both into the book's ``_static`` folder, from
packages on disk. (The camera-frame player of :func:`vdtutorial.course.viz.frames_animation` draws its
controls with plain HTML and needs nothing from the web.)

* MathJax 2.7 comes from ``jupyter-server-mathjax`` (the Jupyter project's PyPI package of MathJax's files;
  the ``book`` extra installs it). Its combined configuration typesets with HTML-CSS and the STIX web fonts
  it ships.
* The widget manager, ``@jupyter-widgets/html-manager``, is published on npm only, so its standalone bundle
  is kept in ``vdtutorial/web/html-manager`` (``SOURCE.md`` there says where it came from).

Not taught in a chapter: part of the rendered book (vdtutorial/course/html_book.py).
"""

from __future__ import annotations

import shutil
from pathlib import Path

#: The vendored widget manager (``embed.js`` draws every widget view of a page on load).
HTML_MANAGER_DIR = Path(__file__).resolve().parent.parent / "web" / "html-manager"
#: MathJax's combined configuration in jupyter-server-mathjax: TeX input, HTML-CSS output, the AMS packages;
#: ``Safe`` keeps the TeX from adding links or styles.
MATHJAX_CONFIG = "TeX-AMS-MML_HTMLorMML-full,Safe"


#: MathJax's settings for a book page, before MathJax starts: TeX between $...$ or \(...\) (and $$...$$ or
#: \[...\] displayed), and the STIX web fonts, the only ones jupyter-server-mathjax ships (MathJax would
#: otherwise look for its TeX fonts first). The hidden MathML that MathJax adds beside each equation for screen
#: readers is styled by its native-MathML settings, whose script and fraktur letters name TeX fonts that are not
#: shipped; the style rule keeps that hidden copy on the page's own fonts, so no font file is asked for in vain.
MATHJAX_SETTINGS = """<style>.MJX_Assistive_MathML * { font-family: serif !important; }</style>
<script type="text/x-mathjax-config">
MathJax.Hub.Config({
  tex2jax: {inlineMath: [["$", "$"], ["\\\\(", "\\\\)"]], displayMath: [["$$", "$$"], ["\\\\[", "\\\\]"]],
            processEscapes: true},
  "HTML-CSS": {availableFonts: [], webFont: "STIX-Web", imageFont: null}
});
</script>"""


def mathjax_dir() -> Path:
    """MathJax's files as ``jupyter-server-mathjax`` ships them (``MathJax.js``, ``config/``, ``fonts/``...)."""
    try:
        import jupyter_server_mathjax
    except ImportError as exc:
        raise ImportError("the book needs MathJax from jupyter-server-mathjax: pip install -e '.[book]'") from exc
    return Path(jupyter_server_mathjax.__file__).resolve().parent / "static"


def copy_assets(static: Path) -> dict[str, str]:
    """Copy MathJax and the widget manager into ``static``; return the URLs a page uses for them, relative to
    the folder that holds ``static`` (where the pages are)."""
    for source, name in ((mathjax_dir(), "mathjax"), (HTML_MANAGER_DIR, "html-manager")):
        shutil.copytree(source, static / name, dirs_exist_ok=True, ignore=shutil.ignore_patterns("__pycache__", "*.py"))
    return {
        "mathjax_url": f"{static.name}/mathjax/MathJax.js?config={MATHJAX_CONFIG}",
        "widget_renderer_url": f"{static.name}/html-manager/embed.js",
    }
