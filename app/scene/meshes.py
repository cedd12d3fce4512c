"""Mesh files (OBJ+MTL, glTF/GLB, PLY) -> RawMesh -> validated polygons.

Quads stay quads: an OBJ face with four vertices is one element, and two coplanar triangles that
share a diagonal and form a parallelogram are merged back into one (seed §3.2 splits rectangles
across their longer sides). Every problem raises `SceneError` naming the file and the face.
"""

from __future__ import annotations

import gc
import itertools
import os
import re
import warnings
from dataclasses import dataclass, field

import numpy as np

from radiosity.errors import SceneError
from radiosity.core.geometry import diameter, polygon_properties
from radiosity.scene import meshkernels
from radiosity.settings import Settings

MESH_FORMATS = (".obj", ".gltf", ".glb", ".ply")
#: Largest vertex coordinate accepted: fourth powers of lengths (|cross product|^2, r^4 in
#: the sampled kernels) must stay finite in float64 (1e75^4 = 1e300 < 1.8e308).
MAX_COORD = 1e75
_KEYWORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_GARBLED = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ufffd]")


class SceneWarning(UserWarning):
    """Input the loader repaired (non-planar or non-convex quad, n-gon): said, not silent."""


@dataclass
class RawMesh:
    """What a mesh loader returns before validation.

    vertices : (V, 3) float64; faces : list of vertex-index lists (3 or more each);
    face_material : material name per face; materials : name -> dict of file-given properties.
    """

    vertices: np.ndarray
    faces: list
    face_material: list
    materials: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- loaders

def _floats(parts, fn, lineno, n=3):
    try:
        vals = [float(p) for p in parts[:n]]
    except ValueError:
        raise SceneError(f"{fn}:{lineno}: expected {n} numbers, got {' '.join(parts)!r}") from None
    if len(vals) < n:
        raise SceneError(f"{fn}:{lineno}: expected {n} numbers, got {' '.join(parts)!r}")
    return vals


def _check_line(fn: str, lineno: int, line: str, key: str, kind: str) -> None:
    """A text line of an OBJ or MTL file starts with a keyword and holds no binary bytes
    (unknown keywords are skipped, as other readers do; garbage is not)."""
    if _GARBLED.search(line) or not _KEYWORD.match(key):
        raise SceneError(f"{fn} could not be parsed as {kind} (line {lineno}): "
                         f"{line.strip()[:40]!r} is not an {kind} statement")


def _read_whole(fn: str) -> str:
    try:
        with open(fn, encoding="utf-8", errors="replace") as f:
            return f.read()
    except FileNotFoundError:
        raise SceneError(f"mesh file not found: {fn}") from None
    except OSError as e:
        raise SceneError(f"cannot read mesh file {fn}: {e.strerror}") from None


def _read_text(fn: str) -> list[str]:
    return _read_whole(fn).splitlines()


def _load_mtl(fn: str) -> dict:
    mats: dict = {}
    cur = None
    for lineno, line in enumerate(_read_text(fn), 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        key, args = parts[0], parts[1:]
        _check_line(fn, lineno, line.split("#", 1)[0], key, "MTL")
        if key == "newmtl":
            cur = " ".join(args)
            mats[cur] = {}
        elif cur is not None and key == "Kd":
            mats[cur]["reflectance"] = _floats(args, fn, lineno)
        elif cur is not None and key == "Ke":
            mats[cur]["emission"] = _floats(args, fn, lineno)
    return mats


# OBJ texts up to this many characters are read line by line (about 2 000 lines, a few ms)
SMALL_OBJ = 1 << 16


def load_obj(fn: str) -> RawMesh:
    """Minimal OBJ reader (v, f, usemtl, mtllib) that keeps quads as quads.

    trimesh triangulates on load, which would lose the seed's quad elements. The plain lines
    (`v x y z`, `f i j k ...`, comments, unknown statements) are read in bulk
    (meshkernels.scan_obj); a file with anything else in a `v` or `f` line, or any error, is
    read line by line (`_load_obj_lines`), which says what is wrong and where. So is a file of
    at most SMALL_OBJ characters: the same result in a few milliseconds, without compiling
    the bulk scanner on a first run (2-3 s).
    """
    text = _read_whole(fn)
    raw = _load_obj_bulk(fn, text) if len(text) > SMALL_OBJ else None
    return raw if raw is not None else _load_obj_lines(fn, text.splitlines())


def _load_obj_bulk(fn: str, text: str) -> RawMesh | None:
    """The OBJ text read as _load_obj_lines reads it, or None where that reader must (a line the
    scanner leaves to it, an error: it names the first bad line)."""
    if "\r" in text:
        text = text.replace("\r\n", "\n")  # one line break for splitlines too; a lone \r: None
    if not text.isascii() and any(c in text for c in "\x85\u2028\u2029"):
        return None  # more of splitlines' line breaks
    data = text.encode("utf-8")
    scan = meshkernels.scan_obj(np.frombuffer(data, np.uint8))
    if scan is None:
        return None
    coords, slow_pos, slow_buf, fidx, fcount, fline, other = scan
    if len(slow_pos):  # numbers beyond the exact fast path (17 digits, large exponents)
        s = slow_buf[:-1].tobytes().decode("ascii")
        try:
            vals = np.fromstring(s, sep=" ")
        except ValueError:
            vals = np.array([float(t) for t in s.split()])
        if len(vals) != len(slow_pos):
            return None
        coords[slow_pos] = vals
    mats: dict = {}
    cur = "default"
    ev_line, ev_name = [], []
    base = os.path.dirname(fn)
    try:
        for li, start, end in other.tolist():
            line = data[start:end].decode("utf-8")
            parts = line.split("#", 1)[0].split()
            if not parts:
                continue
            key, args = parts[0], parts[1:]
            _check_line(fn, li + 1, line.split("#", 1)[0], key, "OBJ")
            if key in ("v", "f"):
                return None
            if key == "usemtl":
                cur = " ".join(args) or "default"
                ev_line.append(li)
                ev_name.append(cur)
            elif key == "mtllib":
                mfn = os.path.join(base, " ".join(args))
                if not os.path.exists(mfn):
                    return None
                mats.update(_load_mtl(mfn))
    except Exception:  # an error: the line reader says it, with the first bad line's number
        return None
    which = np.searchsorted(np.asarray(ev_line, np.int64), fline, side="right")
    fmat = np.array(["default"] + ev_name, dtype=object)[which].tolist()
    collect = gc.isenabled()
    gc.disable()  # a million small lists: the cyclic collector would walk them all many times
    try:
        if len(fcount) and np.all(fcount == fcount[0]):
            faces = fidx.reshape(len(fcount), -1).tolist()
        else:  # the faces of each size at once, then in file order
            starts = np.zeros(len(fcount) + 1, np.int64)
            np.cumsum(fcount, out=starts[1:])
            faces = np.empty(len(fcount), object)
            for c in np.unique(fcount).tolist():
                sel = np.flatnonzero(fcount == c)
                rows = fidx[starts[sel][:, None] + np.arange(c)].tolist()
                faces[sel] = np.fromiter(rows, object, count=len(rows))
            faces = faces.tolist()
    finally:
        if collect:
            gc.enable()
    return RawMesh(coords.reshape(-1, 3), faces, fmat, mats)


def _load_obj_lines(fn: str, lines: list[str]) -> RawMesh:
    """The OBJ reader, one line at a time (for what _load_obj_bulk leaves to it)."""
    verts, faces, fmat, mats = [], [], [], {}
    cur = "default"
    base = os.path.dirname(fn)
    for lineno, line in enumerate(lines, 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        key, args = parts[0], parts[1:]
        _check_line(fn, lineno, line.split("#", 1)[0], key, "OBJ")
        if key == "v":
            verts.append(_floats(args, fn, lineno))
        elif key == "f":
            idx = []
            for a in args:
                try:
                    k = int(a.split("/")[0])
                except ValueError:
                    raise SceneError(f"{fn}:{lineno}: bad face index {a!r}") from None
                k = k - 1 if k > 0 else len(verts) + k
                if not 0 <= k < len(verts):
                    raise SceneError(f"{fn}:{lineno}: face refers to vertex {a} that does not exist")
                idx.append(k)
            if len(idx) < 3:
                raise SceneError(f"{fn}:{lineno}: a face needs at least 3 vertices")
            faces.append(idx)
            fmat.append(cur)
        elif key == "usemtl":
            cur = " ".join(args) or "default"
        elif key == "mtllib":
            mfn = os.path.join(base, " ".join(args))
            if not os.path.exists(mfn):
                raise SceneError(f"{fn}:{lineno}: material library not found: {mfn}")
            mats.update(_load_mtl(mfn))
    return RawMesh(np.array(verts, float).reshape(-1, 3), faces, fmat, mats)


# ----------------------------------------------------------------------------- polygons

def _warn(msg: str) -> None:
    warnings.warn(msg, SceneWarning, stacklevel=3)


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


def polygons_from_raw(raw: RawMesh, fn: str, settings: Settings, merge: bool = True):
    """Validate faces and turn them into polygons: (verts (n,4,3), nverts (n,), face (n,), material names).

    Non-planar or non-convex quads become two triangles, n-gons a triangle fan; each with a warning
    (the first MAX_FACE_WARNINGS of a file, then one line for the rest). merge=False keeps
    triangle pairs that form parallelograms apart (view factors between the user's own facets).
    settings: the run's (its scene.* tolerances). Whole-array operations per face size
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
            _warn(f"{fn}: face {fi + 1} (material '{fm[fi]}') is a {what} quad; "
                  "split into two triangles")
        else:
            _warn(f"{fn}: face {fi + 1} has {sizes[fi]} vertices; triangulated as a fan")
    if len(said) > MAX_FACE_WARNINGS:
        _warn(f"{fn}: and {len(said) - MAX_FACE_WARNINGS} more faces split into triangles likewise "
              "(non-planar or non-convex quads, n-gons)")

    if nok < nf:
        fi = nok
        idx = raw.faces[fi]
        if e_index[fi]:
            wrong = [k for k in idx if not 0 <= k < nv]
            raise SceneError(f"{fn}: face {fi + 1} refers to vertex {wrong[0]}, which does not exist "
                             f"({nv} vertices)")
        if e_size[fi]:
            raise SceneError(f"{fn}: face {fi + 1} has {len(idx)} vertices; a face needs at least 3")
        p = V[flat[starts[fi]:starts[fi + 1]]]
        if e_finite[fi]:
            raise SceneError(f"{fn}: face {fi + 1} has a NaN or infinite vertex coordinate")
        raise SceneError(f"{fn}: face {fi + 1} has a vertex coordinate of {np.abs(p).max():.3g}: "
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
        raise SceneError(f"{fn}: face {face[bad[0]] + 1} (material '{out_m[bad[0]]}') has zero area"
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
