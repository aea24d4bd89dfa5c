"""The chapters with pictures as a student sees them: JupyterLab in headless Chromium, Run All, then every slider
moved by the keyboard.

Each chapter is run from a folder written by ``python -m vdtutorial notebooks DEST`` in quick mode. After Run
All the test checks what a student sees:

* every picture in an output has a size on the page (a picture laid out at 0 x 0 shows nothing) and is not
  blown up beyond its pixels or shrunk so far that its text is unreadable;
* every 3-D scene (an iframe) draws its canvas;
* no request left the JupyterLab server (a CDN's script or font is a picture that breaks offline);
* each slider's picture and caption are those its value draws: the slider is moved one step down (its readout
  and picture must change) and back up, and the picture and caption must then be the ones Run All left;
* no text beside a slider runs past its box (a long ``Label`` is cut at the window's edge);
* saved and opened again, its pictures and 3-D scenes still show;
* no error reached the kernel's replies, in a cell or in a widget's callback (the latter reach only JupyterLab's
  Log Console, never the notebook).

Chromium is driven over the DevTools protocol as in ``test_book.py``; JupyterLab is started with
``expose_app_in_browser`` so that the page's ``window.jupyterapp`` can run the notebook's commands.
"""

import json
import os
import socket
import subprocess
import sys
import time
import urllib.request

import pytest

from test_book import Chromium, chromium_executable
from vdtutorial.course.chapters import write_notebooks

pytestmark = pytest.mark.pipeline  # chapters end to end: CI's lock leg only

#: The chapters with pictures a callback or a script draws, and how many sliders each shows.
CHAPTERS = {"01_environment": 0, "03_demonstrations": 1, "05_pretraining": 1, "07_finetuning": 1}
#: The file browser folded away, as a student reading a chapter has it: the output area is then about 960 px wide
#: in the test's 1280-px window.
COLLAPSED = "jupyterapp.shell.collapseLeft()"
#: How far a picture may be scaled on the page relative to its pixels: above MAX_SCALE it is blown up and soft;
#: below MIN_SCALE matplotlib's default 10-pt text, drawn at its default 100 dpi, is shown under 8 px high.
MAX_SCALE, MIN_SCALE = 1.05, 0.6
NOTEBOOK = "jupyterapp.shell.currentWidget"
#: The notebook's kernel has started and is idle.
KERNEL_IDLE = f"""(() => {{ const k = window.jupyterapp && {NOTEBOOK} && {NOTEBOOK}.sessionContext
    && {NOTEBOOK}.sessionContext.session && {NOTEBOOK}.sessionContext.session.kernel;
    return !!k && k.connectionStatus === 'connected' && k.status === 'idle'; }})()"""
#: Record every error message the kernel sends, whatever it answers (a cell or a widget's callback).
RECORD_ERRORS = f"""(() => {{ window.__errors = [];
    {NOTEBOOK}.sessionContext.session.kernel.anyMessage.connect((_, args) => {{
        const m = args.msg;
        if (args.direction === 'recv' && m.header.msg_type === 'error')
            window.__errors.push(m.content.ename + ': ' + m.content.evalue);
    }}); return true; }})()"""
RUN_ALL = """(() => { window.__ranAll = false;
    jupyterapp.commands.execute('notebook:run-all-cells').then(() => { window.__ranAll = true; });
    return true; })()"""
#: Every slider's readout, the pictures of the widget box it sits in, a digest of each picture's bytes and the
#: box's caption (its HTML text).
SLIDERS = """(async () => Promise.all([...document.querySelectorAll('.jp-OutputArea .widget-slider')].map(async s => {
    const box = s.closest('.widget-vbox') || s.parentElement;
    const pictures = [...box.querySelectorAll('img')];
    const digests = await Promise.all(pictures.map(async i => {
        const bytes = await (await fetch(i.src)).arrayBuffer();
        return [...new Uint8Array(await crypto.subtle.digest('SHA-256', bytes))]
            .map(b => b.toString(16).padStart(2, '0')).join(''); }));
    return {readout: (s.querySelector('.widget-readout') || {}).textContent || '',
            pictures: pictures.map(i => i.src), digests: digests,
            caption: [...box.querySelectorAll('.widget-html-content')].map(t => t.textContent).join(' '),
            labels: [...box.querySelectorAll('.widget-label')].map(l => l.textContent),
            cut: [...box.querySelectorAll('.widget-label, .widget-html-content')]
                .filter(t => t.scrollWidth > t.clientWidth + 1).map(t => t.textContent)}; })))()"""
#: Every picture in an output, each scrolled into view first (JupyterLab may skip laying out cells off screen):
#: its cell, its size on the page and its pixels.
PICTURES = """(async () => { const out = [];
    const cells = [...document.querySelectorAll('.jp-Notebook .jp-Cell')];
    for (const [k, cell] of cells.entries()) for (const i of cell.querySelectorAll('.jp-OutputArea img')) {
        i.scrollIntoView({block: 'center'});
        await new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)));
        if (!i.complete) await new Promise(r => { i.onload = i.onerror = r; setTimeout(r, 5000); });
        const r = i.getBoundingClientRect();
        out.push({cell: k, width: r.width, height: r.height, natural: [i.naturalWidth, i.naturalHeight]}); }
    return out; })()"""

#: The 3-D scenes in outputs (iframes) that have not drawn their canvas yet, each scrolled into view first: a scene
#: without the viewer's JavaScript never does.
SCENES_NOT_DRAWN = """(async () => { const out = [];
    const cells = [...document.querySelectorAll('.jp-Notebook .jp-Cell')];
    for (const [k, cell] of cells.entries()) for (const f of cell.querySelectorAll('.jp-OutputArea iframe')) {
        f.scrollIntoView({block: 'center'});
        await new Promise(r => setTimeout(r, 300));
        const d = f.contentDocument;
        if (!d || d.readyState !== 'complete' || d.querySelector('canvas') === null) out.push(k); }
    return out; })()"""


def _step(browser, k, key, code, keycode):
    """Move the k-th slider one step with the keyboard, as a student does."""
    browser.evaluate(f"""(() => {{ const h = document.querySelectorAll('.jp-OutputArea .widget-slider')[{k}]
        .querySelector('.noUi-handle'); h.scrollIntoView({{block: 'center'}}); h.focus();
        return document.activeElement === h; }})()""")
    for kind in ("keyDown", "keyUp"):
        browser.call("Input.dispatchKeyEvent", type=kind, key=key, code=code, windowsVirtualKeyCode=keycode)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """JupyterLab serving a written copy of the chapters, in quick mode, with its own settings and workspaces."""
    executable = chromium_executable("the JupyterLab test")
    home = tmp_path_factory.mktemp("lab")
    write_notebooks(home / "book")
    port = _free_port()
    env = {
        **os.environ,
        "VDTUTORIAL_QUICK": "1",
        "MPLBACKEND": "module://matplotlib_inline.backend_inline",
        "JUPYTER_CONFIG_DIR": str(home / "config"),
        "JUPYTERLAB_WORKSPACES_DIR": str(home / "workspaces"),
        "JUPYTER_RUNTIME_DIR": str(home / "runtime"),
    }
    server = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "jupyterlab",
            "--no-browser",
            f"--port={port}",
            "--ServerApp.ip=127.0.0.1",
            "--IdentityProvider.token=",
            "--ServerApp.password=",
            f"--ServerApp.root_dir={home / 'book'}",
            "--ServerApp.allow_root=True",
            "--LabApp.expose_app_in_browser=True",
            "--LabApp.news_url=None",
            "--LabApp.check_for_updates_class=jupyterlab.NeverCheckForUpdate",
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=open(home / "server.log", "w"),
    )
    url, deadline = f"http://127.0.0.1:{port}", time.monotonic() + 120
    while True:
        try:
            urllib.request.urlopen(f"{url}/api/status", timeout=5)
            break
        except OSError:
            assert server.poll() is None and time.monotonic() < deadline, (home / "server.log").read_text()[-3000:]
            time.sleep(0.5)
    yield executable, url
    server.terminate()
    server.wait(timeout=60)


def off_host(requests, server_url):
    """The requests that went neither to the JupyterLab server nor to the page itself (data:, blob:, about:)."""
    return [
        url for url in requests if not (url.startswith(server_url) or url.split(":", 1)[0] in ("data", "blob", "about"))
    ]


def test_off_host_names_only_other_hosts():
    url = "http://127.0.0.1:8888"
    requests = [
        f"{url}/api/kernels",
        "data:image/png;base64,AA",
        "blob:http://127.0.0.1:8888/x",
        "about:srcdoc",
        "https://cdnjs.cloudflare.com/ajax/libs/font-awesome/4.7.0/css/font-awesome.min.css",
        "http://127.0.0.1:9999/elsewhere",
    ]
    assert off_host(requests, url) == requests[-2:]


@pytest.mark.parametrize("chapter", sorted(CHAPTERS))
def test_pictures_show_and_agree_with_their_sliders_after_run_all(lab, chapter):
    executable, url = lab
    with Chromium(executable, offline=False) as browser:
        browser.call("Page.navigate", url=f"{url}/lab/tree/notebooks/{chapter}.ipynb?reset")
        browser.wait_for(KERNEL_IDLE, f"{chapter}'s kernel", timeout=180)
        browser.evaluate(f"{COLLAPSED}, true")
        browser.evaluate(RECORD_ERRORS)
        browser.evaluate(RUN_ALL)
        browser.wait_for(f"window.__ranAll && {KERNEL_IDLE}", f"Run All of {chapter}", timeout=900)

        problems = []  # what a student would see wrong, all of it reported at the end
        pictures = browser.evaluate(PICTURES)
        assert pictures, f"{chapter} shows no picture after Run All"
        problems += [
            f"cell {p['cell']}: a picture laid out at {p['width']:.0f} x {p['height']:.0f} px (its pixels: "
            f"{p['natural'][0]} x {p['natural'][1]})"
            for p in pictures
            if p["width"] < 1 or p["height"] < 1 or 0 in p["natural"]
        ]
        problems += [
            f"cell {p['cell']}: a {p['natural'][0]}-px picture shown {p['width']:.0f} px wide"
            for p in pictures
            if p["natural"][0] and not MIN_SCALE <= p["width"] / p["natural"][0] <= MAX_SCALE
        ]
        try:
            browser.wait_for(
                f"{SCENES_NOT_DRAWN}.then(cells => cells.length === 0)", f"{chapter}'s 3-D scenes", timeout=60
            )
        except AssertionError:
            problems.append(f"the 3-D scenes of cells {browser.evaluate(SCENES_NOT_DRAWN)} drew nothing")
        problems += [f"a request to another host: {url}" for url in off_host(browser.requests, url)]

        sliders = browser.evaluate(SLIDERS)
        assert len(sliders) == CHAPTERS[chapter] and all(s["pictures"] for s in sliders), sliders
        for k, after_run_all in enumerate(sliders):
            moved = after_run_all
            for key, code, keycode in (("ArrowLeft", "ArrowLeft", 37), ("ArrowRight", "ArrowRight", 39)):
                # one step down (every slider starts above its lowest value), then back to the value Run All left
                _step(browser, k, key, code, keycode)
                redrawn = f"""(async () => {{ const now = (await {SLIDERS})[{k}];
                    return now.readout !== {json.dumps(moved["readout"])}
                        && JSON.stringify(now.pictures) !== {json.dumps(json.dumps(moved["pictures"]))}; }})()"""
                try:
                    browser.wait_for(redrawn, f"{chapter}'s slider {k} to redraw its picture ({key})", timeout=120)
                except AssertionError as timeout:
                    errors = browser.evaluate("window.__errors")
                    raise AssertionError(f"{timeout}; the kernel reported: {errors}") from None
                browser.wait_for(KERNEL_IDLE, f"{chapter}'s kernel after the slider moved", timeout=300)
                moved = browser.evaluate(SLIDERS)[k]
            if moved["readout"] != after_run_all["readout"] or (moved["digests"], moved["caption"]) != (
                after_run_all["digests"],
                after_run_all["caption"],
            ):
                problems.append(
                    f"after Run All slider {k} read {after_run_all['readout']} but its picture and caption "
                    f"were not the ones that value draws (Run All: {after_run_all['caption']!r}; drawn at "
                    f"{moved['readout']}: {moved['caption']!r})"
                )
        problems += [
            f"text beside a slider cut at the window's edge (1280 px): {text!r}"
            for slider in browser.evaluate(SLIDERS)
            for text in slider["cut"]
        ]
        problems += [f"the kernel reported {error}" for error in browser.evaluate("window.__errors")]

        # The notebook as a student hands it in: saved, then opened again.
        cells = browser.evaluate("document.querySelectorAll('.jp-Notebook .jp-Cell').length")
        browser.evaluate(f"{NOTEBOOK}.context.save().then(() => true)")
        browser.call("Page.reload")
        time.sleep(3)  # the old page's context goes away while the new one loads
        browser.wait_for(
            f"{KERNEL_IDLE} && document.querySelectorAll('.jp-Notebook .jp-Cell').length === {cells}",
            f"{chapter} to open again",
            timeout=180,
        )
        browser.evaluate(f"{COLLAPSED}, true")
        problems += [
            f"reopened, cell {p['cell']}: a picture laid out at {p['width']:.0f} x {p['height']:.0f} px"
            for p in browser.evaluate(PICTURES)
            if p["width"] < 1 or p["height"] < 1
        ]
        try:
            browser.wait_for(
                f"{SCENES_NOT_DRAWN}.then(cells => cells.length === 0)", f"{chapter}'s 3-D scenes", timeout=60
            )
        except AssertionError:
            problems.append(f"reopened, the 3-D scenes of cells {browser.evaluate(SCENES_NOT_DRAWN)} drew nothing")
        assert problems == [], f"{chapter}: " + "; ".join(problems)
