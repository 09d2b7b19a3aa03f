"""The dashboard during a cold start (issue 28 item 5), in headless Chromium: `serve` on the demo log with an empty
numba cache (a fresh install) compiles its kernels for a minute or two before the first cycle. Meanwhile the page
says "compiling the numerical kernels (first run only)", shows no "HTTP 503" panel and no green "live" badge, and the
terminal prints the compile's progress. The server is stopped once that is seen (the compile itself is not waited
for: tests/service/test_startup_state.py checks the end of the start on the API).

Chromium comes from scripts/install-chromium.sh; without it the module skips with the reason."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from tests.service.dashboard_browser import Chromium, find_chromium, free_port
from tests.service.serve_helpers import stop_server

if find_chromium() is None:
    pytest.skip("no chromium on PATH: scripts/install-chromium.sh installs Debian's", allow_module_level=True)

REPO = Path(__file__).resolve().parents[2]
COMPILING = "compiling the numerical kernels (first run only)"
pytestmark = pytest.mark.timeout(300)



@pytest.fixture(scope="module")
def cold_server(tmp_path_factory: pytest.TempPathFactory):
    tmp = tmp_path_factory.mktemp("cold")
    port = free_port()
    log = tmp / "serve.log"
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp / "numba-cache")}  # empty: every kernel compiles
    cmd = [sys.executable, "-m", "frictionwatch.service.cli", "serve", "--host", "127.0.0.1", "--port", str(port),
           "--source", "mcap:replay_logs/demo.mcap?loop=1&speed=1"]
    with log.open("wb") as out:
        proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            assert proc.poll() is None, log.read_text()[-2000:]
            try:
                if httpx.get(f"{base}/api/v1/startup", timeout=5).json()["state"] == "compiling":
                    break
            except (httpx.HTTPError, ValueError):
                pass
            time.sleep(0.25)
        else:
            pytest.fail(f"the server never said it was compiling: {log.read_text()[-2000:]}")
        yield {"base": base, "proc": proc, "log": log}
    finally:
        stop_server(proc)


def test_a_cold_start_says_it_compiles_instead_of_showing_503(cold_server, tmp_path):
    base = cold_server["base"]
    with Chromium.start(tmp_path / "profile") as browser:
        page = browser.new_page(width=1400, height=1000)
        page.navigate(f"{base}/")
        page.wait_for("!document.getElementById('startup').hidden", timeout=30)
        page.wait_for(f"document.getElementById('losses-plot').textContent.includes({COMPILING!r})", timeout=30)
        time.sleep(2.0)  # the panels' own requests (each route answers 503 until the first cycle) have come back
        said = page.evaluate("""(() => ({
            banner: document.getElementById('startup').textContent,
            live: document.getElementById('live').dataset.state,
            liveText: document.getElementById('live-text').textContent,
            errors: [...document.querySelectorAll('.error')].filter(p => !p.hidden).map(p => p.textContent),
            panels: ['losses-plot', 'torque-plot', 'speed-plot'].map(id => document.getElementById(id).textContent),
            body: document.body.innerText }))()""")
        requests = page.requests
    assert httpx.get(f"{base}/api/v1/startup", timeout=5).json()["state"] == "compiling", "the compile ended early"
    assert any("/api/v1/engines/" in u and u.endswith("/losses") for u in requests)  # the 503 routes were asked
    assert said["banner"].startswith(COMPILING)
    assert said["errors"] == [] and "503" not in said["body"]
    assert said["live"] == "starting" and said["liveText"] == "starting…"  # not a green "live" beside no figures
    assert all(COMPILING in p for p in said["panels"]), said["panels"]
    # the terminal: the ticker's line every few seconds
    deadline = time.monotonic() + 15
    while COMPILING not in cold_server["log"].read_text() and time.monotonic() < deadline:
        time.sleep(0.5)
    assert f"frictionwatch serve: {COMPILING}: " in cold_server["log"].read_text()
