"""What a book page needs from the web, shipped instead: MathJax, the widget manager, the animation icons.

An exported notebook normally loads three things from a CDN: MathJax for the equations, the ipywidgets
manager that draws the widgets' saved state, and the Font Awesome icons of matplotlib's animation
controls. Opened with no network (on a train, in an exam room) it then shows raw TeX, blank widgets and
empty buttons. :func:`copy_assets` puts the first two into the book's ``_static`` folder, from packages on
disk; :func:`offline_animation_icons` swaps the third for inline SVG, which needs no font at all.

* MathJax 2.7 comes from ``jupyter-server-mathjax`` (the Jupyter project's PyPI package of MathJax's files;
  the ``book`` extra installs it). Its combined configuration typesets with HTML-CSS and the STIX web fonts
  it ships.
* The widget manager, ``@jupyter-widgets/html-manager``, is published on npm only, so its standalone bundle
  is kept in ``vdtutorial/web/html-manager`` (``SOURCE.md`` there says where it came from).

Not taught in a chapter: part of the rendered book (vdtutorial/course/html_book.py).
"""
from __future__ import annotations

import re
import shutil
from pathlib import Path

#: The vendored widget manager (``embed.js`` draws every widget view of a page on load).
HTML_MANAGER_DIR = Path(__file__).resolve().parent.parent / "web" / "html-manager"
#: MathJax's combined configuration in jupyter-server-mathjax: TeX input, HTML-CSS output, the AMS packages;
#: ``Safe`` keeps the TeX from adding links or styles.
MATHJAX_CONFIG = "TeX-AMS-MML_HTMLorMML-full,Safe"


#: MathJax's settings for a book page, before MathJax starts: TeX between $...$ or \(...\) (and $$...$$ or
#: \[...\] displayed), and the STIX web fonts, the only ones jupyter-server-mathjax ships (MathJax would
#: otherwise look for its TeX fonts first).
MATHJAX_SETTINGS = """<script type="text/x-mathjax-config">
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
        shutil.copytree(source, static / name, dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns("__pycache__", "*.py"))
    return {"mathjax_url": f"{static.name}/mathjax/MathJax.js?config={MATHJAX_CONFIG}",
            "widget_renderer_url": f"{static.name}/html-manager/embed.js"}


# -- matplotlib's animation controls ----------------------------------------------------------------------
#: Inline SVG (16 x 16, drawn in the button's text colour) for the Font Awesome icons that matplotlib's
#: ``to_jshtml`` buttons use: name -> the shapes' path data.
_ICON_PATHS = {
    "minus": "M2 7h12v2H2z",
    "plus": "M7 2h2v5h5v2H9v5H7V9H2V7h5z",
    "play": "M4 2l10 6-10 6z",
    "play fa-flip-horizontal": "M12 2L2 8l10 6z",
    "pause": "M3 2h4v12H3zM9 2h4v12H9z",
    "step-forward": "M2 2l9 6-9 6zM11 2h3v12h-3z",
    "step-backward": "M14 2L5 8l9 6zM2 2h3v12H2z",
    "fast-forward": "M1 2l6 6-6 6zM7 2l6 6-6 6zM13 2h2v12h-2z",
    "fast-backward": "M15 2L9 8l6 6zM9 2L3 8l6 6zM1 2h2v12H1z",
}
_FONT_AWESOME_LINK = re.compile(r'<link[^>]*font-awesome[^>]*>\s*', re.IGNORECASE)
_ICON = re.compile(r'<i class="fa fa-([a-z -]+)"></i>')


def _svg_icon(match: re.Match) -> str:
    path = _ICON_PATHS.get(match.group(1))
    if path is None:
        raise ValueError(f"no offline icon for Font Awesome's {match.group(1)!r}: add it to _ICON_PATHS")
    return (f'<svg viewBox="0 0 16 16" width="1em" height="1em" fill="currentColor" aria-hidden="true">'
            f'<path d="{path}"/></svg>')


def offline_animation_icons(html: str) -> str:
    """``html`` without the Font Awesome stylesheet link (a CDN) and with every ``<i class="fa fa-...">``
    icon drawn as inline SVG; other HTML comes back unchanged."""
    if not _ICON.search(html):
        return html
    return _ICON.sub(_svg_icon, _FONT_AWESOME_LINK.sub("", html))
