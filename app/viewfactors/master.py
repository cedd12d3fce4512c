"""The view-factor stage's master (driver side): resolve the parameters, build the facet tree
and the worker inputs, plan the tasks, run them on the one stage master (runtime/stage.py:
resume, checksums, retries), assemble the CSR matrix from the store and write the outputs.
The method: docs/src/design/viewfactors-method.md.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from radiosity.core.tolerances import TOL
from radiosity.errors import RadiosityError
from radiosity.runtime.stage import StageMaster, StagePlan, TaskFigures
from radiosity.settings import Settings, ViewFactorSettings
from radiosity.viewfactors.facets import Facets, load_facets
from radiosity.viewfactors.store import read_vf_task
from radiosity.viewfactors.task import COUNTERS, STAGES, Inputs, Params, task_viewfactors

VERSION = 2   # of the stored task format and method (part of the resume token)
ENCLOSURE_MODES = ("auto", "on", "off")
FORMATS = ("npz", "csv")
PLANE_TOL = TOL.facet_plane   # facing and plane tests (core.tolerances)


def resolve_params(settings: Settings) -> Params:
    """The task parameters of `settings`; RadiosityError names a bad value."""
    return params_of(settings.viewfactors)


def params_of(vf: ViewFactorSettings) -> Params:
    """The task parameters of the radiosity.viewfactors.* section `vf`, checked."""
    acc = float(vf.accuracy)
    if not 0 < acc < 1:
        raise RadiosityError(f"--accuracy must be in (0, 1), got {acc}")
    cut = float(vf.cutoff)
    if cut < 0:
        raise RadiosityError(f"radiosity.viewfactors.cutoff must be >= 0, got {cut}")
    smax = int(vf.max_points_per_side)
    if smax < 1 or smax & (smax - 1):
        raise RadiosityError("radiosity.viewfactors.max-points-per-side must be a power of 2, "
                             f"got {smax}")
    return Params(acc, float(vf.cheap_share) * acc, smax, int(vf.seed), cut,
                  int(vf.batch_pairs), int(vf.ray_batch))


# ----------------------------------------------------------------------------- inputs and plan

def make_inputs(fac: Facets, leaf_size: int, ray_offset: float):
    """The tree (scene/originals.build_tree, leaves of at most `leaf_size` facets) and the
    worker inputs of facets `fac`, in the tree's leaf order; ray_offset: the ray offset
    (radiosity.rays.epsilon). Boxes and the plane tolerance of the occlusion tests are the
    render's (tracing/shafts.occluders: padded boxes)."""
    from dask.base import tokenize

    from radiosity.scene.originals import build_tree
    from radiosity.tracing.shafts import node_boxes, occluders
    from radiosity.viewfactors.loops import Nodes, facet_quadrature, second_moments

    verts = np.ascontiguousarray(fac.verts, np.float64)
    n = len(fac)
    tree = build_tree(verts, fac.nverts, fac.normal, fac.center, np.zeros(n, bool),
                      leaf=max(1, int(leaf_size)))
    p = tree.order
    v = verts[p]
    nv = fac.nverts[p].astype(np.int64)
    normal, center, area = fac.normal[p], fac.center[p], fac.area[p]
    olo, ohi, _, _, pad = occluders(fac)
    flo, fhi = np.ascontiguousarray(olo[p]), np.ascontiguousarray(ohi[p])
    doff = np.einsum("ic,ic->i", normal, center)
    dev = np.abs(np.einsum("ic,ikc->ik", normal, v) - doff[:, None]).max(axis=1)
    vs = verts.reshape(-1, 3)
    size = float(np.linalg.norm(vs.max(0) - vs.min(0))) or 1.0
    tol = PLANE_TOL * size + float(dev.max(initial=0.0))
    J, R = second_moments(v, nv, center, area)
    qn, qw, qc = facet_quadrature(v, nv, area)
    # node boxes of the padded facet boxes (in leaf order the tree's order is the identity)
    lo, hi = node_boxes(tree.left, tree.right, tree.start, tree.end, np.arange(n, dtype=np.int64),
                        flo, fhi)
    nodes = Nodes(tree.start, tree.end, tree.left, tree.right, lo, hi, tree.axis, tree.spread,
                  tree.node_sums(fac.area), 0)
    inp = Inputs(verts=v, nv=nv, normal=normal, center=center, area=area, doff=doff,
                 flo=flo, fhi=fhi, gid=p, J=J, R=R, qn=qn, qw=qw, qc=qc,
                 nodes=nodes, n_leaves=len(tree.leaves()), tol=tol, pad=pad,
                 key="vf-" + tokenize(v, nv), ray_offset=float(ray_offset))
    return tree, inp


def plan_tasks(tree, n: int, task_pairs: int, min_tasks: int) -> list:
    """Runs of consecutive leaves (tree order), each about the same number of pairs (i < j
    with i in the run), at most task_pairs unless one leaf holds more, and at least
    min_tasks runs when there are enough leaves. Returns a list of leaf-id arrays."""
    lv = tree.leaves()
    na = tree.end[lv] - tree.start[lv]
    cost = na * (na - 1) // 2 + na * (n - tree.end[lv])
    total = int(cost.sum())
    target = max(1, min(int(task_pairs), -(-total // max(1, min_tasks))))
    tasks, cur, acc = [], [], 0
    for leaf, c in zip(lv.tolist(), cost.tolist()):
        if cur and acc + c > target:
            tasks.append(np.array(cur, np.int64))
            cur, acc = [], 0
        cur.append(leaf)
        acc += c
    if cur:
        tasks.append(np.array(cur, np.int64))
    return tasks


def task_cost(tree, n: int, leaves: np.ndarray) -> int:
    na = tree.end[leaves] - tree.start[leaves]
    return int((na * (na - 1) // 2 + na * (n - tree.end[leaves])).sum())


# ----------------------------------------------------------------------------- the master

@dataclass(frozen=True)
class ViewFactorFigures(TaskFigures):
    """The view-factor stage's figures (report.json, section "viewfactors"): what the outputs
    found and wrote (outputs.finish: enclosure, balancing, row sums, files), the parameters,
    the tasks' counters (task.COUNTERS) summed, the task run and the times."""

    SECTION = "viewfactors"
    FLAT = ("outputs", "counters")
    outputs: dict
    facets: int
    accuracy: float
    cutoff: float
    cheap_kernel_relative_bound: float
    max_points_per_side: int
    counters: dict
    tasks: int
    leaf_size: int
    time_assembly_s: float
    task_time_by_stage_s: dict
    task_cpu_s: float
    peak_rss_mb: dict
    time_s: float


@dataclass
class ViewFactors:
    """matrix: CSR (n, n) float64, F[i, j] from facet i to facet j (load order; balanced when
    the facets were treated as an enclosure); area (n,); facets; figures (the report section)."""

    matrix: object
    area: np.ndarray
    facets: Facets
    figures: ViewFactorFigures


class ViewFactorStage(StageMaster):
    """The view-factor stage on the one stage master: the plan (the facet tree, runs of its
    leaves as tasks), the worker inputs, one task_viewfactors per task, the run's store as the
    ledger; the figures assemble the matrix and write the outputs (outputs.finish)."""

    task = staticmethod(task_viewfactors)
    counters = COUNTERS

    def __init__(self, mesh, out: str, client, s: Settings, prm: Params, fmt: str, **kw):
        super().__init__(client, report_dir=out, **kw)
        self.mesh, self.out, self.s, self.prm, self.fmt = mesh, out, s, prm, fmt
        self.matrix = None

    def plan(self) -> StagePlan:
        from dask.base import tokenize

        from radiosity.viewfactors.store import VFLedger

        s, vf, prm = self.s, self.s.viewfactors, self.prm
        self.fac = fac = load_facets(self.mesh, settings=s)
        n = len(fac)
        self.tree, self.inp = tree, _ = make_inputs(fac, vf.leaf_size, s.rays.offset)
        threads = sum(self.client.nthreads().values()) or 1
        self.tasks = tasks = plan_tasks(tree, n, vf.task_pairs, vf.tasks_per_worker * threads)
        self.token = tokenize(VERSION, fac.verts, fac.nverts, asdict(prm), vf.leaf_size,
                              [t.tolist() for t in tasks])
        self.vfl = VFLedger(self.out)
        return StagePlan(name="viewfactors", token=self.token, where=self.vfl.path,
                         ntasks=len(tasks),
                         cost=np.array([task_cost(tree, n, t) for t in tasks], np.int64),
                         repair=f"rerun with: radiosity viewfactors MESH --out {self.out} "
                                "--resume",
                         window_per_worker=vf.window_per_worker, retries=vf.retries)

    def create(self) -> None:
        fac = self.fac
        self.vfl.create(self.token, {"params": asdict(self.prm),
                                     "leaf_size": self.s.viewfactors.leaf_size,
                                     "tasks": len(self.tasks)}, fac.sources,
                        {"verts": fac.verts, "nverts": fac.nverts, "area": fac.area,
                         "normal": fac.normal, "center": fac.center, "face": fac.face,
                         "source": fac.source})

    def ledger(self):
        return self.vfl

    def inputs(self):
        return self.inp

    def args(self, task: int, shared) -> tuple:
        return (shared, self.prm, self.tasks[task], self.vfl.path, task)

    def figures(self, run) -> ViewFactorFigures:
        from radiosity.runtime.monitor import peak_rss_mb
        from radiosity.viewfactors.outputs import finish

        s, prm, fac = self.s, self.prm, self.fac
        stage = np.zeros(len(STAGES))
        cpu = 0.0
        for e in run.done.values():
            stage += np.asarray(e["times"])
            cpu += e["cpu"]
        t_asm = time.perf_counter()
        asm = assemble(self.vfl.rs, fac, self.tree,
                       {t: run.done[t] for t in range(len(self.tasks))})
        t_asm = time.perf_counter() - t_asm
        outputs = finish(self.vfl.rs, self.out, fac, asm, s.viewfactors, self.fmt,
                         float(s.rays.offset))
        self.matrix = outputs.pop("_matrix")
        return ViewFactorFigures(
            outputs=outputs, facets=len(fac), accuracy=prm.accuracy, cutoff=prm.cutoff,
            cheap_kernel_relative_bound=prm.cheap_rel, max_points_per_side=prm.smax,
            counters=dict(zip(COUNTERS, run.counts.tolist())), tasks=len(self.tasks),
            **run.figures(), leaf_size=s.viewfactors.leaf_size,
            time_assembly_s=round(t_asm, 3),
            task_time_by_stage_s={k: round(float(v), 3) for k, v in zip(STAGES, stage)},
            task_cpu_s=round(cpu, 3), peak_rss_mb=peak_rss_mb(self.client),
            time_s=round(time.perf_counter() - self.t_start, 3))


def compute_viewfactors(mesh, out: str, client, settings: Settings, *, fmt="npz",
                        resume: bool = False, progress: bool = True,
                        on_done=None) -> ViewFactors:
    """View factors of the facets of `mesh` (load_facets) into the run directory `out`:
    store.zarr (facets, per-task pairs, the CSR matrix), viewfactors.npz, facets.csv
    (viewfactors.csv with fmt="csv"), report.json (section "viewfactors"). settings: the run's
    (radiosity.viewfactors.*: accuracy, enclosure auto | on | off, cutoff, ...). resume: keep
    the finished tasks of an interrupted run with the same inputs. on_done(n) after each
    finished task (tests). The stage: ViewFactorStage."""
    s = settings
    vf = s.viewfactors
    if vf.enclosure not in ENCLOSURE_MODES:
        raise RadiosityError(f"--enclosure must be one of {', '.join(ENCLOSURE_MODES)}, "
                             f"got {vf.enclosure!r}")
    if fmt not in FORMATS:
        raise RadiosityError(f"--format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    stage = ViewFactorStage(mesh, out, client, s, params_of(vf), fmt, resume=resume,
                            progress=progress, on_done=on_done)
    fig = stage.run()
    return ViewFactors(stage.matrix, stage.fac.area, stage.fac, fig)


# ----------------------------------------------------------------------------- assembly

@dataclass
class Assembled:
    """matrix: CSR F (unbalanced); violations: pairs with F > unobstructed F; cheap_bound,
    dropped_bound (n,): per row, the proven bounds of the cheap kernel's and the cut-off's
    contributions to the row's error."""

    matrix: object
    violations: int
    cheap_bound: np.ndarray
    dropped_bound: np.ndarray


def assemble(rs, fac: Facets, tree, entries: dict) -> Assembled:
    """The CSR matrix from the tasks' pairs (both directions; F_ji = F_ij A_i / A_j), in two
    streaming passes (row counts, then fill): memory is the matrix plus one task."""
    import scipy.sparse as sp

    from radiosity.viewfactors.loops import scatter_rows

    n = len(fac)
    A = fac.area
    rowcount = np.zeros(n, np.int64)
    cheap = np.zeros(n)
    dropdiff = np.zeros(n + 1)
    violations = 0
    for task in sorted(entries):
        ij, f, drop = read_vf_task(rs.path, task, entries[task])
        i, j = ij[:, 0], ij[:, 1]
        rowcount += np.bincount(i, minlength=n) + np.bincount(j, minlength=n)
        violations += int(np.count_nonzero(f[:, 0] > f[:, 1]))
        eb = f[:, 2] * np.where(f[:, 1] > 0, f[:, 0] / np.where(f[:, 1] > 0, f[:, 1], 1.0), 0.0)
        cheap += np.bincount(i, weights=eb, minlength=n) + np.bincount(j, weights=eb * A[i] / A[j], minlength=n)
        for a, b, bab, bba in drop:
            a, b = int(a), int(b)
            dropdiff[tree.start[a]] += bab
            dropdiff[tree.end[a]] -= bab
            dropdiff[tree.start[b]] += bba
            dropdiff[tree.end[b]] -= bba
    dropped = np.zeros(n)
    dropped[tree.order] = np.cumsum(dropdiff)[:n]
    indptr = np.concatenate([[0], np.cumsum(rowcount)])
    indices = np.empty(int(indptr[-1]), np.int32)
    data = np.empty(int(indptr[-1]))
    fill = indptr[:-1].copy()
    for task in sorted(entries):
        ij, f, _ = read_vf_task(rs.path, task, entries[task])
        i, j = ij[:, 0].astype(np.int64), ij[:, 1].astype(np.int64)
        scatter_rows(i, j, f[:, 0], fill, indices, data)
        scatter_rows(j, i, f[:, 0] * A[i] / A[j], fill, indices, data)
    M = sp.csr_matrix((data, indices, indptr), shape=(n, n))
    M.sort_indices()
    return Assembled(M, violations, cheap, dropped)
