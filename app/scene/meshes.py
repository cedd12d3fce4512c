"""A mesh file's faces (a formats reader's RawMesh) -> validated polygons.

Quads stay quads: an OBJ face with four vertices is one element, and two coplanar triangles that
share a diagonal and form a parallelogram are merged back into one (seed §3.2 splits rectangles
across their longer sides). Every problem raises `SceneError` naming the file and the face.
"""

from __future__ import annotations

import itertools

import numpy as np

from radiosity.errors import SceneError
from radiosity.core.geometry import diameter, polygon_properties
from radiosity.formats.raw import RawMesh, warn
from radiosity.scene import meshkernels
from radiosity.settings import Settings

#: Largest vertex coordinate accepted: fourth powers of lengths (|cross product|^2, r^4 in
#: the sampled kernels) must stay finite in float64 (1e75^4 = 1e300 < 1.8e308).
MAX_COORD = 1e75

#: Repairs (non-planar or non-convex quads split, n-gons triangulated) said one by one, per
#: mesh file; beyond these one more line counts the rest.
MAX_FACE_WARNINGS = 10


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a . b of (n, 3) arrays, summed as np.dot sums a 3-vector (to the bit)."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _norm(a: np.ndarray) -> np.ndarray:
    """Row-wise |a| of an (n, 3) array, as np.linalg.norm of a 3-vector (to the bit)."""
    return np.sqrt(_dot(a, a))


def _per_face_any(flags: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Whether any of each face's entries (faces: runs starts[i]:starts[i + 1]) is set."""
    c = np.zeros(len(flags) + 1, np.int64)
    np.cumsum(flags, out=c[1:])
    return c[starts[1:]] > c[starts[:-1]]


def _face_arrays(faces, nv: int):
    """(sizes (F,), starts (F + 1,), flat indices (sum of sizes,) int64) of a list of index
    lists; an index no int64 holds becomes -1 (out of range: named from the list itself)."""
    sizes = np.fromiter(map(len, faces), np.int64, count=len(faces))
    starts = np.zeros(len(faces) + 1, np.int64)
    np.cumsum(sizes, out=starts[1:])
    try:
        flat = np.fromiter(itertools.chain.from_iterable(faces), np.int64, count=int(starts[-1]))
    except (OverflowError, TypeError, ValueError):
        flat = np.fromiter((k if 0 <= k < nv else -1 for k in itertools.chain.from_iterable(faces)),
                           np.int64, count=int(starts[-1]))
    return sizes, starts, flat


def _quad_shapes(p: np.ndarray, tol: float):
    """planar (q,), convex (q,) and the split along the other diagonal (q,) of quads p (q, 4, 3),
    each face as the per-face loop decided it: planar if the normal and the (0, 1, 2) cross
    product are non-zero and vertex 3 is off the (0, 1, 2) plane by at most tol times the
    diameter; convex if every corner turns the way of the normal; a quad that is not both is
    split along 0-2, or along 1-3 when it is planar and the halves (0, 1, 2), (0, 2, 3) face
    opposite ways."""
    p0, p1, p2, p3 = p[:, 0], p[:, 1], p[:, 2], p[:, 3]
    with np.errstate(divide="ignore", invalid="ignore"):  # used only where planar
        c012 = np.cross(p1 - p0, p2 - p0)
        c023 = np.cross(p2 - p0, p3 - p0)
        n = c012 + c023
        nn = _norm(n)
        diam = diameter(p)
        off = np.abs(_dot(p3 - p0, c012))
        c = _norm(c012)
        planar = (nn > 0) & (c > 0) & (off / c <= tol * np.maximum(diam, 1e-300))
        unit = n / nn[:, None]
        convex = np.ones(len(p), bool)
        for k in range(4):
            a, b, d = p[:, k], p[:, (k + 1) % 4], p[:, (k + 2) % 4]
            convex &= _dot(np.cross(b - a, d - b), unit) > 0
    other = planar & (_dot(c023, c012) <= 0)
    return planar, convex & planar, other


def polygons_from_raw(raw: RawMesh, fn: str, settings: Settings, merge: bool = True,
                      first_face: int = 1):
    """Validate faces and turn them into polygons: (verts (n,4,3), nverts (n,), face (n,), material names).

    Non-planar or non-convex quads become two triangles, n-gons a triangle fan; each with a warning
    (the first MAX_FACE_WARNINGS of a file, then one line for the rest). merge=False keeps
    triangle pairs that form parallelograms apart (view factors between the user's own facets).
    settings: the run's (its scene.* tolerances). first_face: the number the messages
    give the file's first face, as the command's files count (1: surfaces.csv, OBJ; 0: the
    view factors' facets.csv). Whole-array operations per face size
    (triangles, quads, n-gons); the first bad face in file order is the one named.
    """
    sc = settings.scene
    tol = sc.planarity_tolerance
    V = np.asarray(raw.vertices, float).reshape(-1, 3)
    nv = len(V)
    nf = len(raw.faces)
    if nf == 0:
        return np.zeros((0, 4, 3)), np.zeros(0, np.int8), np.zeros(0, np.int32), []
    sizes, starts, flat = _face_arrays(raw.faces, nv)

    # the first bad face, with the per-face checks in their order
    out_of_range = (flat < 0) | (flat >= nv)
    safe = np.where(out_of_range, 0, flat)
    e_index = _per_face_any(out_of_range, starts)
    e_size = sizes < 3
    if nv:
        flags = meshkernels.vertex_flags(np.ascontiguousarray(V), MAX_COORD)[safe]
        flags[out_of_range] = 0
        e_finite = _per_face_any(flags == 1, starts)
        e_huge = _per_face_any(flags == 2, starts)
    else:
        e_finite = e_huge = np.zeros(nf, bool)
    bad = np.flatnonzero(e_index | e_size | e_finite | e_huge)
    nok = int(bad[0]) if len(bad) else nf  # faces before the first bad one

    # quads and n-gons among them: the repairs, said in face order
    quad = np.flatnonzero(sizes[:nok] == 4)
    pq = V[flat[starts[quad][:, None] + np.arange(4)]]
    planar, keep, other = _quad_shapes(pq, tol)
    ngon = np.flatnonzero(sizes[:nok] > 4)
    said = np.sort(np.concatenate([quad[~keep], ngon]))
    fm = raw.face_material
    for fi in said[:MAX_FACE_WARNINGS].tolist():
        if sizes[fi] == 4:
            what = "non-planar" if not planar[np.searchsorted(quad, fi)] else "non-convex"
            warn(f"{fn}: face {fi + first_face} (material '{fm[fi]}') is a {what} quad; "
                 "split into two triangles")
        else:
            warn(f"{fn}: face {fi + first_face} has {sizes[fi]} vertices; triangulated as a fan")
    if len(said) > MAX_FACE_WARNINGS:
        warn(f"{fn}: and {len(said) - MAX_FACE_WARNINGS} more faces split into triangles likewise "
              "(non-planar or non-convex quads, n-gons)")

    if nok < nf:
        fi = nok
        idx = raw.faces[fi]
        if e_index[fi]:
            wrong = [k for k in idx if not 0 <= k < nv]
            raise SceneError(f"{fn}: face {fi + first_face} refers to vertex {wrong[0]}, which does not exist "
                             f"({nv} vertices)")
        if e_size[fi]:
            raise SceneError(f"{fn}: face {fi + first_face} has {len(idx)} vertices; a face needs at least 3")
        p = V[flat[starts[fi]:starts[fi + 1]]]
        if e_finite[fi]:
            raise SceneError(f"{fn}: face {fi + first_face} has a NaN or infinite vertex coordinate")
        raise SceneError(f"{fn}: face {fi + first_face} has a vertex coordinate of {np.abs(p).max():.3g}: "
                         f"beyond {MAX_COORD:g}, lengths to the fourth power overflow; "
                         "rescale the mesh")

    # the polygons, in face order: a triangle or a kept quad gives one, a split quad two, an
    # n-gon a fan of n - 2 triangles (a triangle repeats its vertex 2 in slot 3)
    count = np.ones(nf, np.int64)
    count[quad[~keep]] = 2
    count[ngon] = sizes[ngon] - 2
    first = np.zeros(nf + 1, np.int64)
    np.cumsum(count, out=first[1:])
    how = np.zeros(nf, np.int64)  # meshkernels.fill_polygons' cases
    how[quad] = np.where(keep, 1, np.where(other, 3, 2))
    how[ngon] = 4
    verts = np.empty((int(first[-1]), 4, 3))
    meshkernels.fill_polygons(np.ascontiguousarray(V), flat, starts, first, how, verts)
    nverts = np.where(np.all(verts[:, 3] == verts[:, 2], axis=1), 3, 4).astype(np.int8)
    face = np.repeat(np.arange(nf, dtype=np.int32), count)
    out_m = list(map(fm.__getitem__, face.tolist()))
    if merge:
        verts, nverts, face, out_m = merge_parallelograms(verts, nverts, face, out_m,
                                                          sc.merge_tolerance)
    area, _, _ = polygon_properties(verts, nverts)
    diam = diameter(verts)
    bad = np.nonzero(~(area > sc.min_relative_area * diam ** 2))[0]
    if len(bad):
        raise SceneError(f"{fn}: face {face[bad[0]] + first_face} (material '{out_m[bad[0]]}') has zero area"
                         + (f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""))
    return verts, nverts, face, out_m


def merge_parallelograms(verts, nverts, face, mats, tol: float):
    """Merge pairs of coplanar triangles that share a diagonal and form a parallelogram into quads.

    Greedy in file order, each triangle merges at most once; keeps the winding (front side).
    tol: scene.merge-tolerance. A triangle k tries its edges e = 0, 1, 2
    and on each the other triangles on that edge in file order (order of their edge slots);
    the first one that is free, of the same material, wound the other way along the edge and
    forms a parallelogram with k (diagonals that bisect each other, coplanar, within tol) is
    its partner (meshkernels.merge_pairs); k becomes the quad, the partner is dropped.
    """
    tri = np.nonzero(nverts == 3)[0]
    if len(tri) < 2:
        return verts, nverts, face, mats
    P = np.ascontiguousarray(verts[tri, :3], dtype=np.float64)
    pts = P.reshape(-1, 3)
    if np.all(np.isfinite(pts)):  # vertex identity by exact coordinates
        vid = meshkernels.point_ids(pts).reshape(-1, 3)
    else:
        vid = np.unique(pts, axis=0, return_inverse=True)[1].reshape(-1, 3)
    code = {m: i for i, m in enumerate(dict.fromkeys(mats))}
    mat = np.fromiter(map(code.__getitem__, mats), np.int64, count=len(mats))[tri]
    order, gstart, group = meshkernels.edge_runs(np.ascontiguousarray(vid, np.int64))
    partner, edge, pedge = meshkernels.merge_pairs(P, vid, mat, order, gstart, group, float(tol))
    k = np.flatnonzero(edge >= 0)
    if not len(k):
        return verts, nverts, face, mats
    j, e, ej = partner[k], edge[k], pedge[k]
    quads = np.stack([P[k, (e + 1) % 3], P[k, (e + 2) % 3], P[k, e], P[j, (ej + 2) % 3]], axis=1)
    keep = np.ones(len(verts), bool)
    keep[tri[j]] = False
    at = np.cumsum(keep) - 1  # where each kept polygon goes
    keep = np.flatnonzero(keep)
    verts, nverts = verts[keep], nverts[keep]
    verts[at[tri[k]]] = quads
    nverts[at[tri[k]]] = 4
    return verts, nverts, face[keep], list(map(mats.__getitem__, keep.tolist()))
