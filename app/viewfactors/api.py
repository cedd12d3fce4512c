"""View factors between the user's own facets, for thermal-radiation engineers (issue 16):
`radiosity viewfactors MESH --out DIR` and `radiosity.view_factors(mesh) -> scipy.sparse.csr_matrix`.

The facets are the mesh's faces as loaded (OBJ / glTF / PLY, or the meshes of a scene TOML; no
camera, no subdivision, triangle pairs are not merged into quads), one-sided: facet i radiates
from the side its normal points to. F_ij is the fraction of the power leaving facet i that
reaches facet j, so A_i F_ij = A_j F_ji and row sums are <= 1 (= 1 in an enclosure).

Method, per unordered pair {i, j} (each computed once; F_ji = F_ij A_i / A_j):

1. Which pairs. A tree over the facets (bvh.py; leaves of `leaf-size` facets) is walked leaf
   against tree (vfkernels.near_leaves): cluster pairs wholly behind each other's planes are
   culled (exact zeros, no pair is visited); with `cutoff` > 0, cluster pairs whose form-factor
   bound area / (pi rho^2) is at most the cut-off both ways are dropped, and the sum of the
   dropped bounds is reported per facet. Nothing n x n is ever built: pairs are enumerated
   leaf by leaf, in batches of at most `batch-pairs`.
2. Unobstructed F. Pairs that face each other get the exact polygon form factor (exact.py, the
   double contour integral, clipped to the front half-spaces), except far pairs where the cheap
   degree-5 product quadrature has a proven error bound (vfkernels, bound (*)) of at most
   `cheap-share` x accuracy x its value: there the cheap value is used and its bound recorded.
3. Visibility. Shafts (Haines & Wallace) between the two leaves' boxes, then between the two
   facets' boxes, with the occluders found by walking the tree: a pair with no possible
   occluder is unobstructed (F = the unobstructed value, no rays). Otherwise the visible
   fraction phi is sampled with rays (Embree, rays.py): level s puts s x s jittered stratified
   points on each facet and traces all s^4 point pairs, phi being their kernel-weighted visible
   fraction (seed §2.2 method 2). A pair whose unobstructed F (the larger of F_ij and F_ji) is
   at most the accuracy stops at s = 1 (one ray between centroids; its error is at most
   F <= accuracy); a larger one starts at the s where one sample pair carries at most the
   accuracy (F / s^4 <= accuracy), stops there when its sample pairs are unanimous (all
   visible or all blocked: what they missed lies within one cell pair), and otherwise doubles
   s until two successive levels agree within the accuracy, F |phi_s - phi_s/2| <= accuracy,
   or s reaches `max-points-per-side`. (Jittered stratification over the s^4 cell pairs:
   where a shadow edge crosses a pair, the standard error of phi is about 0.5 s^-2.5,
   measured on the half-blocked squares of the tests.) F = phi x the unobstructed F, so
   obstructed <= unobstructed holds by construction, and so does reciprocity.
4. Tasks: runs of consecutive leaves, balanced by their pair counts, run on Dask through a
   bounded as_completed window (runner.run_tasks, the one runner); each task writes its pairs into the run's Zarr
   store and the master records a crc32 per task in a manifest (a rerun with resume=True
   recomputes only missing or corrupted tasks).
5. Assembly into CSR (two streaming passes over the tasks), the enclosure test and symmetric
   balancing (enclosure.py), the checks (factors in [0, 1], no self factor, obstructed <=
   unobstructed, rows <= 1, reciprocity residual), viewfactors.npz, facets.csv, report.json.
"""

from __future__ import annotations

import csv
import os
import time
import warnings
from dataclasses import asdict, dataclass

import numpy as np

from radiosity import config
from radiosity.runtime.cluster import Scattered
from radiosity.errors import RadiosityError, SceneError
from radiosity.runtime.monitor import worker_address

COUNTERS = ("pairs_total", "pairs_culled_cluster", "pairs_dropped_cutoff", "pairs_facing_away",
            "pairs_facing", "pairs_zero_unobstructed", "pairs_cheap_kernel", "pairs_exact_kernel",
            "pairs_proven_unobstructed", "pairs_sampled", "pairs_one_ray", "pairs_at_max_points",
            "pairs_unresolved", "rays", "shaft_tests", "pairs_blocked", "pairs_stored")
(_TOTAL, _CULLED, _DROPPED, _AWAY, _FACING, _ZERO, _CHEAP, _EXACT, _PROVEN, _SAMPLED, _ONE,
 _CAPPED, _UNRES, _RAYS, _TESTS, _BLOCKED, _STORED) = range(len(COUNTERS))
STAGES = ("enumerate_s", "unobstructed_s", "shafts_s", "visibility_s")
VERSION = 1   # of the stored task format and method (part of the resume token)
ENCLOSURE_MODES = ("auto", "on", "off")
FORMATS = ("npz", "csv")


# ----------------------------------------------------------------------------- facets

@dataclass(frozen=True)
class Facets:
    """The user's facets, in load order.

    verts (n, 4, 3) float64 (a triangle repeats vertex 2), nverts (n,) int8, normal (n, 3)
    unit front normals, center (n, 3) area centroids, area (n,) float64 (mesh unit squared),
    face (n,) int32: the face number in its file (0-based; faces with more than 4 vertices or
    non-planar quads become several facets, with a warning), source (n,) int32 index into
    sources (the mesh files)."""

    verts: np.ndarray
    nverts: np.ndarray
    normal: np.ndarray
    center: np.ndarray
    area: np.ndarray
    face: np.ndarray
    source: np.ndarray
    sources: tuple = ()

    def __len__(self) -> int:
        return len(self.area)

    def describe(self, i: int) -> str:
        src = os.path.basename(self.sources[self.source[i]]) if self.sources else "?"
        return f"facet {i} (face {int(self.face[i]) + 1} of {src})"


def _from_polygons(parts: list, sources: list) -> Facets:
    from radiosity.core.geometry import polygon_properties

    verts = np.concatenate([p[0] for p in parts])
    if len(verts) == 0:
        raise SceneError(f"{', '.join(sources) or 'the mesh'}: no faces: nothing to compute")
    nverts = np.concatenate([p[1] for p in parts]).astype(np.int8)
    face = np.concatenate([p[2] for p in parts]).astype(np.int32)
    source = np.concatenate([np.full(len(p[0]), k, np.int32) for k, p in enumerate(parts)])
    area, normal, center = polygon_properties(verts, nverts)
    return Facets(verts, nverts, normal, center, area, face, source, tuple(sources))


def load_facets(mesh) -> Facets:
    """The facets of `mesh`: a path (OBJ, glTF/GLB, PLY, or a scene TOML / its directory, whose
    [[mesh]] files are read and whose camera and materials are ignored), a trimesh.Trimesh, a
    (vertices (V, 3), faces) pair, a types.Elements, or Facets. Bad input raises SceneError."""
    from radiosity.scene.load import MESH_FORMATS, RawMesh, load_mesh
    from radiosity.core.bundles import Elements

    if isinstance(mesh, Facets):
        return mesh
    if isinstance(mesh, Elements):
        return Facets(mesh.verts, mesh.nverts, mesh.normal, mesh.center, mesh.area, mesh.face,
                      mesh.source, mesh.sources)
    if isinstance(mesh, (str, os.PathLike)):
        path = os.path.abspath(os.fspath(mesh))
        if os.path.isdir(path) and os.path.exists(os.path.join(path, "scene.toml")):
            path = os.path.join(path, "scene.toml")
        if path.lower().endswith(".toml"):
            files = _toml_meshes(path)
        elif path.lower().endswith(MESH_FORMATS):
            files = [path]
        else:
            raise SceneError(f"{path}: not a mesh ({', '.join(MESH_FORMATS)}) or a scene TOML")
        parts = [_polygons(load_mesh(fn), fn) for fn in files]
        return _from_polygons(parts, files)
    if hasattr(mesh, "vertices") and hasattr(mesh, "faces"):
        vertices, faces, name = mesh.vertices, mesh.faces, "mesh"
    elif isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        (vertices, faces), name = mesh, "(vertices, faces)"
    else:
        raise SceneError(f"cannot read facets from a {type(mesh).__name__}: give a mesh path, "
                         "a trimesh.Trimesh or a (vertices, faces) pair")
    V = np.asarray(vertices, float)
    if V.ndim != 2 or V.shape[1] != 3:
        raise SceneError(f"{name}: vertices must be a (V, 3) array, got shape {V.shape}")
    F = [list(map(int, f)) for f in faces]
    for k, f in enumerate(F):
        if len(f) < 3 or min(f) < 0 or max(f) >= len(V):
            raise SceneError(f"{name}: face {k + 1} {f} refers to vertices that do not exist "
                             f"(there are {len(V)})")
    return _from_polygons([_polygons(RawMesh(V, F, ["default"] * len(F)), name)], [name])


def _polygons(raw, fn: str):
    """(verts (n, 4, 3), nverts (n,), face (n,)) of a raw mesh, one facet per face, as
    scene.polygons_from_raw(merge=False) gives them. Meshes of valid triangles and planar
    convex quads (the usual case) are checked with whole-array operations; any other mesh
    goes through polygons_from_raw, which repairs (with a warning) or rejects (one line naming
    the face) exactly as the scene loader does."""
    from radiosity.scene.load import polygons_from_raw

    sizes = np.array([len(f) for f in raw.faces], np.int64)
    if len(sizes) and sizes.min() >= 3 and sizes.max() <= 4:
        V = np.asarray(raw.vertices, float)
        idx = np.array([list(f) + [f[2]] * (4 - len(f)) for f in raw.faces], np.int64)
        p = V[idx]
        if np.isfinite(p).all():
            p0, p1, p2, p3 = (p[:, k] for k in range(4))
            c012 = np.cross(p1 - p0, p2 - p0)
            n = c012 + np.cross(p2 - p0, p3 - p0)
            nn = np.linalg.norm(n, axis=1)
            diam = np.linalg.norm(p[:, :, None] - p[:, None], axis=-1).max(axis=(1, 2))
            quad = sizes == 4
            off = np.abs(np.einsum("ij,ij->i", p3 - p0, c012))
            c = np.linalg.norm(c012, axis=1)
            planar = (c > 0) & (off <= config.get("scene.planarity-tolerance") * diam * np.maximum(c, 1e-300))
            unit = n / np.where(nn > 0, nn, 1.0)[:, None]
            turns = np.stack([np.einsum("ij,ij->i", np.cross(p[:, (k + 1) % 4] - p[:, k],
                                                             p[:, (k + 2) % 4] - p[:, (k + 1) % 4]), unit)
                              for k in range(4)], 1)
            convex = (turns > 0).all(axis=1)
            area = 0.5 * nn
            ok = (area > config.get("scene.min-relative-area") * diam ** 2) & (~quad | (planar & convex))
            if ok.all():
                return p, sizes.astype(np.int8), np.arange(len(sizes), dtype=np.int32)
    v, nv, f, _ = polygons_from_raw(raw, fn, merge=False)
    return v, nv, f


def _toml_meshes(path: str) -> list:
    import tomllib

    try:
        with open(path, "rb") as f:
            doc = tomllib.load(f)
    except FileNotFoundError:
        raise SceneError(f"scene file not found: {path}") from None
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{path}: not valid TOML: {e}") from None
    meshes = doc.get("mesh", [])
    if not isinstance(meshes, list) or not meshes:
        raise SceneError(f"{path}: no [[mesh]] entries: the scene is empty")
    out = []
    for k, m in enumerate(meshes):
        if not isinstance(m, dict) or "path" not in m:
            raise SceneError(f"{path}: [[mesh]] {k + 1} has no 'path'")
        out.append(os.path.join(os.path.dirname(path), m["path"]))
    return out


# ----------------------------------------------------------------------------- inputs

@dataclass(frozen=True)
class Params:
    """Tunables resolved on the driver (worker code never reads configuration).

    accuracy: target absolute error of a factor; cheap_rel: the cheap kernel is used where its
    bound <= cheap_rel x its value; smax: largest sample points per side; seed: of the jitter;
    cutoff: cluster form-factor bound below which cluster pairs are dropped (0: never);
    batch_pairs: pairs per batch in a task; ray_batch: rays per Embree batch."""

    accuracy: float
    cheap_rel: float
    smax: int
    seed: int
    cutoff: float
    batch_pairs: int
    ray_batch: int


def resolve_params(accuracy=None, cutoff=None) -> Params:
    acc = float(config.get("viewfactors.accuracy", accuracy))
    if not 0 < acc < 1:
        raise RadiosityError(f"--accuracy must be in (0, 1), got {acc}")
    cut = float(config.get("viewfactors.cutoff", cutoff))
    if cut < 0:
        raise RadiosityError(f"radiosity.viewfactors.cutoff must be >= 0, got {cut}")
    smax = int(config.get("viewfactors.max-points-per-side"))
    if smax < 1 or smax & (smax - 1):
        raise RadiosityError(f"radiosity.viewfactors.max-points-per-side must be a power of 2, got {smax}")
    return Params(acc, float(config.get("viewfactors.cheap-share")) * acc, smax,
                  int(config.get("viewfactors.seed")), cut,
                  int(config.get("viewfactors.batch-pairs")), int(config.get("viewfactors.ray-batch")))


@dataclass(frozen=True)
class Inputs:
    """Read-only arrays every task needs, in tree order (scattered to the workers once).

    verts (n, 4, 3), nv (n,) int64, normal, center (n, 3), area (n,), doff (n,) = n . c,
    flo, fhi (n, 3) facet boxes, gid (n,) int64 original facet ids, J, R (n,) second moments
    and radii (vfkernels.second_moments), qn (n, MAXQ, 3), qw (n, MAXQ), qc (n,) quadrature;
    the tree: start, end, left, right (k,) int64, lo, hi, axis (k, 3), spread, tarea (k,),
    root; tol: the facing tolerance, pad: the plane tolerance (lengths); key: Embree cache
    key."""

    verts: np.ndarray
    nv: np.ndarray
    normal: np.ndarray
    center: np.ndarray
    area: np.ndarray
    doff: np.ndarray
    flo: np.ndarray
    fhi: np.ndarray
    gid: np.ndarray
    J: np.ndarray
    R: np.ndarray
    qn: np.ndarray
    qw: np.ndarray
    qc: np.ndarray
    start: np.ndarray
    end: np.ndarray
    left: np.ndarray
    right: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    axis: np.ndarray
    spread: np.ndarray
    tarea: np.ndarray
    root: int
    n_leaves: int
    tol: float
    pad: float
    key: str
    epsilon: float  # the ray offset (radiosity.rays.epsilon), resolved on the driver


PLANE_TOL = 1e-9   # facing and plane tests: lengths below this fraction of the scene size are 0


def make_inputs(fac: Facets, leaf_size: int):
    """The tree and the worker inputs of facets `fac`."""
    from dask.base import tokenize

    from radiosity.viewfactors.bvh import build_tree
    from radiosity.viewfactors.loops import facet_quadrature, second_moments

    verts = np.ascontiguousarray(fac.verts, np.float64)
    flo, fhi = verts.min(axis=1), verts.max(axis=1)
    tree = build_tree(flo, fhi, fac.center, fac.normal, fac.area, leaf_size)
    p = tree.perm
    v = verts[p]
    nv = fac.nverts[p].astype(np.int64)
    normal, center, area = fac.normal[p], fac.center[p], fac.area[p]
    doff = np.einsum("ic,ic->i", normal, center)
    dev = np.abs(np.einsum("ic,ikc->ik", normal, v) - doff[:, None]).max(axis=1)
    size = float(np.linalg.norm(fhi.max(0) - flo.min(0))) or 1.0
    tol = PLANE_TOL * size + float(dev.max(initial=0.0))
    J, R = second_moments(v, nv, center, area)
    qn, qw, qc = facet_quadrature(v, nv, area)
    inp = Inputs(verts=v, nv=nv, normal=normal, center=center, area=area, doff=doff,
                 flo=flo[p], fhi=fhi[p], gid=p, J=J, R=R, qn=qn, qw=qw, qc=qc,
                 start=tree.start, end=tree.end, left=tree.left, right=tree.right, lo=tree.lo,
                 hi=tree.hi, axis=tree.axis, spread=tree.spread, tarea=tree.area,
                 root=tree.root, n_leaves=len(tree.leaves), tol=tol, pad=tol,
                 key="vf-" + tokenize(v, nv), epsilon=float(config.get("rays.epsilon")))
    return tree, inp


def plan_tasks(tree, n: int, task_pairs: int, min_tasks: int) -> list:
    """Runs of consecutive leaves (tree order), each about the same number of pairs (i < j
    with i in the run), at most task_pairs unless one leaf holds more, and at least
    min_tasks runs when there are enough leaves. Returns a list of leaf-id arrays."""
    lv = tree.leaves
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


# ----------------------------------------------------------------------------- the task

def task_viewfactors(inp: Inputs, prm: Params, leaves: np.ndarray, store_path: str,
                     task: int) -> dict:
    """All pairs (i, j), i in the given leaves, i < j in tree order: compute, write to the
    store (store.write_vf_task), and return the manifest entry: task, crc, n, nd, counts
    (len(COUNTERS),), times (len(STAGES),) seconds, cpu seconds, start, stop, pid."""
    from radiosity.tracing.rays import caster_for
    from radiosity.viewfactors.store import write_vf_task

    t0, c0 = time.time(), time.process_time()
    caster = caster_for(inp.key, inp.verts, inp.nv, inp.epsilon)
    counts = np.zeros(len(COUNTERS), np.int64)
    times = np.zeros(len(STAGES))
    parts, drops = [], []
    for a in np.asarray(leaves).tolist():
        p, d = _leaf(inp, prm, caster, a, counts, times)
        parts += p
        drops.append(d)
    if parts:
        ij = np.stack([np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])], 1)
        f = np.stack([np.concatenate([p[k] for p in parts]) for k in (2, 3, 4)], 1)
    else:
        ij, f = np.zeros((0, 2), np.int32), np.zeros((0, 3))
    drop = np.concatenate(drops) if drops else np.zeros((0, 4))
    counts[_STORED] = len(ij)
    res = write_vf_task(store_path, task, ij, f, drop)
    res.update(task=int(task), counts=counts.tolist(), times=times.tolist(), start=t0,
               stop=time.time(), cpu=time.process_time() - c0, worker=worker_address())
    return res


def _leaf(inp: Inputs, prm: Params, caster, a: int, counts: np.ndarray, times: np.ndarray):
    """The pairs of leaf a against every later facet: list of (i, j, F, F_unobstructed, bound)
    batches (original ids) and the dropped cluster pairs (d, 4)."""
    from radiosity.viewfactors.loops import near_leaves

    t = time.perf_counter()
    n = len(inp.area)
    buf = np.empty(inp.n_leaves, np.int64)
    k = len(inp.start)
    dn, dab, dba = np.empty(k, np.int64), np.empty(k), np.empty(k)
    nl, culled, dropped, nd = near_leaves(inp.start, inp.end, inp.left, inp.right, inp.lo, inp.hi,
                                          inp.axis, inp.spread, inp.tarea, inp.root, a, inp.tol,
                                          prm.cutoff, buf, dn, dab, dba)
    a0, a1 = int(inp.start[a]), int(inp.end[a])
    na = a1 - a0
    counts[_TOTAL] += na * (na - 1) // 2 + na * (n - a1)
    counts[_CULLED] += culled
    counts[_DROPPED] += dropped
    drop = np.column_stack([np.full(nd, a, np.float64), dn[:nd], dab[:nd], dba[:nd]])
    bl = buf[:nl]
    times[0] += time.perf_counter() - t
    out = []
    sizes = na * (inp.end[bl] - inp.start[bl])
    s = 0
    while s < nl:
        e, acc = s, 0
        while e < nl and (e == s or acc + sizes[e] <= prm.batch_pairs):
            acc += sizes[e]
            e += 1
        out.append(_batch(inp, prm, caster, a, bl[s:e], counts, times))
        s = e
    return out, drop


def _batch(inp: Inputs, prm: Params, caster, a: int, bl: np.ndarray, counts: np.ndarray,
           times: np.ndarray):
    """Leaf a against the leaves bl: facing pairs, unobstructed F (cheap or exact), shafts,
    sampled visibility. Returns (i, j) original ids (int32), F, F unobstructed, cheap bound."""
    from radiosity.core.exact import pair_form_factors_exact
    from radiosity.viewfactors.loops import cheap_ff, facing_pairs, prove_unobstructed

    t = time.perf_counter()
    a0, a1 = int(inp.start[a]), int(inp.end[a])
    cap = int((a1 - a0) * (inp.end[bl] - inp.start[bl]).sum())
    ia, ib, blk = np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64)
    full = np.empty(cap, np.bool_)
    m, away = facing_pairs(inp.verts, inp.nv, inp.normal, inp.doff, a0, a1, inp.start[bl],
                           inp.end[bl], inp.tol, ia, ib, blk, full)
    counts[_AWAY] += away
    counts[_FACING] += m
    ia, ib, blk, full = ia[:m], ib[:m], blk[:m], full[:m]
    t1 = time.perf_counter()
    times[0] += t1 - t
    f, bnd = np.empty(m), np.empty(m)
    cheap_ff(ia, ib, full, inp.normal, inp.center, inp.area, inp.J, inp.R, inp.flo, inp.fhi,
             inp.qn, inp.qw, inp.qc, f, bnd)
    cheap = bnd <= prm.cheap_rel * f
    ex = np.nonzero(~cheap)[0]
    if len(ex):
        f[ex] = pair_form_factors_exact(inp.verts[ia[ex]], inp.nv[ia[ex]], inp.verts[ib[ex]],
                                        inp.nv[ib[ex]], two_sided=False)
        bnd[ex] = 0.0
    counts[_CHEAP] += m - len(ex)
    counts[_EXACT] += len(ex)
    keep = np.nonzero(f > 0)[0]
    counts[_ZERO] += m - len(keep)
    ia, ib, blk, f, bnd = ia[keep], ib[keep], blk[keep], f[keep], bnd[keep]
    t2 = time.perf_counter()
    times[1] += t2 - t1
    # the accuracy holds for both directions: F_ji = F_ij A_i / A_j may be the larger one
    fmax = f * np.maximum(1.0, inp.area[ia] / inp.area[ib])
    proven = np.zeros(len(ia), np.bool_)
    counts[_TESTS] += prove_unobstructed(ia, ib, blk, fmax > prm.accuracy, bl, a, inp.start, inp.end,
                                         inp.left, inp.right, inp.lo, inp.hi, inp.root, inp.verts,
                                         inp.nv, inp.flo, inp.fhi, inp.normal, inp.doff, inp.pad,
                                         proven)
    t3 = time.perf_counter()
    times[2] += t3 - t2
    phi = np.ones(len(ia))
    un = np.nonzero(~proven)[0]
    counts[_PROVEN] += len(ia) - len(un)
    if len(un):
        phi[un] = _sampled(inp, prm, caster, ia[un], ib[un], fmax[un], counts)
    times[3] += time.perf_counter() - t3
    F = f * phi
    nz = np.nonzero(F > 0)[0]
    counts[_BLOCKED] += len(F) - len(nz)
    return (inp.gid[ia[nz]].astype(np.int32), inp.gid[ib[nz]].astype(np.int32), F[nz], f[nz],
            bnd[nz])


def _sampled(inp: Inputs, prm: Params, caster, fi, fj, fu, counts) -> np.ndarray:
    """Visible fractions (k,) of pairs (fi, fj) (tree order) whose larger unobstructed factor
    (of F_ij, F_ji) is fu: a pair
    with fu <= accuracy takes level 1 (one ray between centroids); a larger one starts at
    the level s0 where one sample pair carries at most the accuracy (fu / s0^4 <= accuracy),
    stops there if all its sample pairs agree (phi = 0 or 1), and else doubles s until two
    successive levels agree (fu |phi_s - phi_s/2| <= accuracy) or s reaches smax."""
    k = len(fi)
    counts[_SAMPLED] += k
    phi = np.zeros(k)
    prev = np.full(k, np.nan)
    small = fu <= prm.accuracy
    lev = np.ones(k, np.int64)
    big = np.nonzero(~small)[0]
    s0 = np.ceil((fu[big] / prm.accuracy) ** 0.25 - 1e-9)
    lev[big] = np.minimum(2 ** np.ceil(np.log2(np.maximum(s0, 1.0))).astype(np.int64), prm.smax)
    active = np.arange(k)
    while len(active):
        ph = np.empty(len(active))
        la = lev[active]
        for s in np.unique(la).tolist():
            g = np.nonzero(la == s)[0]
            ph[g] = _level(inp, prm, caster, fi[active[g]], fj[active[g]], int(s), counts)
        has = ~np.isnan(ph)
        sm = small[active]
        pp = prev[active]
        agree = has & ~np.isnan(pp) & (fu[active] * np.abs(ph - pp) <= prm.accuracy)
        # the first level, unanimous (every sample pair visible, or none): a region it missed
        # lies within one cell pair, which carries at most the accuracy
        agree |= has & np.isnan(pp) & ((ph == 0.0) | (ph == 1.0))
        last = la >= prm.smax
        accept = has & (sm | agree | last)
        counts[_ONE] += int(np.count_nonzero(accept & sm & (la == 1)))
        counts[_CAPPED] += int(np.count_nonzero(has & ~sm & ~agree & last))
        phi[active[accept]] = ph[accept]
        # no sample pair with a positive kernel even at the finest level (facets that barely
        # face each other): keep the last level that had one, else 0
        gone = ~accept & last
        rest = active[gone]
        phi[rest] = np.where(np.isnan(prev[rest]), 0.0, prev[rest])
        counts[_UNRES] += len(rest)
        upd = has & ~accept
        prev[active[upd]] = ph[upd]
        active = active[~accept & ~gone]
        lev[active] *= 2
    return phi


def _level(inp: Inputs, prm: Params, caster, fi, fj, s: int, counts) -> np.ndarray:
    """phi at level s (s x s points per facet, s^4 rays per pair) for pairs (fi, fj); NaN
    where no sample pair has a positive kernel."""
    from radiosity.viewfactors.loops import sample_facets, sample_rays, visible_fraction

    S = s * s
    per = S * S
    out = np.empty(len(fi))
    step = max(1, prm.ray_batch // per)
    for c0 in range(0, len(fi), step):
        a, b = fi[c0:c0 + step], fj[c0:c0 + step]
        kk = len(a)
        U, inv = np.unique(np.concatenate([a, b]), return_inverse=True)
        pts, w = np.empty((len(U) * S, 3)), np.empty(len(U) * S)
        sample_facets(U, inp.gid, s, prm.seed, inp.verts, inp.nv, inp.center, inp.area, pts, w)
        ptr = np.empty(kk + 1, np.int64)
        ra, rb, term = np.empty(kk * per, np.int64), np.empty(kk * per, np.int64), np.empty(kk * per)
        nr = sample_rays(inv[:kk], inv[kk:], S, pts, w, inp.normal, a, b, ptr, ra, rb, term)
        vis = ~caster.occluded_pairs(pts, ra[:nr], rb[:nr], np.repeat(U, S))
        ph = np.empty(kk)
        visible_fraction(ptr, term[:nr], vis, ph)
        out[c0:c0 + kk] = ph
        counts[_RAYS] += nr
    return out


# ----------------------------------------------------------------------------- the master

@dataclass
class ViewFactors:
    """matrix: CSR (n, n) float64, F[i, j] from facet i to facet j (load order; balanced when
    the facets were treated as an enclosure); area (n,); facets; figures (the report section)."""

    matrix: object
    area: np.ndarray
    facets: Facets
    figures: dict


def compute_viewfactors(mesh, out: str, client, *, accuracy=None, enclosure=None, fmt="npz",
                        cutoff=None, resume: bool = False, progress: bool = True,
                        on_done=None) -> ViewFactors:
    """View factors of the facets of `mesh` (load_facets) into the run directory `out`:
    store.zarr (facets, per-task pairs, the CSR matrix), viewfactors.npz, facets.csv
    (viewfactors.csv with fmt="csv"), report.json (section "viewfactors"). enclosure: auto |
    on | off (default radiosity.viewfactors.enclosure). resume: keep the finished tasks of an
    interrupted run with the same inputs. on_done(n) after each finished task (tests)."""
    from dask.base import tokenize

    from radiosity.runtime.store import RunStore, update_report

    from radiosity.viewfactors.store import create_vf, read_vf_task, vf_manifest, vf_token

    t_start = time.perf_counter()
    mode = config.get("viewfactors.enclosure", enclosure)
    if mode not in ENCLOSURE_MODES:
        raise RadiosityError(f"--enclosure must be one of {', '.join(ENCLOSURE_MODES)}, got {mode!r}")
    if fmt not in FORMATS:
        raise RadiosityError(f"--format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    prm = resolve_params(accuracy, cutoff)
    fac = load_facets(mesh)
    n = len(fac)
    leaf_size = int(config.get("viewfactors.leaf-size"))
    tree, inp = make_inputs(fac, leaf_size)
    threads = sum(client.nthreads().values()) or 1
    tasks = plan_tasks(tree, n, int(config.get("viewfactors.task-pairs")),
                       int(config.get("viewfactors.tasks-per-worker")) * threads)
    token = tokenize(VERSION, fac.verts, fac.nverts, asdict(prm), leaf_size,
                     [t.tolist() for t in tasks])
    store = os.path.join(os.path.abspath(out), "store.zarr")
    rs = None
    done: dict = {}
    corrupted = 0
    man = vf_manifest(os.path.abspath(out))
    if resume and os.path.exists(store):
        rs = RunStore(out, "r+")
        if vf_token(rs) == token:
            for task, entry in man.finished(token).items():
                try:
                    read_vf_task(rs.path, task, entry)
                    done[task] = entry
                except RadiosityError:
                    corrupted += 1
            if corrupted:
                man.rewrite(token, done)
        else:
            rs = None
    if rs is None:
        rs = RunStore(out, "w")
        rs.set_attrs(kind="viewfactors", sources=list(fac.sources))
        rs.write_arrays("facets", {"verts": fac.verts, "nverts": fac.nverts, "area": fac.area,
                                   "normal": fac.normal, "center": fac.center, "face": fac.face,
                                   "source": fac.source})
        create_vf(rs, token, {"params": asdict(prm), "leaf_size": leaf_size, "tasks": len(tasks)})
    costs = np.array([task_cost(tree, n, t) for t in tasks], np.int64)
    order = [t for t in np.lexsort((np.arange(len(tasks)), -costs)).tolist() if t not in done]
    busy: dict = {}

    def record(task, res):
        man.record({k: res[k] for k in ("task", "crc", "n", "nd", "counts", "times", "cpu")})
        done[task] = res
        busy[res["worker"]] = busy.get(res["worker"], 0.0) + res["stop"] - res["start"]

    t_tasks = time.perf_counter()
    computed = 0
    if order:
        shared = Scattered(client, inp)
        from radiosity.runtime.runner import run_tasks

        n_done = [0]

        def record_and_count(task, res):
            record(task, res)
            n_done[0] += 1
            if on_done is not None:
                on_done(n_done[0])

        # order is already most expensive first: the runner keeps it (cost=None)
        computed = run_tasks(
            client, task_viewfactors, order, lambda t: (shared.future(), prm, tasks[t], rs.path, t),
            name="viewfactors", token=tokenize(token, rs.path), window=max(
                1, int(config.get("viewfactors.window-per-worker")) * threads),
            retries=int(config.get("viewfactors.retries")), on_result=record_and_count,
            progress=progress, repair=f"rerun with: radiosity viewfactors MESH --out {out} --resume"
        ).finished
    t_tasks = time.perf_counter() - t_tasks
    counts = np.zeros(len(COUNTERS), np.int64)
    stage = np.zeros(len(STAGES))
    cpu = 0.0
    for e in done.values():
        counts += np.asarray(e["counts"], np.int64)
        stage += np.asarray(e["times"])
        cpu += e["cpu"]

    t_asm = time.perf_counter()
    asm = assemble(rs, fac, tree, {t: done[t] for t in range(len(tasks))})
    t_asm = time.perf_counter() - t_asm
    fig = finish(rs, out, fac, asm, mode, fmt, prm)
    nworkers = len(client.scheduler_info()["workers"]) or 1
    fig.update({
        "facets": n, "accuracy": prm.accuracy, "cutoff": prm.cutoff,
        "cheap_kernel_relative_bound": prm.cheap_rel, "max_points_per_side": prm.smax,
        **dict(zip(COUNTERS, counts.tolist())),
        "tasks": len(tasks), "tasks_computed": computed, "tasks_reused": len(tasks) - computed,
        "tasks_corrupted_recomputed": corrupted, "leaf_size": leaf_size,
        "time_tasks_s": round(t_tasks, 3), "time_assembly_s": round(t_asm, 3),
        "task_time_by_stage_s": {k: round(float(v), 3) for k, v in zip(STAGES, stage)},
        "task_cpu_s": round(cpu, 3),
        "busy_s_per_worker": {str(k): round(v, 3) for k, v in busy.items()},
        "workers": nworkers, "peak_rss_mb": _peak_rss_mb(client),
    })
    matrix = fig.pop("_matrix")
    fig["time_s"] = round(time.perf_counter() - t_start, 3)
    update_report(out, "viewfactors", fig)
    return ViewFactors(matrix, fac.area, fac, fig)


def _peak_mib() -> float:
    """Peak resident memory of this process's program image (MiB): VmHWM of /proc/self/status.
    ru_maxrss is not used: Linux carries it across fork and exec, so a worker spawned by a
    driver that once held 1 GiB would report 1 GiB."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:  # not Linux
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _peak_rss_mb(client) -> dict:
    """Peak resident memory of the driver and of each worker (MiB)."""
    out = {"master": round(_peak_mib(), 1)}
    try:
        out["workers"] = {k: round(v, 1) for k, v in client.run(_peak_mib).items()}
    except Exception:  # a worker that died has no figure
        pass
    return out


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

    from radiosity.viewfactors.store import read_vf_task
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
    dropped[tree.perm] = np.cumsum(dropdiff)[:n]
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


HIST_EDGES = (0.0, 0.25, 0.5, 0.75, 0.9, 0.99, 0.999, 1.001, 1.01, np.inf)


def row_histogram(rows: np.ndarray) -> dict:
    """Counts of row sums in the bins of HIST_EDGES, as {"[a, b)": count}."""
    h, _ = np.histogram(rows, bins=np.array(HIST_EDGES))
    names = [f"[{a:g}, {b:g})" for a, b in zip(HIST_EDGES[:-1], HIST_EDGES[1:])]
    return dict(zip(names, h.tolist()))


def _worst(fac: Facets, values: np.ndarray, idx: np.ndarray, k: int = 5) -> str:
    return "; ".join(f"{fac.describe(int(i))}: {values[i]:.6g}" for i in idx[:k])


def finish(rs, out: str, fac: Facets, asm: Assembled, mode: str, fmt: str, prm: Params) -> dict:
    """Enclosure test and balancing, checks and warnings, outputs. Returns the figures (with
    the final matrix under "_matrix")."""
    import scipy.sparse as sp

    from radiosity.viewfactors.enclosure import balance, closure
    from radiosity.viewfactors.store import write_vf_matrix
    from radiosity.viewfactors.loops import reciprocity_residual

    F = asm.matrix
    n = F.shape[0]
    A = fac.area
    rows0 = np.asarray(F.sum(axis=1)).ravel()
    cl = closure(fac.verts, fac.nverts)
    do_balance = mode == "on" or (mode == "auto" and cl.enclosure)
    fig: dict = {"enclosure_mode": mode, "closed": cl.closed, "normals_inward": cl.inward,
                 "enclosure": cl.enclosure, "not_enclosure_because": cl.reason,
                 "balanced": do_balance, "nonzeros": int(F.nnz),
                 "row_sum_min": float(rows0.min()), "row_sum_max": float(rows0.max()),
                 "row_sum_histogram": row_histogram(rows0),
                 "obstructed_over_unobstructed": asm.violations,
                 "cheap_kernel_row_bound_max": float(asm.cheap_bound.max(initial=0.0)),
                 "dropped_row_bound_max": float(asm.dropped_bound.max(initial=0.0))}
    if mode == "on" and not cl.enclosure:
        warnings.warn(f"--enclosure on: the facets do not form an enclosure ({cl.reason}); "
                      "their rows are balanced to 1 all the same")
    scale = np.ones(n)
    if do_balance:
        dev = np.abs(rows0 - 1.0)
        bad = np.argsort(-dev)
        if dev[bad[0]] > 10 * prm.accuracy:
            warnings.warn(f"enclosure rows sum to 1 +- {dev[bad[0]]:.3g} before balancing "
                          f"(more than 10 x the accuracy {prm.accuracy:g}); worst rows: "
                          f"{_worst(fac, rows0, bad)}")
        F, bal = balance(F, tol=float(config.get("viewfactors.balance-tol")),
                         max_iterations=int(config.get("viewfactors.balance-max-iterations")))
        scale = bal.scale
        fig.update({"balance_iterations": bal.iterations, "balance_converged": bal.converged,
                    "balance_scale_min": float(scale.min()), "balance_scale_max": float(scale.max())})
        if not bal.converged:
            warnings.warn(f"balancing stopped after {bal.iterations} iterations with rows "
                          f"1 +- {bal.residual_after:.3g}")
    rows = np.asarray(F.sum(axis=1)).ravel()
    diag = F.diagonal()
    fig.update({
        "row_sum_final_min": float(rows.min()), "row_sum_final_max": float(rows.max()),
        "row_sum_final_histogram": row_histogram(rows),
        "factor_min": float(F.data.min()) if F.nnz else 0.0,
        "factor_max": float(F.data.max()) if F.nnz else 0.0,
        "self_factors": int(np.count_nonzero(diag)),
        "reciprocity_residual_max": float(reciprocity_residual(F.indptr, F.indices.astype(np.int64),
                                                               F.data, A)),
        "rows_with_no_factor": int(np.count_nonzero(rows == 0)),
    })
    over = np.nonzero(rows > 1.0 + max(prm.accuracy, 1e-12))[0]
    fig["rows_over_1"] = int(len(over))
    if len(over):
        worst = over[np.argsort(-rows[over])]
        warnings.warn(f"{len(over)} rows sum to more than 1 + {prm.accuracy:g}: {_worst(fac, rows, worst)}")
    if fig["factor_min"] < 0 or fig["factor_max"] > 1:
        warnings.warn(f"factors outside [0, 1]: min {fig['factor_min']:.6g}, max {fig['factor_max']:.6g}")
    if asm.violations:
        warnings.warn(f"{asm.violations} pairs have an obstructed factor above the unobstructed one")
    # outputs
    write_vf_matrix(rs, F.indptr, F.indices, F.data, scale, {"balanced": do_balance})
    os.makedirs(out, exist_ok=True)
    sp.save_npz(os.path.join(out, "viewfactors.npz"), F, compressed=True)
    _write_facets_csv(os.path.join(out, "facets.csv"), fac, rows)
    files = ["viewfactors.npz", "facets.csv"]
    if fmt == "csv":
        limit = int(config.get("viewfactors.csv-max-nonzeros"))
        if F.nnz > limit:
            raise RadiosityError(f"--format csv: {F.nnz} nonzeros is more than "
                                 f"radiosity.viewfactors.csv-max-nonzeros ({limit}); use npz")
        _write_matrix_csv(os.path.join(out, "viewfactors.csv"), F)
        files.append("viewfactors.csv")
    fig["files"] = files
    fig["_matrix"] = F
    return fig


def _write_facets_csv(fn: str, fac: Facets, rows: np.ndarray) -> None:
    with open(fn, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["facet", "source", "face", "area", "cx", "cy", "cz", "nx", "ny", "nz", "row_sum"])
        for i in range(len(fac)):
            w.writerow([i, os.path.basename(fac.sources[fac.source[i]]), int(fac.face[i]),
                        repr(float(fac.area[i])), *(repr(float(x)) for x in fac.center[i]),
                        *(repr(float(x)) for x in fac.normal[i]), repr(float(rows[i]))])


def _write_matrix_csv(fn: str, F) -> None:
    C = F.tocoo()
    with open(fn, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["i", "j", "F_ij"])
        for i, j, v in zip(C.row.tolist(), C.col.tolist(), C.data.tolist()):
            w.writerow([i, j, repr(v)])


# ----------------------------------------------------------------------------- the API

def viewfactors(mesh, *, accuracy: float | None = None, enclosure: str | None = None,
                out: str | None = None, client=None, workers: int | None = None,
                resume: bool = False, progress: bool = False):
    """The view-factor matrix of the facets of `mesh` (a mesh or scene path, a
    trimesh.Trimesh, a (vertices, faces) pair): scipy.sparse.csr_matrix (n, n), F[i, j] the
    fraction of the power leaving facet i (front side) that reaches facet j, rows in the
    order the facets were loaded (facets.csv in `out` names them).

    accuracy: target absolute error per factor (default radiosity.viewfactors.accuracy);
    enclosure: auto | on | off; out: run directory (default: a temporary one, removed after);
    client: a distributed.Client (default: a LocalCluster of `workers` for this call)."""
    import tempfile

    from radiosity.runtime.cluster import open_client

    with tempfile.TemporaryDirectory(prefix="radiosity-vf-") as tmp:
        run = out or tmp
        if client is not None:
            return compute_viewfactors(mesh, run, client, accuracy=accuracy, enclosure=enclosure,
                                       resume=resume, progress=progress).matrix
        with open_client(workers, quiet=True) as c:
            return compute_viewfactors(mesh, run, c, accuracy=accuracy, enclosure=enclosure,
                                       resume=resume, progress=progress).matrix
