"""The view-factor stage's master (driver side): resolve the parameters, build the facet tree
and the worker inputs, plan the tasks, run them through runtime.stage.run_stage (resume,
checksums, retries), assemble the CSR matrix from the store and write the outputs.
The method: docs/src/design/viewfactors-method.md.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from radiosity.core.tolerances import TOL
from radiosity.errors import RadiosityError
from radiosity.settings import Settings, ViewFactorSettings
from radiosity.viewfactors.facets import Facets, load_facets
from radiosity.viewfactors.store import read_vf_task
from radiosity.viewfactors.task import COUNTERS, STAGES, Inputs, Params, task_viewfactors

VERSION = 1   # of the stored task format and method (part of the resume token)
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

def make_inputs(fac: Facets, leaf_size: int, epsilon: float):
    """The tree (scene/originals.build_tree, leaves of at most `leaf_size` facets) and the
    worker inputs of facets `fac`, in the tree's leaf order; epsilon: the ray offset
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
                 key="vf-" + tokenize(v, nv), epsilon=float(epsilon))
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

@dataclass
class ViewFactors:
    """matrix: CSR (n, n) float64, F[i, j] from facet i to facet j (load order; balanced when
    the facets were treated as an enclosure); area (n,); facets; figures (the report section)."""

    matrix: object
    area: np.ndarray
    facets: Facets
    figures: dict


def compute_viewfactors(mesh, out: str, client, settings: Settings, *, fmt="npz",
                        resume: bool = False, progress: bool = True,
                        on_done=None) -> ViewFactors:
    """View factors of the facets of `mesh` (load_facets) into the run directory `out`:
    store.zarr (facets, per-task pairs, the CSR matrix), viewfactors.npz, facets.csv
    (viewfactors.csv with fmt="csv"), report.json (section "viewfactors"). settings: the run's
    (radiosity.viewfactors.*: accuracy, enclosure auto | on | off, cutoff, ...). resume: keep
    the finished tasks of an interrupted run with the same inputs. on_done(n) after each
    finished task (tests)."""
    from dask.base import tokenize

    from radiosity.runtime.cluster import Scattered
    from radiosity.runtime.monitor import peak_rss_mb
    from radiosity.runtime.stage import StagePlan, run_stage
    from radiosity.runtime.store import update_report
    from radiosity.viewfactors.outputs import finish
    from radiosity.viewfactors.store import VFLedger

    t_start = time.perf_counter()
    s = settings
    vf = s.viewfactors
    if vf.enclosure not in ENCLOSURE_MODES:
        raise RadiosityError(f"--enclosure must be one of {', '.join(ENCLOSURE_MODES)}, "
                             f"got {vf.enclosure!r}")
    if fmt not in FORMATS:
        raise RadiosityError(f"--format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    prm = params_of(vf)
    fac = load_facets(mesh, settings=s)
    n = len(fac)
    tree, inp = make_inputs(fac, vf.leaf_size, s.rays.epsilon)
    threads = sum(client.nthreads().values()) or 1
    tasks = plan_tasks(tree, n, vf.task_pairs, vf.tasks_per_worker * threads)
    token = tokenize(VERSION, fac.verts, fac.nverts, asdict(prm), vf.leaf_size,
                     [t.tolist() for t in tasks])
    ledger = VFLedger(out)
    plan = StagePlan(name="viewfactors", token=token, where=ledger.path, ntasks=len(tasks),
                     cost=np.array([task_cost(tree, n, t) for t in tasks], np.int64),
                     repair=f"rerun with: radiosity viewfactors MESH --out {out} --resume",
                     window_per_worker=vf.window_per_worker, retries=vf.retries)
    shared = Scattered(client, inp)  # sent with the first task submitted

    def create():
        ledger.create(token, {"params": asdict(prm), "leaf_size": vf.leaf_size,
                              "tasks": len(tasks)}, fac.sources,
                      {"verts": fac.verts, "nverts": fac.nverts, "area": fac.area,
                       "normal": fac.normal, "center": fac.center, "face": fac.face,
                       "source": fac.source})

    run = run_stage(client, plan, task_viewfactors,
                    lambda t: (shared.future(), prm, tasks[t], ledger.path, t), ledger,
                    resume=resume, create=create, ncounters=len(COUNTERS), on_done=on_done,
                    progress=progress)
    stage = np.zeros(len(STAGES))
    cpu = 0.0
    for e in run.done.values():
        stage += np.asarray(e["times"])
        cpu += e["cpu"]
    t_asm = time.perf_counter()
    asm = assemble(ledger.rs, fac, tree, {t: run.done[t] for t in range(len(tasks))})
    t_asm = time.perf_counter() - t_asm
    fig = finish(ledger.rs, out, fac, asm, vf, fmt, float(s.rays.epsilon))
    fig.update({
        "facets": n, "accuracy": prm.accuracy, "cutoff": prm.cutoff,
        "cheap_kernel_relative_bound": prm.cheap_rel, "max_points_per_side": prm.smax,
        **dict(zip(COUNTERS, run.counts.tolist())), "tasks": len(tasks), **run.figures(),
        "leaf_size": vf.leaf_size, "time_assembly_s": round(t_asm, 3),
        "task_time_by_stage_s": {k: round(float(v), 3) for k, v in zip(STAGES, stage)},
        "task_cpu_s": round(cpu, 3), "peak_rss_mb": peak_rss_mb(client),
    })
    matrix = fig.pop("_matrix")
    fig["time_s"] = round(time.perf_counter() - t_start, 3)
    update_report(out, "viewfactors", fig)
    return ViewFactors(matrix, fac.area, fac, fig)

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
