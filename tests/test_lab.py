"""The chapters with widgets as a student uses them: JupyterLab in headless Chromium, Run All, then every slider
moved by the keyboard.

Each chapter is run from a folder written by ``python -m vdtutorial notebooks DEST`` in quick mode. After Run
All, the test moves each slider one step and checks that the picture the slider drives is redrawn and that its
readout changed, and that no text beside a slider runs past its box (a long ``Label`` is cut at the window's
edge); throughout, it records every error the kernel reports, in a cell or in a widget's callback (the
latter reach only JupyterLab's Log Console, never the notebook). Chromium is driven over the DevTools protocol
as in ``test_book.py``; JupyterLab is started with ``expose_app_in_browser`` so that the page's
``window.jupyterapp`` can run the notebook's commands.
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

#: The chapters with sliders, and how many sliders each shows.
WIDGET_CHAPTERS = {"03_demonstrations": 1, "05_pretraining": 1, "07_finetuning": 1}
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
#: Every slider's readout and the pictures of the widget box it sits in.
SLIDERS = """[...document.querySelectorAll('.jp-OutputArea .widget-slider')].map(s => {
    const box = s.closest('.widget-vbox') || s.parentElement;
    return {readout: (s.querySelector('.widget-readout') || {}).textContent || '',
            pictures: [...box.querySelectorAll('img')].map(i => i.src),
            labels: [...box.querySelectorAll('.widget-label')].map(l => l.textContent),
            cut: [...box.querySelectorAll('.widget-label, .widget-html-content')]
                .filter(t => t.scrollWidth > t.clientWidth + 1).map(t => t.textContent)}; })"""


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
    env = {**os.environ, "VDTUTORIAL_QUICK": "1", "MPLBACKEND": "module://matplotlib_inline.backend_inline",
           "JUPYTER_CONFIG_DIR": str(home / "config"), "JUPYTERLAB_WORKSPACES_DIR": str(home / "workspaces"),
           "JUPYTER_RUNTIME_DIR": str(home / "runtime")}
    server = subprocess.Popen(
        [sys.executable, "-m", "jupyterlab", "--no-browser", f"--port={port}", "--ServerApp.ip=127.0.0.1",
         "--IdentityProvider.token=", "--ServerApp.password=", f"--ServerApp.root_dir={home / 'book'}",
         "--ServerApp.allow_root=True", "--LabApp.expose_app_in_browser=True", "--LabApp.news_url=None",
         "--LabApp.check_for_updates_class=jupyterlab.NeverCheckForUpdate"],
        env=env, stdout=subprocess.DEVNULL, stderr=open(home / "server.log", "w"))
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


@pytest.mark.parametrize("chapter", sorted(WIDGET_CHAPTERS))
def test_every_slider_redraws_after_run_all_and_no_error_reaches_the_log(lab, chapter):
    executable, url = lab
    with Chromium(executable, offline=False) as browser:
        browser.call("Page.navigate", url=f"{url}/lab/tree/notebooks/{chapter}.ipynb?reset")
        browser.wait_for(KERNEL_IDLE, f"{chapter}'s kernel", timeout=180)
        browser.evaluate(RECORD_ERRORS)
        browser.evaluate(RUN_ALL)
        browser.wait_for(f"window.__ranAll && {KERNEL_IDLE}", f"Run All of {chapter}", timeout=900)
        sliders = browser.evaluate(SLIDERS)
        assert len(sliders) == WIDGET_CHAPTERS[chapter] and all(s["pictures"] for s in sliders), sliders
        for k, before in enumerate(sliders):
            browser.evaluate(f"""(() => {{ const h = document.querySelectorAll('.jp-OutputArea .widget-slider')[{k}]
                .querySelector('.noUi-handle'); h.scrollIntoView({{block: 'center'}}); h.focus();
                return document.activeElement === h; }})()""")
            for kind in ("keyDown", "keyUp"):  # one step down: every slider starts above its lowest value
                browser.call("Input.dispatchKeyEvent", type=kind, key="ArrowLeft", code="ArrowLeft",
                             windowsVirtualKeyCode=37)
            redrawn = f"""(() => {{ const now = ({SLIDERS})[{k}];
                return now.readout !== {json.dumps(before['readout'])}
                    && JSON.stringify(now.pictures) !== {json.dumps(json.dumps(before['pictures']))}; }})()"""
            try:
                browser.wait_for(redrawn, f"{chapter}'s slider {k} to redraw its picture", timeout=120)
            except AssertionError as timeout:
                raise AssertionError(f"{timeout}; the kernel reported: {browser.evaluate('window.__errors')}") from None
            browser.wait_for(KERNEL_IDLE, f"{chapter}'s kernel after the slider moved", timeout=300)
        cut = [text for slider in browser.evaluate(SLIDERS) for text in slider["cut"]]
        assert cut == [], f"{chapter}: text beside a slider is cut at the window's edge (1280 px): {cut}"
        errors = browser.evaluate("window.__errors")
        assert errors == [], f"{chapter}: the kernel reported errors: {errors}"
