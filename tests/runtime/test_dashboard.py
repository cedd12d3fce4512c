"""The radiosity page on the Dask dashboard, end to end: a LocalCluster from radiosity.cluster (dashboard
on 127.0.0.1, port 0, page added by the scheduler preload), a tiny real run publishing its
progress, and the page loaded and screenshotted in headless Chromium over the DevTools protocol
(plain `chromium --screenshot` would catch the page before Bokeh has drawn anything)."""

from __future__ import annotations

import asyncio
import base64
import json
import os
import shutil
import subprocess
import tempfile
import time

import pytest

from helpers import CHROMIUM, ROOT, scene_path, stop_process
from radiosity.settings import options as settings_of

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--hide-scrollbars", "--remote-debugging-address=127.0.0.1", "--remote-debugging-port=0"]
WIDTH, HEIGHT = 1400, 620

# Bokeh 3 renders into shadow roots: search through them. Plot titles are drawn on canvases, so
# they are read from the Bokeh document (the models synced over the websocket), by model name.
PAGE_STATE = """(() => {
  const all = [];
  const walk = (root) => { for (const el of root.querySelectorAll('*')) {
      all.push(el); if (el.shadowRoot) walk(el.shadowRoot); } };
  walk(document);
  const doc = window.Bokeh && Bokeh.documents && Bokeh.documents[0];
  const title = (name) => { const m = doc && doc.get_model_by_name(name);
      return m && m.title ? m.title.text : null; };
  const text = (name) => { const m = doc && doc.get_model_by_name(name);
      return m ? m.text : null; };
  const imgs = all.filter((e) => e.tagName === 'IMG' && e.classList.contains('radiosity-preview'));
  return {
    idle: !!(doc && doc.is_idle),
    canvases: all.filter((e) => e.tagName === 'CANVAS' && e.width > 0 && e.height > 0).length,
    preview: imgs.length ? {src: imgs[0].src.slice(0, 22), w: imgs[0].naturalWidth,
                            complete: imgs[0].complete} : null,
    visibility_title: title('radiosity-visibility'),
    residual_title: title('radiosity-residual'),
    run_html: text('radiosity-run'),
    nav: Array.from(document.querySelectorAll('.navbar a')).map((a) => a.textContent.trim()),
    doc_title: document.title,
  };
})()"""


class DevTools:
    """The smallest DevTools-protocol client: one page target over tornado's websocket."""

    def __init__(self, ws):
        self.ws = ws
        self.n = 0

    async def call(self, method: str, timeout: float = 20.0, **params):
        self.n += 1
        mid = self.n
        await self.ws.write_message(json.dumps({"id": mid, "method": method, "params": params}))
        deadline = time.monotonic() + timeout
        while True:
            msg = await asyncio.wait_for(self.ws.read_message(), deadline - time.monotonic())
            if msg is None:
                raise RuntimeError("DevTools connection closed")
            data = json.loads(msg)
            if data.get("id") == mid:  # events (no id) are dropped
                if "error" in data:
                    raise RuntimeError(f"{method}: {data['error']}")
                return data.get("result", {})

    async def evaluate(self, expr: str):
        r = await self.call("Runtime.evaluate", expression=expr, returnByValue=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"page script failed: {r['exceptionDetails']}")
        return r["result"].get("value")

    async def wait_for(self, expr_ok, timeout: float, what: str):
        deadline = time.monotonic() + timeout
        state = None
        while time.monotonic() < deadline:
            state = await self.evaluate(PAGE_STATE)
            if state and expr_ok(state):
                return state
            await asyncio.sleep(0.2)
        raise AssertionError(f"page never showed {what}; last state: {state}")


def _start_chromium(profile: str) -> tuple[subprocess.Popen, int]:
    proc = subprocess.Popen([CHROMIUM, *FLAGS, f"--user-data-dir={profile}",
                             f"--window-size={WIDTH},{HEIGHT}", "about:blank"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    port_file = os.path.join(profile, "DevToolsActivePort")  # written once it listens
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"chromium exited with status {proc.returncode}")
        try:
            with open(port_file) as f:
                port = int(f.readline())
            return proc, port
        except (OSError, ValueError):
            time.sleep(0.05)
    proc.kill()
    raise RuntimeError("chromium did not open its DevTools port in 20 s")


async def _page_target(port: int) -> str:
    from tornado.httpclient import AsyncHTTPClient

    http = AsyncHTTPClient()
    for _ in range(100):
        r = await http.fetch(f"http://127.0.0.1:{port}/json/list", raise_error=False)
        if r.code == 200:
            pages = [t for t in json.loads(r.body) if t.get("type") == "page"]
            if pages:
                return pages[0]["webSocketDebuggerUrl"]
        await asyncio.sleep(0.05)
    raise RuntimeError("no page target in chromium")


async def _browse(port: int, url: str, publish_later) -> tuple[dict, dict, bytes]:
    from tornado.websocket import websocket_connect

    ws = await websocket_connect(await _page_target(port), max_message_size=64 << 20)
    try:
        dt = DevTools(ws)
        await dt.call("Emulation.setDeviceMetricsOverride", width=WIDTH, height=HEIGHT,
                      deviceScaleFactor=1, mobile=False)
        await dt.call("Page.navigate", url=url)

        def drawn(s):
            return (s["idle"] and s["canvases"] >= 2 and s["preview"] is not None
                    and s["preview"]["complete"] and s["preview"]["w"] > 0
                    and (s["visibility_title"] or "").startswith("Visibility blocks done")
                    and "pass" in (s["residual_title"] or ""))

        state = await dt.wait_for(drawn, 20, "its plots drawn")
        await asyncio.sleep(0.3)  # one more frame for the canvases
        shot = await dt.call("Page.captureScreenshot", format="png")
        # live: a new stage published now reaches the open page via the periodic callback
        await asyncio.to_thread(publish_later)  # a sync Client call, off this event loop
        live = await dt.wait_for(lambda s: "image" in (s["run_html"] or ""), 10,
                                 "the new stage (periodic update)")
        return state, live, base64.b64decode(shot["data"])
    finally:
        ws.close()


@pytest.mark.filterwarnings("ignore::radiosity.formats.raw.SceneWarning")  # the published red wall
@pytest.mark.needs("chromium")
def test_dashboard_page_in_chromium(tmp_path):
    import dask

    from radiosity.runtime.cluster import open_client
    from radiosity.runtime.dashboard import PATH, page_url
    from radiosity.runtime.monitor import Monitor
    from radiosity.stages.preprocess import preprocess
    from radiosity.scene.load import load_scene
    from radiosity.stages.solve import run_solve
    from radiosity.methods.pairs.visibility import compute_visibility

    t0 = time.perf_counter()
    out = str(tmp_path / "run")
    lines: list[str] = []
    with dask.config.set({"radiosity.cluster.host": "127.0.0.1",
                          "radiosity.cluster.dashboard-address": "127.0.0.1:0"}), \
            open_client(workers=1, kind="local", echo=lines.append, settings=settings_of().cluster) as client:
        url = page_url(client)
        assert url.startswith("http://127.0.0.1:") and url.endswith(PATH)
        assert f"radiosity page: {url}" in lines, lines
        t_cluster = time.perf_counter() - t0

        # a tiny real run publishes every key: run, visibility, solve, preview
        sc = load_scene(scene_path("cornell-box"), resolution=16, settings=settings_of())  # 20 originals, 9 CG passes
        preprocess(sc, out, client, settings_of(), progress=False)
        compute_visibility(out, client, settings_of(), progress=False)
        run_solve(out, client, settings_of(), progress=False)
        assert client.get_metadata(["radiosity", "preview"])["png"]
        t_run = time.perf_counter() - t0 - t_cluster

        profile = tempfile.mkdtemp(prefix="chromium-", dir=tmp_path)
        proc, port = _start_chromium(profile)
        try:
            state, live, png = asyncio.run(_browse(
                port, url, lambda: Monitor(client).stage("image", out, "cornell-box")))
        finally:
            stop_process(proc, 10)
        t_browser = time.perf_counter() - t0 - t_cluster - t_run

    (tmp_path / "dashboard.png").write_bytes(png)
    if os.environ.get("RADIOSITY_UPDATE_DOCS"):  # refresh the docs' screenshot on request only
        shutil.copyfile(tmp_path / "dashboard.png", os.path.join(ROOT, "docs", "src", "images", "dashboard.png"))
    print(f"cluster {t_cluster:.1f} s, run {t_run:.1f} s, browser {t_browser:.1f} s")

    # the screenshot is a real PNG of the requested size
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    w, h = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
    assert (w, h) == (WIDTH, HEIGHT)
    # the page: Dask's menu bar with our entry, two Bokeh plots, the preview image, the run
    assert state["doc_title"] == "Dask: Radiosity"
    assert "Radiosity" in state["nav"] and "Status" in state["nav"]
    assert state["canvases"] >= 2
    assert state["preview"]["src"].startswith("data:image/png;base64")
    assert state["visibility_title"].startswith("Visibility blocks done")
    done, total = state["visibility_title"].split(": ", 1)[1].split(" tasks")[0].split(" / ")
    assert done == total and int(total) >= 1, state["visibility_title"]
    assert state["residual_title"].startswith("Solver residual (cg, point-nf kernel), pass ")
    assert "solve" in state["run_html"]
    assert os.path.basename(out) in live["run_html"] and "image" in live["run_html"]


def test_printed_links_answer_for_workers_as_threads():
    """Workers as threads: the scheduler's address is inproc://HOST/..., HOST the machine's
    network address, and Dask's link named HOST while the dashboard listens on 127.0.0.1 (the
    link was refused). Both printed links are fetched."""
    import urllib.request

    from radiosity.runtime.cluster import open_client
    from radiosity.runtime.dashboard import PATH

    lines: list[str] = []
    with open_client(1, kind="local", in_process=True, echo=lines.append,
                     settings=settings_of().cluster) as client:
        assert client.scheduler.address.startswith("inproc://")
        links = {line.split(": ", 1)[0]: line.split(": ", 1)[1] for line in lines if ": http" in line}
        assert links["dashboard"].startswith("http://127.0.0.1:"), lines
        assert links["radiosity page"].endswith(PATH), lines
        for url in links.values():
            with urllib.request.urlopen(url, timeout=30) as page:
                assert page.status == 200 and b"<html" in page.read().lower(), url
