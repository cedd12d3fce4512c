"""The segment queries' occluders with each flat face as one polygon: a face cut into many
coplanar triangles (a tessellated wall or block) blocks a segment exactly where its union does,
and Embree answers a segment near one big polygon faster than near thousands of small ones.

Design notes and measurements: docs/src/design/methods-hierarchical-clusters.md ("Flat faces as one
occluder").
"""

from __future__ import annotations

import numpy as np

from radiosity.core.geometry import element_triangles, tangent_basis
from radiosity.core.tolerances import TOL

#: Faces of at least this many elements are merged: below it the triangles are few anyway.
MIN_ELEMENTS = 8
# Its tolerances: core.tolerances' occluder_area, occluder_normal and occluder_plane.


def merged_faces(verts: np.ndarray, nverts: np.ndarray, normal: np.ndarray, area: np.ndarray,
                 scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangles (t, 3, 3) that cover the polygons (n, 4, 3) exactly, with every set of at least
    MIN_ELEMENTS edge-connected coplanar polygons whose union is convex replaced by a fan over
    that union's hull; and the group of each triangle (t,) and of each polygon (n,) int64 (a
    merged face is one group, every other polygon its own). A segment that leaves a polygon
    meets its plane only there, so a hit on its own group is a hit on itself."""
    n = len(verts)
    group = np.arange(n, dtype=np.int64)
    faces = _faces(verts, nverts, normal, scale) if n >= MIN_ELEMENTS else []
    merged = np.zeros(n, bool)
    fans, fan_group = [], []
    for members in faces:
        hull = _convex_union(verts[members], nverts[members], normal[members[0]],
                             float(area[members].sum()), TOL.occluder_plane * scale)
        if hull is None:
            continue
        merged[members] = True
        group[members] = members[0]
        fans.append(np.stack([np.broadcast_to(hull[0], hull[1:-1].shape), hull[1:-1], hull[2:]], 1))
        fan_group.append(np.full(len(hull) - 2, members[0], np.int64))
    rest = np.nonzero(~merged)[0]
    tris, owner = element_triangles(verts[rest], nverts[rest])
    tris = np.concatenate([tris] + fans) if fans else tris
    owner = np.concatenate([rest[owner]] + fan_group) if fans else rest[owner]
    return tris, owner.astype(np.int64), group


def _faces(verts, nverts, normal, scale) -> list[np.ndarray]:
    """The sets of at least MIN_ELEMENTS polygons connected through shared edges (the same two
    vertices) between polygons whose normals agree within TOL.occluder_normal."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(verts)
    _, lo, hi, poly = _edges(verts, nverts)
    order = np.lexsort((hi, lo))
    lo, hi, poly = lo[order], hi[order], poly[order]
    same = (lo[1:] == lo[:-1]) & (hi[1:] == hi[:-1])
    i, j = poly[:-1][same], poly[1:][same]
    flat = np.einsum("ij,ij->i", normal[i], normal[j]) >= 1.0 - TOL.occluder_normal
    i, j = i[flat], j[flat]
    graph = coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    _, comp = connected_components(graph, directed=False)
    sizes = np.bincount(comp)
    big = np.nonzero(sizes >= MIN_ELEMENTS)[0]
    if not len(big):
        return []
    order = np.argsort(comp, kind="stable")
    starts = np.concatenate([[0], np.cumsum(sizes)])
    return [order[starts[c]:starts[c + 1]] for c in big]


def _edges(verts, nverts):
    """Vertex ids (n, 4) by exact coordinates, the unique vertices, and each polygon edge as
    (lo, hi) vertex ids with its polygon (a triangle's fourth slot repeats its third vertex and
    adds no edge)."""
    n = len(verts)
    pts, vid = np.unique(verts.reshape(-1, 3), axis=0, return_inverse=True)
    vid = vid.reshape(n, 4)
    b = np.where((nverts == 3)[:, None], vid[:, [1, 2, 0, 0]], vid[:, [1, 2, 3, 0]])
    ok = (nverts[:, None] == 4) | (np.arange(4)[None, :] < 3)
    poly = np.broadcast_to(np.arange(n)[:, None], (n, 4))[ok]
    return pts, np.minimum(vid, b)[ok], np.maximum(vid, b)[ok], poly


def _convex_union(verts, nverts, normal, area: float, tol: float) -> np.ndarray | None:
    """The convex hull (h, 3) of edge-connected polygons, in order around it, where it is their
    union: every vertex within `tol` of one plane, every edge of only one polygon (the union's
    boundary) within `tol` of the hull's boundary (no hole, no notch; float32 rounding leaves
    a face's edge ragged by about 1e-7 of the scene) and their areas summing to no more than
    the hull's (no overlap); None otherwise."""
    from scipy.spatial import ConvexHull, QhullError

    pts, lo, hi, _ = _edges(verts, nverts)
    off = pts @ normal
    if off.max() - off.min() > tol:
        return None
    u, v = tangent_basis(np.asarray(normal, np.float64)[None])
    uv = np.column_stack([pts @ u[0], pts @ v[0]])
    try:
        hull = ConvexHull(uv)
    except QhullError:
        return None
    if area > hull.volume * (1.0 + TOL.occluder_area):  # in two dimensions, its volume is its area
        return None
    key = lo * len(pts) + hi
    uniq, count = np.unique(key, return_counts=True)
    rim = np.unique(np.concatenate([uniq[count == 1] // len(pts), uniq[count == 1] % len(pts)]))
    # each hull line is a . x + c = 0 with a the unit outward normal: 0 on it, < 0 inside
    height = uv[rim] @ hull.equations[:, :2].T + hull.equations[:, 2]
    if (height.max(axis=1) < -tol).any():
        return None
    return pts[hull.vertices]
