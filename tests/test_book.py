"""The offline book (``python -m vdtutorial book OUT``): the pieces on their own, then the quick book for
chapters 00, 04 and 07 opened in headless Chromium with the network blocked.

The browser test drives Debian's ``chromium`` through the DevTools protocol (websocket-client, no browser
download): it records every request the pages make, waits for MathJax, the widget manager and the meshcat
viewers, reads the rendered page, and keeps one screenshot per chapter in ``book-screenshots/`` (git ignores
it). Without chromium the test is skipped, except in CI (``CI`` set), where ``.ci/run`` installs it.
"""

import base64
import html
import io
import json
import os
import re
import shutil
import subprocess
import tempfile
import time
import urllib.parse
import urllib.request
from pathlib import Path

import nbformat
import numpy as np
import pytest

from vdtutorial.course import html_book, offline_assets, viz
from vdtutorial.__main__ import build_parser
from vdtutorial.settings import shipped_dir

pytestmark = pytest.mark.pipeline  # a command, chapter or long run end to end: CI's lock leg only

ROOT = Path(__file__).resolve().parent.parent
SCREENSHOTS = ROOT / "book-screenshots"
TESTED_CHAPTERS = ("00", "04", "07")


# -- the pieces ------------------------------------------------------------------------------------------
def test_links_to_repository_files_point_at_copies_inside_the_book(tmp_path):
    """A chapter links ``../docs/results.md`` (relative to notebooks/); next to the book's pages that would be
    a dead link, so the book copies the file in and links the copy. Missing files and files outside the
    repository keep their links; other links and text are untouched."""
    (tmp_path / "repo" / "docs").mkdir(parents=True)
    (tmp_path / "repo" / "docs" / "results.md").write_text("# results\n")
    (tmp_path / "secret.md").write_text("outside\n")
    notebook = nbformat.v4.new_notebook(
        cells=[
            nbformat.v4.new_markdown_cell(
                "see [`docs/results.md`](../docs/results.md#trpo), [gone](../docs/gone.md), "
                "[up](../../secret.md) and [paper](https://doi.org/10.1109/IROS.2018.8594341)"
            ),
            nbformat.v4.new_code_cell("# [not a link](../docs/results.md)"),
        ]
    )
    out = tmp_path / "book"
    copied = html_book.repository_links(notebook, tmp_path / "repo", out)
    assert copied == ["docs/results.md"]
    assert (out / "docs" / "results.md").read_text() == "# results\n"
    assert notebook.cells[0].source == (
        "see [`docs/results.md`](docs/results.md#trpo), [gone](../docs/gone.md), "
        "[up](../../secret.md) and [paper](https://doi.org/10.1109/IROS.2018.8594341)"
    )
    assert notebook.cells[1].source == "# [not a link](../docs/results.md)"
    assert not (out / "secret.md").exists()


def test_links_between_chapters_point_at_their_pages_in_the_book():
    notebook = nbformat.v4.new_notebook(
        cells=[
            nbformat.v4.new_markdown_cell(
                "see [chapter 05](05_pretraining.ipynb#section-7), [A5](A5_statistics_of_verdicts.ipynb), "
                "[not built](09_beyond_the_paper.ipynb) and [docs](../docs/results.md)"
            ),
            nbformat.v4.new_code_cell("# [not a link](05_pretraining.ipynb)"),
        ]
    )
    html_book.chapter_links(notebook, {"05_pretraining.html", "A5_statistics_of_verdicts.html"})
    assert notebook.cells[0].source == (
        "see [chapter 05](05_pretraining.html#section-7), [A5](A5_statistics_of_verdicts.html), "
        "[not built](09_beyond_the_paper.ipynb) and [docs](../docs/results.md)"
    )
    assert notebook.cells[1].source == "# [not a link](05_pretraining.ipynb)"


def _widget_output(widget):
    return nbformat.v4.new_output(
        "display_data", {html_book.WIDGET_VIEW: {"version_major": 2, "version_minor": 0, "model_id": widget.model_id}}
    )


def test_controls_that_need_the_kernel_are_greyed_out_and_say_so():
    """A slider that redraws a picture through a Python callback is disabled and gets the note above its box;
    a slider tied to another in the browser (jslink) keeps working and gets none; a picture alone gets none."""
    import ipywidgets as widgets
    from ipywidgets.embed import embed_data

    slider, picture = widgets.FloatSlider(description="threshold"), widgets.Image(format="png")
    box = widgets.VBox([slider, picture])
    left, right = widgets.IntSlider(), widgets.IntText()
    link = widgets.jslink((left, "value"), (right, "value"))
    alone = widgets.Label("a label")
    notebook = nbformat.v4.new_notebook()
    notebook.cells = [
        nbformat.v4.new_code_cell("box", outputs=[_widget_output(box)]),
        nbformat.v4.new_code_cell("linked", outputs=[_widget_output(widgets.HBox([left, right]))]),
        nbformat.v4.new_code_cell("label", outputs=[_widget_output(alone)]),
    ]
    notebook.metadata["widgets"] = {
        html_book.WIDGET_STATE: embed_data(views=[box, left, right, link, alone])["manager_state"]
    }

    assert html_book.mark_kernel_controls(notebook) == 1
    state = notebook.metadata["widgets"][html_book.WIDGET_STATE]["state"]
    assert state[slider.model_id]["state"]["disabled"] is True
    assert not state[left.model_id]["state"].get("disabled") and not state[right.model_id]["state"].get("disabled")
    first, linked, label = (cell.outputs for cell in notebook.cells)
    assert len(first) == 2 and html_book.NEEDS_KERNEL in first[0]["data"]["text/plain"]
    assert first[1]["data"][html_book.WIDGET_VIEW]["model_id"] == box.model_id
    assert len(linked) == 1 and len(label) == 1
    for widget in (box, slider, picture, left, right, link, alone):
        widget.close()


def test_chapters_titles_and_learning_goals_come_from_the_chapters_and_teaching_notes():
    chapters = html_book.find_chapters()
    assert [c.source.name for c in chapters] == sorted(p.name for p in (shipped_dir() / "notebooks").glob("*.ipynb"))
    goals = html_book.learning_goals(shipped_dir() / "notebooks" / "TEACHING.md")
    assert set(goals) == {c.number for c in chapters}, "TEACHING.md's learning goals name every chapter once"
    assert all(len(goal.split()) >= 5 for goal in goals.values())
    four = html_book.find_chapters(["4"])[0]
    assert four.number == "04" and four.page == four.source.with_suffix(".html").name
    assert four.title.startswith("04") and "#" not in four.title
    with pytest.raises(ValueError, match="no chapter numbered 99"):
        html_book.find_chapters(["99"])


def test_book_command_line():
    args = build_parser().parse_args(["book", "out", "--chapters", "00", "07"])
    assert (args.out, args.chapters, args.full) == ("out", ["00", "07"], False)
    assert build_parser().parse_args(["book", "out", "--full"]).full


# -- the book in a browser -------------------------------------------------------------------------------
class Chromium:
    """Headless Chromium driven over the DevTools protocol, with every request recorded and, when ``offline``, the
    network blocked (no name resolves, and every connection goes to a closed local port). One browser per page: in a
    browser that has already shown a page with meshcat scenes, the next page's first screenshot took 25-30 s on
    a quiet 2-core machine and over 120 s under load (a fresh browser: under 1 s)."""

    def __init__(self, executable: str, offline: bool = True):
        import websocket

        self.profile = Path(tempfile.mkdtemp(prefix="vdtutorial-chromium-"))
        blocked = ["--host-resolver-rules=MAP * ~NOTFOUND", "--proxy-server=127.0.0.1:9"] if offline else []
        self.process = subprocess.Popen(
            [
                executable,
                "--headless",
                "--no-sandbox",
                "--no-first-run",
                "--remote-debugging-port=0",
                f"--user-data-dir={self.profile}",
                *blocked,
                "--window-size=1280,900",
                "--enable-unsafe-swiftshader",
                "about:blank",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        port_file, deadline = self.profile / "DevToolsActivePort", time.monotonic() + 60
        while not (port_file.is_file() and len(port_file.read_text().split()) == 2):
            assert self.process.poll() is None and time.monotonic() < deadline, "chromium did not start"
            time.sleep(0.1)
        port, path = port_file.read_text().split()
        self.socket = websocket.create_connection(f"ws://127.0.0.1:{port}{path}", timeout=300, suppress_origin=True)
        self.calls, self.requests = 0, []
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        self.call("Network.enable")
        self.call("Page.enable")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.socket.close()
        self.process.kill()
        self.process.wait()
        shutil.rmtree(self.profile, ignore_errors=True)

    def call(self, method, **params):
        self.calls += 1
        message = {"id": self.calls, "method": method, "params": params}
        if getattr(self, "session", None):
            message["sessionId"] = self.session
        self.socket.send(json.dumps(message))
        while True:
            reply = json.loads(self.socket.recv())
            if reply.get("method") == "Network.requestWillBeSent":
                self.requests.append(reply["params"]["request"]["url"])
            if reply.get("id") == self.calls:
                assert "error" not in reply, reply["error"]
                return reply["result"]

    def evaluate(self, expression):
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        assert "exceptionDetails" not in result, result["exceptionDetails"]
        return result["result"].get("value")

    def wait_for(self, expression, what, timeout=120):
        deadline = time.monotonic() + timeout
        while not self.evaluate(expression):
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            time.sleep(0.5)

    def show(self, page: Path, what: str):
        """Open ``page`` and wait until it has loaded and is READY (equations, widgets, scenes)."""
        self.call("Page.navigate", url=page.as_uri())
        self.wait_for("document.readyState === 'complete'", f"{page.name} to load")
        self.wait_for(READY, what)

    def screenshot(self, clip=None) -> bytes:
        params = {"format": "png", **({"clip": {**clip, "scale": 1}} if clip else {})}
        return base64.b64decode(self.call("Page.captureScreenshot", **params)["data"])


#: Everything the page shows that MathJax should have typeset: the rendered Markdown cells' text.
MARKDOWN_TEXT = "[...document.querySelectorAll('.jp-MarkdownOutput')].map(e => e.innerText).join('\\n')"
#: TeX left as typed: $...$, $$, \( or \[ in the visible text.
RAW_TEX = re.compile(r"\$[^$\s][^$\n]*\$|\$\$|\\\(|\\\[")
#: Ready when MathJax has typeset the page (its queue runs the callback last), the widget manager has drawn every
#: widget view and its pictures, and every meshcat viewer has replayed its scene.
READY = """(() => {
  if (!window.__typeset) { MathJax.Hub.Queue(() => { window.__typeset = true; }); return false; }
  const views = document.querySelectorAll('script[type="application/vnd.jupyter.widget-view+json"]').length;
  const drawn = document.querySelectorAll('.jupyter-widgets.widget-container, .jupyter-widgets .widget-slider');
  const pictures = [...document.querySelectorAll('.jupyter-widgets img')];
  const scenes = [...document.querySelectorAll('iframe')].map(f => f.contentDocument);
  return (views === 0 || drawn.length > 0) && pictures.every(i => i.complete && i.naturalWidth > 0)
    && scenes.every(d => d && d.readyState === 'complete' && d.querySelector('canvas') !== null);
})()"""


def missing_files(requests) -> list[str]:
    """The file: URLs a page asked for that are not on disk (a font MathJax looks for and the book does not ship)."""
    return [
        url
        for url in requests
        if url.startswith("file:") and not Path(urllib.request.url2pathname(urllib.parse.urlparse(url).path)).exists()
    ]


def test_mathjax_asks_for_no_font_the_book_lacks(tmp_path):
    """Script, fraktur and calligraphic letters: MathJax's hidden MathML for screen readers names TeX fonts that
    jupyter-server-mathjax does not ship; the page asks for none of them, and still typesets every equation."""
    executable = chromium_executable("the book's MathJax test")
    urls = offline_assets.copy_assets(tmp_path / html_book.STATIC)
    notebook = nbformat.v4.new_notebook(
        cells=[
            nbformat.v4.new_markdown_cell(
                "# 99 · Letters\n\n$\\mathcal{L}$, $\\mathscr{D}$, $\\mathfrak{g}$ and $$\\mathbb{E}[x]$$"
            )
        ]
    )
    book = {"previous": None, "next": None, "mathjax_settings": offline_assets.MATHJAX_SETTINGS}
    page = tmp_path / "letters.html"
    page.write_text(html_book._exporter(urls).from_notebook_node(notebook, resources={"book": book})[0])
    with Chromium(executable) as browser:
        browser.show(page, "the letters typeset")
        time.sleep(1.0)  # fonts are asked for when the typeset page is laid out
        browser.evaluate("document.body.offsetHeight")
        assert browser.evaluate("document.querySelectorAll('.MathJax, .MathJax_Display').length") >= 4
        assert not missing_files(browser.requests), missing_files(browser.requests)


def _scene_pixels(browser, frame_index):
    """The picture of the ``frame_index``-th meshcat scene on screen, as an H x W x 3 array in [0, 1]."""
    import matplotlib.image

    rect = browser.evaluate(f"""(() => {{ const f = document.querySelectorAll('iframe')[{frame_index}];
        f.scrollIntoView({{block: 'center'}}); const r = f.getBoundingClientRect();
        return {{x: r.x + scrollX, y: r.y + scrollY, width: r.width, height: r.height}}; }})()""")  # page coordinates
    time.sleep(1.0)  # a frame or two of the viewer's render loop after scrolling
    return matplotlib.image.imread(io.BytesIO(browser.screenshot(rect)), format="png")[..., :3]


def _scene_shares(browser, frame_index, timeout: float = 60.0) -> dict[str, float]:
    """The shares of the ``frame_index``-th scene's picture that are the arm (its dark links; the sky is lighter), the
    cup (red) and the table (lit tan, not the blue sky), looked at again until all three are drawn or ``timeout``
    seconds have passed: the viewer adds each body's mesh as it loads, later on a busy machine."""
    deadline = time.monotonic() + timeout
    while True:
        pixels = _scene_pixels(browser, frame_index)
        red, green, blue = np.moveaxis(pixels, 2, 0)
        shares = {
            "arm": float(np.mean(pixels.max(axis=2) < 0.2)),
            "cup": float(np.mean((red > 0.6) & (green < 0.35) & (blue < 0.35))),
            "table": float(np.mean((red > 0.4) & (red - blue > 0.15) & (green > blue))),
        }
        drawn = shares["arm"] > 0.005 and shares["cup"] > 0.001 and shares["table"] > 0.05
        if drawn or time.monotonic() > deadline:
            return shares


def chromium_executable(test: str) -> str:
    """Debian's chromium, for ``test``; skipped without it, except in CI (``CI`` set), where .ci/run installs it."""
    executable = shutil.which("chromium") or shutil.which("chromium-browser")
    if executable is None:
        if os.environ.get("CI"):
            pytest.fail(f"CI needs Debian's chromium for {test} (.ci/run installs it)")
        pytest.skip(f"{test} needs chromium (apt-get install chromium)")
    return executable


@pytest.fixture(scope="module")
def quick_book(tmp_path_factory):
    executable = chromium_executable("the book's browser test")
    out = tmp_path_factory.mktemp("book")
    book = html_book.build_book(out, numbers=TESTED_CHAPTERS, quick=True, log=lambda line: None)
    return executable, book


def test_quick_book_reads_offline_in_a_browser(quick_book):
    executable, book = quick_book
    index = book.index.read_text()
    for chapter in book.chapters:
        assert f'href="{chapter.page}"' in index and chapter.title in index
        assert (
            html.escape(html_book.learning_goals(shipped_dir() / "notebooks" / "TEACHING.md")[chapter.number]) in index
        )
    SCREENSHOTS.mkdir(exist_ok=True)
    with Chromium(executable) as browser:
        browser.show(book.index, "the index's titles typeset")
        assert not RAW_TEX.findall(browser.evaluate("document.body.innerText")), "the index shows raw TeX"
        assert not [url for url in browser.requests if not re.match(r"(file|data|blob|about):", url)]
    for k, chapter in enumerate(book.chapters):
        page = book.index.parent / chapter.page
        assert not re.search(
            r"""<(?:script|link|img|iframe)\b[^>]*\b(?:src|href)\s*=\s*["']?(?:https?:)?//""", page.read_text()
        )
        assert page.read_text().count("<details>") >= 3, "the self-check's answers, folded"
        with Chromium(executable) as browser:
            browser.show(page, f"{chapter.page}'s equations, widgets and scenes")
            _check_chapter_page(browser, chapter, previous=book.chapters[k - 1].page if k else None)
            (SCREENSHOTS / f"{page.stem}.png").write_bytes(browser.screenshot())


def test_a_later_scene_draws_with_the_viewer_the_first_scene_brought(tmp_path, monkeypatch):
    """In a notebook only the first scene carries meshcat's viewer (vdtutorial.course.viz._brings_viewer); a page
    holding it and a later scene without it, the later one placed first, draws the arm, the cup and the table in
    both, offline."""
    import IPython

    from vdtutorial.envs.scene import JacoScene

    executable = chromium_executable("the shared viewer's browser test")
    scene = JacoScene()
    recorder = viz.Recorder()
    viz.mirror_bodies(recorder, scene.client, scene.bodies)
    request = {"header": {"msg_id": "run-1"}, "metadata": {}}
    kernel = type("Kernel", (), {"get_parent": lambda self: request})()
    monkeypatch.setattr(IPython, "get_ipython", lambda: type("Shell", (), {"kernel": kernel})())
    monkeypatch.setattr(viz, "_viewer_display", None)
    first = recorder.iframe("width: 480px; height: 360px; border: none;")
    later = recorder.iframe("width: 480px; height: 360px; border: none;")
    assert len(later) < len(first) / 4
    page = tmp_path / "scenes.html"
    page.write_text(f"<!DOCTYPE html><html><body>{later}<br>{first}</body></html>")
    with Chromium(executable) as browser:
        browser.call("Page.navigate", url=page.as_uri())
        browser.wait_for(
            "[...document.querySelectorAll('iframe')].every(f => f.contentDocument"
            " && f.contentDocument.querySelector('canvas') !== null)",
            "both scenes drawn",
            timeout=60,
        )
        for frame in range(2):
            shares = _scene_shares(browser, frame)
            assert shares["arm"] > 0.005 and shares["cup"] > 0.001 and shares["table"] > 0.05, (frame, shares)
        assert not [url for url in browser.requests if not re.match(r"(file|data|blob|about):", url)]
    scene.close()


def _check_chapter_page(browser, chapter, previous):
    """What a reader must see on a chapter's page: no network, typeset equations, the book's links, meshcat
    scenes with the arm, the cup and the table in them, and chapter 07's slider; it ends scrolled to the first
    scene, widget or equation, for the screenshot."""
    remote = [url for url in browser.requests if not re.match(r"(file|data|blob|about):", url)]
    assert not remote, f"{chapter.page} asked the network for {remote}"
    assert not missing_files(browser.requests), f"{chapter.page} asked for files the book lacks"
    assert browser.evaluate("document.title") == chapter.title
    assert browser.evaluate("document.querySelectorAll('.MathJax').length") > 0, "no equation typeset"
    assert browser.evaluate("document.querySelectorAll('.MathJax_Error, .merror').length") == 0
    leftover = RAW_TEX.findall(browser.evaluate(MARKDOWN_TEXT))
    assert not leftover, f"{chapter.page} shows raw TeX: {leftover[:5]}"
    links = browser.evaluate("[...document.querySelectorAll('nav.vdbook a')].map(a => a.getAttribute('href'))")
    assert "index.html" in links and (previous is None or previous in links)

    scenes = browser.evaluate("document.querySelectorAll('iframe').length")
    for frame in range(scenes):
        shares = _scene_shares(browser, frame)
        assert shares["arm"] > 0.005 and shares["cup"] > 0.001 and shares["table"] > 0.05, (
            f"scene {frame} of {chapter.page}: arm {shares['arm']:.1%}, cup {shares['cup']:.2%}, "
            f"table {shares['table']:.1%} of the picture"
        )
    if chapter.number in ("00", "07"):
        assert scenes > 0, f"{chapter.page} shows a meshcat scene"
    if chapter.number == "07":
        assert browser.evaluate("document.querySelectorAll('.jupyter-widgets .widget-slider').length") > 0, (
            "chapter 07's smoothing slider is drawn"
        )
        assert browser.evaluate("document.querySelectorAll('.vdbook-needs-kernel').length") > 0
        assert browser.evaluate(
            "[...document.querySelectorAll('.jupyter-widgets img')].every(i => i.naturalWidth > 100)"
        )

    first = "iframe" if scenes else ".jupyter-widgets" if chapter.number == "07" else ".MathJax_Display, .MathJax"
    browser.evaluate(f"document.querySelector('{first}').scrollIntoView({{block: 'center'}})")
    time.sleep(1.0)
