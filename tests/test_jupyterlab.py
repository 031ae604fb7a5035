"""The notebooks as a person runs them: JupyterLab from the project's environment, driven through headless
Chromium (Debian's ``chromium`` and ``chromium-driver``, selenium from the test extras). Two notebooks are opened
(neither may show as modified), run with Run All, and every cell must finish without an error or a stderr
output; the notebook with an evaluation must draw its progress bar as a widget.

The notebooks run on copies in a temporary folder, so JupyterLab's autosave never touches the checkout; their
figures go to a temporary ``CTXMATCH_FIGURES``. Skipped, with the reason, where the browser, its driver or
selenium is missing (``.ci/run`` installs the browser).
"""

import json
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")

#: The notebooks run: the toy blob table (no evaluation) and the filter tables (an evaluation with a progress bar).
NOTEBOOKS = ("fig_blob_toy.ipynb", "tables.ipynb")
#: Seconds a notebook may take under Run All (with the evaluation cache of a previous run: about 15 s).
RUN_TIMEOUT_S = 600

pytestmark = pytest.mark.slow


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """A JupyterLab server on a loopback port, its root a folder with copies of :data:`NOTEBOOKS`."""
    pytest.importorskip("selenium", reason="selenium is not installed (the test extras of the Makefile)")
    if not CHROMIUM or not DRIVER:
        pytest.skip("chromium and chromedriver are not installed (Debian: apt-get install chromium chromium-driver)")
    root = tmp_path_factory.mktemp("lab")
    for name in NOTEBOOKS:
        shutil.copy(ROOT / "notebooks" / name, root / name)
    port, token = _free_port(), "ctxmatch-test"
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}  # the kernel draws inline, as in `make lab`
    env["CTXMATCH_FIGURES"] = str(root / "figures")
    cmd = [sys.executable, "-m", "jupyter", "lab", "--no-browser", f"--port={port}", "--ServerApp.ip=127.0.0.1",
           f"--IdentityProvider.token={token}", f"--ServerApp.root_dir={root}", "--expose-app-in-browser",
           "--LabApp.news_url=None", "--LabApp.check_for_updates_class=jupyterlab.NeverCheckForUpdate"]
    if hasattr(os, "getuid") and os.getuid() == 0:
        cmd.append("--allow-root")
    log = open(root / "lab.log", "w")
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=root)
    url = f"http://127.0.0.1:{port}"
    try:
        for _ in range(120):
            if proc.poll() is not None:
                pytest.fail(f"jupyter lab exited: {(root / 'lab.log').read_text()[-2000:]}")
            try:
                urllib.request.urlopen(f"{url}/api/status?token={token}", timeout=2)
                break
            except OSError:
                time.sleep(0.5)
        else:
            pytest.fail(f"jupyter lab did not answer in 60 s: {(root / 'lab.log').read_text()[-2000:]}")
        yield url, token, root
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()


@pytest.fixture(scope="module")
def browser(lab):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1400,1000"):
        options.add_argument(arg)
    driver = webdriver.Chrome(service=Service(DRIVER), options=options)
    yield driver
    driver.quit()


#: The open notebook's cells as JupyterLab's models hold them: type, execution count and outputs.
CELLS_JS = """
const panel = window.jupyterapp.shell.currentWidget;
if (!panel || !panel.content || !panel.context) { return null; }
const cells = panel.content.widgets.map(c => ({
    type: c.model.type,
    count: c.model.type === 'code' ? c.model.executionCount : null,
    outputs: c.model.type === 'code' ? c.model.outputs.toJSON() : []}));
const kernel = panel.sessionContext.session ? panel.sessionContext.session.kernel : null;
return JSON.stringify({path: panel.context.path, dirty: panel.context.model.dirty, cells: cells,
                       kernel: kernel ? kernel.status : null});
"""


def _state(driver):
    raw = driver.execute_script(CELLS_JS)
    return json.loads(raw) if raw else None


def _wait(predicate, timeout: float, what: str):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        value = predicate()
        if value:
            return value
        time.sleep(0.5)
    pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}")


@pytest.mark.parametrize("name", NOTEBOOKS)
def test_run_all_in_jupyterlab_without_an_error_or_stderr(lab, browser, name):
    url, token, root = lab
    browser.get(f"{url}/lab/tree/{name}?token={token}")
    _wait(lambda: browser.execute_script("return typeof window.jupyterapp !== 'undefined'"), 60, "JupyterLab")
    opened = _wait(lambda: (s := _state(browser)) and s["path"] == name and s["kernel"] == "idle" and s, 120,
                   f"{name} open with an idle kernel")
    assert not opened["dirty"], f"{name} shows as modified as soon as it opens"
    browser.execute_script("window.jupyterapp.commands.execute('notebook:run-all-cells');")

    def finished():
        s = _state(browser)
        done = s and s["kernel"] == "idle" and all(c["count"] is not None for c in s["cells"] if c["type"] == "code")
        return s if done else None

    state = _wait(finished, RUN_TIMEOUT_S, f"Run All of {name}")
    problems = []
    for i, cell in enumerate(state["cells"]):
        for out in cell["outputs"]:
            if out["output_type"] == "error":
                problems.append(f"cell {i}: {out['ename']}: {out['evalue']}")
            elif out["output_type"] == "stream" and out["name"] == "stderr":
                problems.append(f"cell {i}: stderr {''.join(out['text'])[:300]!r}")
    assert not problems, f"{name}: {problems}"
    if any("progress=True" in "".join(c["source"]) for c in json.loads((root / name).read_text())["cells"]):
        widgets = [o for c in state["cells"] for o in c["outputs"]
                   if "application/vnd.jupyter.widget-view+json" in o.get("data", {})]
        assert widgets, f"{name}: the progress bar is not a widget"
        assert browser.find_elements("css selector", ".widget-hprogress, .jupyter-widgets.widget-progress"), \
            f"{name}: no progress widget rendered"
