"""The leaves' first bounce when emitters are handled at points (SPEC §10): L1 of a leaf is the
mean over stratified points of the leaf of rho H1 / pi, H1 from scene/direct.DirectLight, per
side. The solve then takes L1 as its right-hand side in place of Le (the links carry only
light after its first bounce) and Le is added back at the end.

Real scenes have 10^4 - 2 10^5 leaves, each with a few points and shadow rays per point and
emitter, so this is a stage (DirectStage, on the one stage master) like the link stage: tasks
over runs of consecutive leaves balanced by points x emitters, each task's L1 one array of the
run store's group direct/ (store.DirectStore) with a manifest, so a killed run resumes with the
tasks already done; small scenes (or no client) compute in process. Each point's sample offsets
hash from its number among all the leaves' points, so both paths give the same bits.
Design: docs/src/design/methods-hierarchical-direct.md.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from radiosity.runtime.cluster import scatterable
from radiosity.runtime.stage import StageMaster, StagePlan, TaskFigures
from radiosity.scene.direct import DirectLight
from radiosity.scene.luminaires import luminaires_of

#: Stratified points per leaf (a square), where the leaf is small against its distance to the
#: emitters (the default of settings.direct.leaf_points).
LEAF_POINTS = 4
#: Shadow rays per point and emitter (the default of settings.direct.samples).
SAMPLES = 16
#: At most this many strata a side on a leaf that is large against its distance to the nearest
#: emitter (leaf_strata: up to 64 points).
MAX_STRATA = 8
#: A leaf takes strata of at most this fraction of its distance to the nearest emitter.
STRATUM_OVER_DISTANCE = 0.5
#: The points leaf_strata may add, as a fraction of the default points of all the leaves.
EXTRA_POINTS = 1.0
#: ... or at least this many (a scene of few leaves).
EXTRA_MIN = 1 << 14
#: Point x emitter pairs per task at most (about SAMPLES shadow rays each: ~1 s of one thread).
TASK_PAIRS = 1 << 19
#: Tasks at least, when the pairs allow (for the master to balance).
MIN_TASKS = 16
#: Point x emitter pairs below which where="auto" computes in process (a stage costs ~1 s).
LOCAL_PAIRS = 1 << 17
#: Task counters (report.json).
COUNTERS = ("points", "shadow_rays")
#: Part of the token: changes when the stage's arithmetic does.
VERSION = 1


def direct_settings(settings) -> tuple[int, int]:
    """(samples, leaf_points) of settings.direct (until that section exists: the defaults)."""
    d = getattr(settings, "direct", None)
    return int(getattr(d, "samples", SAMPLES)), int(getattr(d, "leaf_points", LEAF_POINTS))


# ----------------------------------------------------------------------------- points (pure)

def leaf_strata(table: dict, elements, k: int = LEAF_POINTS, adaptive: bool = True) -> np.ndarray:
    """(M,) int64 strata a side s per leaf (s^2 points): isqrt(k), more on a leaf whose size
    (its polygon's diameter) exceeds STRATUM_OVER_DISTANCE s times its gap to the nearest
    emitter that can light it (the distance from its centre to the polygons of the 8 emitters
    nearest by centre, less half the leaf; not one whose plane holds the leaf, nor one the leaf
    is wholly behind; a luminaire: its distance to the leaf's centre less half the leaf), up to
    MAX_STRATA, the largest leaves first while the added points stay within EXTRA_POINTS of the
    default ones (or EXTRA_MIN). H1 varies over a leaf on the scale of that gap: a wall's one
    leaf next to a lamp needs more than 4 points to average it, a pixel-sized leaf does not. A
    leaf that reflects nothing keeps isqrt(k) (its points are never lit)."""
    ln = np.asarray(table["leaf_node"], np.int64)
    s0 = max(1, int(math.isqrt(max(1, int(k)))))
    s = np.full(len(ln), s0, np.int64)
    Le = np.asarray(elements.emission, np.float64).max(axis=2)          # (n, 2)
    em = np.flatnonzero(Le.max(axis=1) > 0)
    lum = luminaires_of(elements).positions                              # (k, 3) points
    if not adaptive or not (len(em) or len(lum)) or not len(ln) or s0 >= MAX_STRATA:
        return s
    V = np.asarray(table["verts"], np.float64)[ln]
    nv = np.asarray(table["nverts"], np.int64)[ln]
    V4 = np.where(nv[:, None, None] == 3, V[:, [0, 1, 2, 2]], V)
    c = V4.mean(axis=1)
    size = np.linalg.norm(V4 - c[:, None], axis=2).max(axis=1) * 2.0
    gap = np.full(len(c), np.inf)
    if len(em):
        gap = _area_gap(elements, em, Le, V4, c, size)
    if len(lum):          # a luminaire: its distance to the leaf's centre less half the leaf
        from scipy.spatial import cKDTree

        gap = np.minimum(gap, cKDTree(lum).query(c)[0].reshape(-1) - 0.5 * size)
    want = np.ceil(size / (STRATUM_OVER_DISTANCE * np.maximum(gap, 1e-300)))
    lo = np.asarray(table["orig"], np.int64)[ln]
    reflects = np.asarray(elements.reflectance, np.float64)[lo].max(axis=(1, 2)) > 0
    want = np.where(reflects, np.clip(want, s0, MAX_STRATA), s0).astype(np.int64)
    # within the budget, the largest leaves first (they carry the most light): the leaves that
    # touch a lamp's housing would otherwise all take MAX_STRATA
    extra = want * want - s0 * s0
    order = np.argsort(-(size * size) * (extra > 0), kind="stable")
    ok = np.cumsum(extra[order]) <= max(EXTRA_POINTS * s0 * s0 * len(ln), EXTRA_MIN)
    s[order[ok]] = want[order[ok]]
    return s


def _area_gap(elements, em, Le, V4, c, size) -> np.ndarray:
    """(M,) distance from each leaf (corners V4, centre c, diameter size) to the nearest of the
    8 emitting elements `em` nearest by centre that can light it, less half the leaf."""
    from scipy.spatial import cKDTree

    ec = np.asarray(elements.center, np.float64)[em]
    en = np.asarray(elements.normal, np.float64)[em]
    EV = np.asarray(elements.verts, np.float64)[em]
    EV = np.where((np.asarray(elements.nverts)[em] == 3)[:, None, None], EV[:, [0, 1, 2, 2]], EV)
    nn = min(8, len(em))
    d, j = cKDTree(ec).query(c, k=nn)
    d, j = d.reshape(len(c), nn), j.reshape(len(c), nn)
    # the leaf's corners' heights over each emitter's plane: lit by a side it is in front of
    h = np.einsum("mvc,mjc->mjv", V4, en[j]) - np.einsum("mjc,mjc->mj", ec[j], en[j])[..., None]
    tol = 1e-9 * (1.0 + d)
    lights = ((h.max(axis=2) > tol) & (Le[em[j], 0] > 0)) \
        | ((h.min(axis=2) < -tol) & (Le[em[j], 1] > 0))
    return np.where(lights, polygon_distance(c, EV, j), np.inf).min(axis=1) - 0.5 * size


def polygon_distance(c: np.ndarray, V: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(m, q) distance from points c (m, 3) to the polygons V[j[i, :]] (quads (., 4, 3), a
    triangle's last corner repeated): the nearer of the triangles v0 v1 v2 and v0 v2 v3."""
    P = c[:, None]
    out = np.full(j.shape, np.inf)
    for a, b, e in ((0, 1, 2), (0, 2, 3)):
        A, B, C = V[j, a], V[j, b], V[j, e]
        n = np.cross(B - A, C - A)
        nn = np.einsum("mqc,mqc->mq", n, n)
        inside = np.ones(j.shape, bool)
        for X, Y in ((A, B), (B, C), (C, A)):
            inside &= np.einsum("mqc,mqc->mq", np.cross(Y - X, P - X), n) >= 0
        plane = np.abs(np.einsum("mqc,mqc->mq", P - A, n)) / np.sqrt(np.where(nn > 0, nn, 1.0))
        best = np.where(inside & (nn > 0), plane, np.inf)
        for X, Y in ((A, B), (B, C), (C, A)):
            XY = Y - X
            t = np.einsum("mqc,mqc->mq", P - X, XY) / np.maximum(
                np.einsum("mqc,mqc->mq", XY, XY), 1e-300)
            Q = X + np.clip(t, 0.0, 1.0)[..., None] * XY
            best = np.minimum(best, np.linalg.norm(P - Q, axis=2))
        out = np.minimum(out, best)
    return out


def leaf_points(table: dict, strata):
    """Stratified points on each leaf of the link table: (P, 3) points, (P,) originals and
    (M + 1,) int64 first point of each leaf (the leaves' own order). strata: s (an int, s^2
    points a leaf) or (M,) per leaf (leaf_strata)."""
    from radiosity.methods.hierarchical.links.sampling import link_points, ray_pairing, triangle_strata

    ln = np.asarray(table["leaf_node"], np.int64)
    M = len(ln)
    s = np.broadcast_to(np.asarray(strata, np.int64), (M,))
    first = np.zeros(M + 1, np.int64)
    np.cumsum(s * s, out=first[1:])
    pts = np.empty((int(first[-1]), 3))
    e = np.empty(int(first[-1]), np.int64)
    verts, nverts = table["verts"], table["nverts"].astype(np.int64)
    orig = table["orig"].astype(np.int64)
    for si in np.unique(s):
        si = int(si)
        leaves = np.flatnonzero(s == si)
        nodes = ln[leaves]
        centre = np.zeros((len(verts), 3))
        if si == 1:  # one point: the polygon's centroid
            V = np.asarray(verts, np.float64)[nodes]
            tri = nverts[nodes] == 3
            centre[nodes] = np.where(tri[:, None], V[:, :3].mean(axis=1), V.mean(axis=1))
        p, o = link_points(verts, nverts, centre, orig, nodes, nodes, si,
                           triangle_strata(si * si), ray_pairing(si * si))
        at = (first[leaves][:, None] + np.arange(si * si)).ravel()
        pts[at], e[at] = p[:len(at)], o[:len(at)]
    return pts, e, first


def leaf_l1(light: DirectLight, normal: np.ndarray, pts: np.ndarray, e: np.ndarray,
            first: np.ndarray, rho: np.ndarray, p0: int = 0) -> np.ndarray:
    """L1 (n, 2, 3) of n leaves: rho (n, 2, 3) / pi times the mean H1 over each leaf's points
    pts[first[i]:first[i + 1]] (local first (n + 1,), originals e, normal the originals' (., 3)),
    per side (back: -normal); a side that reflects nothing gets 0. p0: the number of the first
    point among all the leaves' points (the shadow rays' offsets hash from it)."""
    n = len(rho)
    out = np.zeros((n, 2, 3))
    cnt = np.diff(first)
    leaf = np.repeat(np.arange(n), cnt)
    for side, sign in ((0, 1.0), (1, -1.0)):
        r = rho[:, side]
        idx = np.flatnonzero((r.max(axis=1) > 0)[leaf])
        if not len(idx):
            continue
        H = light.irradiance(pts[idx], sign * normal[e[idx]], e[idx], index=(p0 + idx) * 2 + side)
        Hs = np.zeros((n, 3))
        np.add.at(Hs, leaf[idx], H)
        out[:, side] = r * (Hs / np.maximum(cnt, 1)[:, None]) / math.pi
    return out


def direct_plan(first: np.ndarray, emitters: int, cap: int = TASK_PAIRS,
                min_tasks: int = MIN_TASKS):
    """The direct tasks: runs of consecutive leaves of about equal points x emitters, none above
    `cap` nor 1 / min_tasks of the whole. first (M + 1,): the leaves' first points. Returns
    (k + 1,) int64 first leaf of each task and (k,) int64 its cost."""
    from radiosity.runtime.packing import capped_starts

    cost = np.diff(np.asarray(first, np.int64)) * max(1, int(emitters))
    if not len(cost):
        return np.zeros(1, np.int64), np.zeros(0, np.int64)
    cap = max(1, min(int(cap), int(cost.sum()) // max(1, min_tasks)))
    starts = capped_starts(np.ascontiguousarray(cost), np.int64(cap))
    cum = np.concatenate([[0], np.cumsum(cost)])
    return starts, (cum[starts[1:]] - cum[starts[:-1]]).astype(np.int64)


# ----------------------------------------------------------------------------- the task

class _Counted:
    """A caster that counts the shadow rays it is asked (one per task: no lock)."""

    def __init__(self, caster):
        self.caster, self.rays = caster, 0

    def occluded(self, x, *args, **kw):
        self.rays += len(x)
        return self.caster.occluded(x, *args, **kw)

    def occluded_pairs(self, points, ia, *args, **kw):
        self.rays += len(ia)
        return self.caster.occluded_pairs(points, ia, *args, **kw)

    def __getattr__(self, name):
        return getattr(self.caster, name)


@scatterable
class DirectInputs:
    """What every direct task needs (scattered once): the scene's elements, the Embree cache key
    of their polygons, the rays' offset, shadow rays per point and emitter, the samples' seed."""

    def __init__(self, elements, key: str, ray_offset: float, samples: int, seed: int = 0):
        self.elements, self.key = elements, key
        self.ray_offset, self.samples, self.seed = float(ray_offset), int(samples), int(seed)

    def light(self) -> tuple[DirectLight, _Counted]:
        """A DirectLight on this process's caster (tracing.rays.caster_for: built once)."""
        from radiosity.tracing.rays import caster_for

        el = self.elements
        return _light(el, self.ray_offset, self.samples, self.seed,
                      caster_for(self.key, el.verts, el.nverts, self.ray_offset))


def _rays(light, counted: _Counted) -> int:
    """Shadow rays the light cast: its own count where it keeps one, else the caster's."""
    own = getattr(light, "rays", None)
    return int(own) if isinstance(own, (int, np.integer)) else counted.rays


def _light(elements, ray_offset: float, samples: int, seed: int, caster):
    """(DirectLight, its caster counting the shadow rays)."""
    light = DirectLight(elements, ray_offset, samples=samples, seed=seed)
    counted = _Counted(caster)
    light._caster = counted  # scene/direct.DirectLight's lazily built caster
    return light, counted


def task_direct(inp: DirectInputs, pts, e, first, rho, p0: int, store_path: str | None,
                task: int) -> dict:
    """One direct task: L1 of its leaves (leaf_l1), written to the store (store.write_direct).
    Returns {crc, n, counts (points, shadow rays), start, stop, worker, l1}."""
    from radiosity.runtime.monitor import worker_address

    t0 = time.time()
    light, counted = inp.light()
    l1 = leaf_l1(light, inp.elements.normal, pts, e, first, rho, p0)
    out = {"l1": l1}
    if store_path is not None:
        from radiosity.methods.hierarchical.store import write_direct

        out.update(write_direct(store_path, task, l1))
    out.update({"counts": np.array([len(pts), _rays(light, counted)], np.int64), "start": t0,
                "stop": time.time(), "worker": worker_address()})
    return out


# ----------------------------------------------------------------------------- the stage

@dataclass(frozen=True)
class DirectFigures(TaskFigures):
    """The first bounce's figures (report.json, section "direct")."""

    SECTION = "direct"
    where: str
    leaves: int
    points: int
    points_per_leaf_max: int
    leaves_more_points: int
    emitters: int
    samples: int
    leaf_points: int
    shadow_rays: int
    tasks: int
    time_s: float

    def rows(self):
        return [("first bounce", f"{self.leaves} leaves, {self.points} points (up to "
                                 f"{self.points_per_leaf_max} a leaf), {self.shadow_rays} shadow "
                                 f"rays to {self.emitters} emitters, {self.tasks} tasks "
                                 f"({self.tasks_reused} reused) on the {self.where}, "
                                 f"{self.time_s:.2f} s")]


class _Prepared:
    """The leaves' points, originals, reflectances and the token of everything L1 depends on."""

    def __init__(self, table, elements, settings, k: int | None, adaptive: bool):
        from dask.base import tokenize

        samples, kk = direct_settings(settings)
        self.k = kk if k is None else int(k)
        self.samples = samples
        self.offset = float(settings.rays.offset)
        self.emitters = int((np.asarray(elements.emission).max(axis=(1, 2)) > 0).sum())
        self.emitters += len(luminaires_of(elements))      # [[luminaire]] point sources
        self.strata = leaf_strata(table, elements, self.k, adaptive)
        self.pts, self.e, self.pfirst = leaf_points(table, self.strata)
        lo = np.asarray(table["orig"], np.int64)[np.asarray(table["leaf_node"], np.int64)]
        self.rho = np.ascontiguousarray(np.asarray(elements.reflectance, np.float64)[lo])
        self.first, self.cost = direct_plan(self.pfirst, self.emitters)
        self.token = tokenize(VERSION, self.pts, self.e, self.pfirst, self.rho, self.first,
                              elements.verts, elements.nverts, elements.normal,
                              elements.emission, samples, self.offset,
                              luminaires_of(elements).digest())

    def args(self, t: int) -> tuple:
        a, b = int(self.first[t]), int(self.first[t + 1])
        pa, pb = int(self.pfirst[a]), int(self.pfirst[b])
        return (self.pts[pa:pb], self.e[pa:pb], self.pfirst[a:b + 1] - pa, self.rho[a:b], pa)


class DirectStage(StageMaster):
    """The first bounce on the one stage master: the plan (_Prepared: points, runs of leaves),
    DirectInputs scattered once, one task_direct per run, store.DirectStore as the ledger; the
    figures gather L1 (kept results, else read back) into `l1` (2, 3, M)."""

    task = staticmethod(task_direct)
    counters = COUNTERS

    def __init__(self, rs, client, settings, prep: _Prepared, elements, **kw):
        super().__init__(client, report_dir=rs.run_dir, **kw)
        self.rs, self.s, self.prep, self.el = rs, settings, prep, elements
        self.parts: dict = {}
        self.l1 = None

    def plan(self) -> StagePlan:
        from radiosity.methods.hierarchical.store import DirectStore

        p, s = self.prep, self.s
        self.ds = DirectStore(self.rs)
        return StagePlan("direct", p.token, self.rs.path, len(p.first) - 1, p.cost,
                         f"rerun the solve: radiosity solve {self.rs.run_dir} (finished direct "
                         "tasks are kept)", int(s.visibility.window_per_worker),
                         int(s.visibility.retries))

    def create(self) -> None:
        p = self.prep
        self.ds.create(p.first, p.token, {"samples": p.samples, "leaf_points": p.k,
                                          "ray_offset": p.offset})

    def ledger(self):
        return self.ds

    def inputs(self) -> DirectInputs:
        from dask.base import tokenize

        el = self.el
        return DirectInputs(el, tokenize(el.verts, el.nverts), self.prep.offset,
                            self.prep.samples)

    def args(self, task: int, shared) -> tuple:
        return (shared, *self.prep.args(task), self.rs.path, task)

    def on_result(self, task, result, done) -> None:
        self.parts[task] = result.pop("l1")

    def figures(self, run) -> DirectFigures:
        from radiosity.methods.hierarchical.store import read_direct

        p = self.prep
        out = np.zeros((len(p.rho), 2, 3))
        for t in range(len(p.first) - 1):
            a, b = p.first[t], p.first[t + 1]
            got = self.parts.pop(t, None)
            out[a:b] = got if got is not None else read_direct(self.rs.path, t, run.done[t])
        self.l1 = np.ascontiguousarray(np.transpose(out, (1, 2, 0)))
        return _figures(p, "workers", run.figures(), run.counts, self.t_start)


def _figures(p: _Prepared, where: str, task_figures: dict, counts, t0: float,
             tasks: int | None = None) -> DirectFigures:
    c = dict(zip(COUNTERS, np.asarray(counts).tolist()))
    n = np.diff(p.pfirst)
    return DirectFigures(**task_figures, where=where, leaves=len(p.rho), points=int(c["points"]),
                         points_per_leaf_max=int(n.max(initial=0)),
                         leaves_more_points=int((n > p.k).sum()), emitters=p.emitters,
                         samples=p.samples, leaf_points=p.k, shadow_rays=int(c["shadow_rays"]),
                         tasks=len(p.first) - 1 if tasks is None else tasks,
                         time_s=round(time.perf_counter() - t0, 4))


def first_bounce(table: dict, elements, settings, k: int | None = None, *, rs=None, client=None,
                 where: str = "auto", resume: bool = True, progress: bool = False,
                 adaptive: bool = True, on_done=None, figures: list | None = None) -> np.ndarray:
    """L1 (2, 3, M) float64 of the leaves of the link table: rho / pi times the mean direct
    irradiance H1 over stratified points of each leaf (leaf_strata: k = settings.direct.leaf_points,
    more on leaves large against their distance to the emitters), per side.

    With a run store `rs` and a `client` (where "auto" above LOCAL_PAIRS points x emitters, or
    "workers"): the direct stage, its tasks stored and, with `resume`, reused when the token
    (the leaves' points, the scene, samples, rays.offset) is the same. Otherwise in process.
    Same bits either way. The figures go to rs's report.json (section "direct") and, given a
    list, into `figures`."""
    t0 = time.perf_counter()
    p = _Prepared(table, elements, settings, k, adaptive)
    M = len(p.rho)
    if where not in ("auto", "driver", "workers"):
        raise ValueError(f"where must be auto, driver or workers, got {where!r}")
    stage = rs is not None and client is not None and p.emitters and M and (
        where == "workers" or (where == "auto" and len(p.pts) * p.emitters >= LOCAL_PAIRS))
    if stage:
        st = DirectStage(rs, client, settings, p, elements, resume=resume, progress=progress,
                         on_done=on_done)
        fig = st.run()
        if figures is not None:
            figures.append(fig)
        return st.l1
    light, counted = None, _Counted(None)
    if p.emitters:
        from radiosity.tracing.rays import caster_of

        light, counted = _light(elements, p.offset, p.samples, 0,
                                caster_of(elements.verts, elements.nverts, p.offset))
    out = np.zeros((M, 2, 3)) if light is None else \
        leaf_l1(light, elements.normal, p.pts, p.e, p.pfirst, p.rho)
    fig = _figures(p, "driver", {"tasks_computed": 1, "tasks_reused": 0,
                                 "tasks_corrupted_recomputed": 0,
                                 "time_tasks_s": round(time.perf_counter() - t0, 4),
                                 "busy_s_per_worker": {}, "idle_fraction": None, "workers": 1},
                   (0, 0) if light is None else (len(p.pts), _rays(light, counted)), t0, tasks=1)
    if rs is not None:
        fig.write(rs.run_dir)
    if figures is not None:
        figures.append(fig)
    return np.ascontiguousarray(np.transpose(out, (1, 2, 0)))
