"""The engine's own page on the Dask dashboard: a run's progress, live, at `/radiosity`.

Design notes and measurements: docs/src/design/runtime-dashboard.md.
"""

from __future__ import annotations

import html
import logging
import math
import time
from urllib.parse import urlsplit, urlunsplit

logger = logging.getLogger(__name__)

PATH = "/radiosity"
NAME = PATH.strip("/")
INTERVAL_MS = 500
SIZE = 430  # pixels, each of the three panels

_ATTR = "_radiosity_dashboard"


# ----------------------------------------------------------------------------- registration

def _dask_bokeh_app(scheduler):
    """Dask's own Bokeh server application on this scheduler, or None (dashboard off)."""
    http = getattr(scheduler, "http_application", None)
    for app in getattr(http, "applications", ()):
        if hasattr(app, "app_paths") and "/status" in app.app_paths:
            return app
    return None


def register(scheduler) -> bool:
    """Add the page to `scheduler`'s dashboard; True if it is (or already was) there.

    Call it on the scheduler's event loop: from a preload (`dask_setup`), or with
    `client.run_on_scheduler(register)`. Idempotent."""
    if getattr(scheduler, _ATTR, None) is not None:
        return True
    try:
        from tornado.ioloop import IOLoop

        from distributed.dashboard.core import BokehApplication
        from distributed.dashboard.scheduler import template_variables
    except ImportError as e:  # no bokeh: Dask has no dashboard either
        logger.warning("radiosity dashboard page not added: %s", e)
        return False
    dask_app = _dask_bokeh_app(scheduler)
    if dask_app is None:
        logger.info("radiosity dashboard page not added: the scheduler has no dashboard")
        return False
    tv = template_variables(scheduler)  # memoised per scheduler; Dask's pages share the list
    pages = tv.get("pages") if isinstance(tv, dict) else None
    if isinstance(pages, list) and NAME not in pages:
        pages.append(NAME)  # the menu bar entry, on Dask's pages and on ours
    app = BokehApplication({PATH: radiosity_doc}, scheduler, prefix=dask_app.prefix,
                           template_variables=tv)
    scheduler.http_application.add_application(app)  # stopped with Dask's at scheduler close
    app.initialize(IOLoop.current())
    app.start()
    setattr(scheduler, _ATTR, app)
    logger.info("radiosity dashboard page at %s%s", dask_app.prefix, PATH)
    return True


def dask_setup(scheduler) -> None:
    """Scheduler preload hook: `dask scheduler --preload radiosity.runtime.dashboard`."""
    register(scheduler)


def dashboard_link(client) -> str:
    """The link to Dask's dashboard (/status) that answers.

    Dask builds `client.dashboard_link` from the scheduler's address. With workers as threads
    that address is inproc://HOST/..., HOST the machine's network address, while the dashboard
    listens where `cluster.dashboard-address` says (127.0.0.1): the link was refused. For a
    scheduler in this process the link takes the host its dashboard is bound to."""
    from distributed.utils import format_dashboard_link

    link = client.dashboard_link
    scheduler = getattr(getattr(client, "cluster", None), "scheduler", None)
    server = getattr(scheduler, "http_server", None)
    host, port = getattr(server, "address", None), getattr(server, "port", None)
    if not link or not host or not port or host in ("0.0.0.0", "::"):
        return link  # not in this process, or on every interface: Dask's host is as good
    return format_dashboard_link(f"[{host}]" if ":" in host else host, port)


def page_url(client) -> str:
    """URL of the page, from dashboard_link (which ends in /status)."""
    parts = urlsplit(dashboard_link(client))
    path = parts.path
    base = path[: -len("/status")] if path.rstrip("/").endswith("/status") else path.rstrip("/")
    return urlunsplit(parts._replace(path=base.rstrip("/") + PATH, query="", fragment=""))


# ----------------------------------------------------------------------------- the page

def _metadata(scheduler, key: str):
    try:
        return scheduler.get_metadata(["radiosity", key], default=None)
    except Exception:  # metadata is whatever a client put there
        return None


class RadiosityPage:
    """The page's models; `update()` pulls the scheduler's metadata into them."""

    def __init__(self, scheduler):
        import numpy as np
        from bokeh.layouts import column, row
        from bokeh.models import (BasicTicker, ColorBar, ColumnDataSource, Div, HoverTool,
                                  LinearColorMapper, Range1d)
        from bokeh.palettes import Viridis256
        from bokeh.plotting import figure

        self.np = np
        self.scheduler = scheduler
        self._seen: dict = {}

        self.header = Div(name="radiosity-run", text=self._header_html(None),
                          sizing_mode="stretch_width")

        # visibility heat map: image rows are I (drawn top-down), columns J
        self.heat_source = ColumnDataSource({"image": [np.full((1, 1), -1.0)], "x": [0], "y": [0],
                                             "dw": [1], "dh": [1]})
        mapper = LinearColorMapper(palette=Viridis256, low=0.0, high=1.0, low_color="#eeeeee",
                                   nan_color="#eeeeee")
        self.heat = figure(name="radiosity-visibility", title="Visibility: no run yet",
                           width=SIZE, height=SIZE, x_range=Range1d(0, 1), y_range=Range1d(1, 0),
                           tools="pan,wheel_zoom,box_zoom,reset,save", toolbar_location="above",
                           x_axis_label="original element J", y_axis_label="original element I")
        self.heat.image(image="image", x="x", y="y", dw="dw", dh="dh", color_mapper=mapper,
                        source=self.heat_source)
        self.heat.add_tools(HoverTool(tooltips=[("J", "$x{0}"), ("I", "$y{0}"),
                                                ("done", "@image{0.000}")]))
        self.heat.add_layout(ColorBar(color_mapper=mapper, width=10, title="fraction done"),
                             "right")
        self.heat.grid.visible = False
        for axis in (self.heat.xaxis, self.heat.yaxis):
            axis.ticker = BasicTicker(min_interval=1)  # element indices are integers
        self.heat.toolbar.autohide = True

        # solver residual per pass
        self.res_source = ColumnDataSource({"pass": [], "residual": []})
        self.residual = figure(name="radiosity-residual", title="Solver residual: not started",
                               width=SIZE, height=SIZE, y_axis_type="log",
                               tools="pan,wheel_zoom,box_zoom,reset,save", toolbar_location="above",
                               x_axis_label="pass", y_axis_label="relative residual")
        self.residual.line("pass", "residual", source=self.res_source, line_width=2)
        self.residual.scatter("pass", "residual", source=self.res_source, size=6)
        self.residual.add_tools(HoverTool(tooltips=[("pass", "@pass"),
                                                    ("residual", "@residual{0.000e}")]))
        self.residual.xaxis.ticker = BasicTicker(min_interval=1)
        self.residual.toolbar.autohide = True

        # current image
        self.preview = Div(name="radiosity-preview", text=self._preview_html(None),
                           width=SIZE, height=SIZE + 40)

        self.root = column(self.header, row(self.heat, self.residual, self.preview),
                           sizing_mode="stretch_width")

    # -- html pieces
    @staticmethod
    def _header_html(run) -> str:
        if not run:
            return ('<h2 class="radiosity-stage" style="margin:4px 0">Radiosity: no run yet</h2>'
                    '<div>Waiting for a run to publish its progress to this scheduler.</div>')
        stage = html.escape(str(run.get("stage") or "?"))
        scene = html.escape(str(run.get("scene") or ""))
        run_dir = html.escape(str(run.get("run_dir") or ""))
        t = run.get("time")
        since = time.strftime("%H:%M:%S", time.localtime(t)) if isinstance(t, (int, float)) else ""
        return (f'<h2 class="radiosity-stage" style="margin:4px 0">Radiosity: {stage}'
                + (f" &mdash; {scene}" if scene else "") + "</h2>"
                f'<div>run directory <code class="radiosity-run-dir">{run_dir}</code>'
                + (f" &middot; stage since {since}" if since else "") + "</div>")

    @staticmethod
    def _preview_html(pv) -> str:
        head = '<div style="font-weight:bold;margin-bottom:6px">Current image'
        if not pv or not pv.get("png"):
            return head + "</div><div>no image yet</div>"
        w, h = int(pv.get("width") or 1), int(pv.get("height") or 1)
        scale = SIZE / max(w, h, 1)
        return (head + f" ({w}&times;{h})</div>"
                f'<img class="radiosity-preview" alt="current image" '
                f'width="{max(1, round(w * scale))}" height="{max(1, round(h * scale))}" '
                'style="image-rendering:pixelated;border:1px solid #ccc" '
                f'src="data:image/png;base64,{pv["png"]}"/>')

    # -- updates
    def _changed(self, key: str):
        """The key's value if it changed since the last update (the object is replaced on every
        set_metadata, so identity is enough), else None."""
        value = _metadata(self.scheduler, key)
        if value is None or self._seen.get(key) is value:
            return None
        self._seen[key] = value
        return value

    def update(self) -> None:
        run = self._changed("run")
        if run is not None:
            self.header.text = self._header_html(run if isinstance(run, dict) else None)
        vis = self._changed("visibility")
        if isinstance(vis, dict):
            self._update_visibility(vis)
        sol = self._changed("solve")
        if isinstance(sol, dict):
            self._update_solve(sol)
        pv = self._changed("preview")
        if isinstance(pv, dict):
            self.preview.text = self._preview_html(pv)

    def _update_visibility(self, vis: dict) -> None:
        np = self.np
        done = np.asarray(vis.get("done") or [[-1.0]], dtype=float)
        if done.ndim != 2:
            return
        n = max(1, int(vis.get("n") or done.shape[0]))
        # image rows go upwards from y; the y range is flipped, so row 0 (I = 0) is at the top
        self.heat_source.data = {"image": [done], "x": [0], "y": [0], "dw": [n], "dh": [n]}
        if self.heat.x_range.end != n:
            self.heat.x_range.update(start=0, end=n)
            self.heat.y_range.update(start=n, end=0)
        td, tt = int(vis.get("tasks_done") or 0), int(vis.get("tasks") or 0)
        pct = f" ({100.0 * td / tt:.0f} %)" if tt else ""
        self.heat.title.text = vis.get("title") or f"Visibility blocks done: {td} / {tt} tasks{pct}, {n} originals"

    def _update_solve(self, sol: dict) -> None:
        res = [float(r) for r in sol.get("residuals") or []]
        k = [i + 1 for i, r in enumerate(res) if math.isfinite(r) and r > 0]
        self.res_source.data = {"pass": k, "residual": [res[i - 1] for i in k]}
        last = f", pass {len(res)}: {res[-1]:.2e}" if res else ""
        self.residual.title.text = (f"Solver residual ({sol.get('solver', '?')}, "
                                    f"{sol.get('kernel', '?')} kernel){last}")


def radiosity_doc(scheduler, extra, doc) -> None:
    """Bokeh document factory, called once per browser session: (scheduler, extra, doc)."""
    from distributed.dashboard.components import add_periodic_callback
    from distributed.dashboard.components.scheduler import BOKEH_THEME, env

    page = RadiosityPage(scheduler)
    page.update()
    add_periodic_callback(doc, page, INTERVAL_MS)
    doc.title = "Dask: Radiosity"
    doc.add_root(page.root)
    doc.template = env.get_template("simple.html")
    doc.template_variables.update(extra)
    doc.theme = BOKEH_THEME
