"""The only module that imports embreex: batched first-hit and occlusion-segment queries.

The accelerator is built once from the original elements (a quad is two triangles that map back
to it). Embree works in float32, so geometry is moved to a normalised frame (centred on the
bounding box, divided by its diagonal) and every ray offset is relative to the scene's size:
results do not change when the whole scene is scaled.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numba
import numpy as np

from radiosity.core.camera import hit_points, ray_directions32
from radiosity.core.geometry import element_triangles, on_hull_planes, polygon_properties
from radiosity.tracing.occluders import merged_faces

BATCH = 1 << 20  # rays per Embree call: bounds the temporary float32 buffers


def _embree():
    try:
        from embreex import mesh_construction, rtcore_scene
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("the 'embreex' package is required for ray casting: pip install embreex") from e
    return rtcore_scene, mesh_construction


#: The ray offset where a caller gives none: radiosity.yaml's rays.epsilon as shipped (a test
#: keeps the two equal; why 1e-6 is said there). rays.epsilon is the user's name for it; in code
#: it is `ray_offset`, and epsilon is the links' refinement threshold (hierarchy.epsilon).
DEFAULT_RAY_OFFSET = 1e-6


class RayCaster:
    """Embree scene of a set of polygons (verts (n, 4, 3), nverts (n,)), queried in world units."""

    def __init__(self, verts: np.ndarray, nverts: np.ndarray, ray_offset: float | None = None):
        """ray_offset: in the normalised frame, resolved by the caller (the stage masters pass
        the rays.epsilon setting); None takes DEFAULT_RAY_OFFSET."""
        rtcore_scene, mesh_construction = _embree()
        tris, self.owner = element_triangles(np.asarray(verts, float), np.asarray(nverts))
        lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
        self.origin = 0.5 * (lo + hi)
        self.scale = float(np.linalg.norm(hi - lo)) or 1.0
        self.ray_offset = float(DEFAULT_RAY_OFFSET if ray_offset is None else ray_offset)
        self._local = threading.local()
        self.normal = polygon_properties(np.asarray(verts, float), np.asarray(nverts))[1]
        self._scene = rtcore_scene.EmbreeScene()
        self._mesh = mesh_construction.TriangleMesh(
            self._scene, ((tris - self.origin) / self.scale).astype(np.float32))
        self._verts, self._nverts = verts, nverts
        self._inner = None  # (scene or None, owner): segment queries' occluders, built on use
        self._inner_mesh = None  # keeps the second scene's triangles alive
        self._keep = None  # the elements of the segment queries' occluders (_inner_scene)
        self._boxes = None  # occluder_boxes, built on use
        self._inner_lock = threading.Lock()

    def _inner_scene(self):
        """The Embree scene of the elements that can block a segment between two points on
        elements: all but those in a supporting plane of the scene's convex hull (a room's
        walls, floor and ceiling: core.geometry.on_hull_planes), each flat face of many
        elements as one polygon (occluders.merged_faces); with the group of each triangle and
        of each element (None: the elements themselves); (None, None, None) when no element is
        left (nothing can block). Built once, on the first query."""
        if self._inner is not None:  # the hot path: every segment query asks
            return self._inner
        with self._inner_lock:
            if self._inner is None:
                verts = np.asarray(self._verts, float)
                nverts = np.asarray(self._nverts)
                keep = np.nonzero(~on_hull_planes(verts, nverts, self.normal))[0]
                self._keep = keep
                if not len(keep):
                    self._inner = (None, None, None)
                elif len(keep) > INNER_SHARE * len(verts):  # a terrain: not worth a second BVH
                    self._inner = (self._scene, self.owner, None)
                else:
                    rtcore_scene, mesh_construction = _embree()
                    area = polygon_properties(verts[keep], nverts[keep])[0]
                    tris, owner, group = merged_faces(verts[keep], nverts[keep],
                                                      self.normal[keep], area, self.scale)
                    scene = rtcore_scene.EmbreeScene()
                    self._inner_mesh = mesh_construction.TriangleMesh(
                        scene, ((tris - self.origin) / self.scale).astype(np.float32))
                    group_of = np.arange(len(verts), dtype=np.int64)
                    group_of[keep] = keep[group]
                    self._inner = (scene, keep[owner], group_of)
            return self._inner

    def occluder_boxes(self):
        """(lo, hi) (b, 3) world boxes that hold every element a segment between two points on
        elements can meet (_inner_scene's), the occluders cut into OCCLUDER_BOXES groups at
        the median of their centres along the widest axis, each padded by 1e-6 of the scene's
        diagonal (Embree's float32 rounding is below 1e-7 of it). A segment between two boxes
        whose bounding box some axis separates from every one of them meets nothing
        (shafts.clear_of).
        Empty where nothing can block; None where the occluders are the whole scene (a
        terrain: no box can prove a segment clear)."""
        if self._boxes is None:
            scene, _, _ = self._inner_scene()
            keep = self._keep
            if scene is None:
                boxes = (np.zeros((0, 3)), np.zeros((0, 3)))
            elif scene is self._scene:
                boxes = None
            else:
                verts = np.asarray(self._verts, float)[keep]
                tri = np.asarray(self._nverts)[keep] == 3  # their fourth slot: the third vertex
                verts = np.where(tri[:, None, None], verts[:, [0, 1, 2, 2]], verts)
                groups = [np.arange(len(keep))]
                center = verts.mean(axis=1)
                while len(groups) < OCCLUDER_BOXES and max(len(g) for g in groups) > 1:
                    g = groups.pop(int(np.argmax([len(g) for g in groups])))
                    c = center[g]
                    o = np.argsort(c[:, int(np.argmax(c.max(0) - c.min(0)))], kind="stable")
                    groups += [g[o[:len(g) // 2]], g[o[len(g) // 2:]]]
                pad = 1e-6 * self.scale
                boxes = (np.array([verts[g].reshape(-1, 3).min(0) - pad for g in groups]),
                         np.array([verts[g].reshape(-1, 3).max(0) + pad for g in groups]))
            self._boxes = (boxes,)
        return self._boxes[0]

    def _to_frame(self, p: np.ndarray) -> np.ndarray:
        return (p - self.origin) * (1.0 / self.scale)

    def first_hit(self, origins: np.ndarray, directions: np.ndarray, distances: bool = False,
                  unit: bool = False):
        """Nearest element hit by each ray.

        origins : (n, 3) or (3,) float64; directions : (n, 3), unit vectors if `unit` (then a
        float32 array is passed to Embree as is)
        Returns elem (n,) int32 (-1 for a miss) and, if `distances`, t (n,) float64: the world
        distance along the unit direction (inf for a miss).
        """
        n = len(directions)
        elem = np.full(n, -1, np.int32)
        t = np.full(n, np.inf) if distances else None
        for s in range(0, n, BATCH):
            sl = slice(s, min(n, s + BATCH))
            o = self._to_frame(origins[sl] if origins.ndim == 2 else origins[None, :])
            d = directions[sl]
            if not unit:
                d = d / np.linalg.norm(d, axis=1, keepdims=True)
            o = np.ascontiguousarray(np.broadcast_to(o.astype(np.float32), d.shape))
            d = np.ascontiguousarray(d, np.float32)
            if distances:
                res = self._scene.run(o, d, output=1)
                prim, tfar = res["primID"], res["tfar"]
                t[sl] = np.where(prim >= 0, tfar.astype(np.float64) * self.scale, np.inf)
            else:
                prim = np.asarray(self._scene.run(o, d))
            elem[sl] = np.where(prim >= 0, self.owner[np.maximum(prim, 0)], -1)
        return (elem, t) if distances else elem

    def occluded(self, p: np.ndarray, q: np.ndarray, ep: np.ndarray | None = None,
                 eq: np.ndarray | None = None) -> np.ndarray:
        """Whether the open segment between p[k] and q[k] hits an element, (n,) bool.

        See `occluded_pairs`; ep, eq (n,) are the elements the endpoints lie on, if known.
        """
        n = len(p)
        pts = np.concatenate([np.asarray(p, np.float64), np.asarray(q, np.float64)])
        idx = np.arange(n)
        e = None if ep is None else np.concatenate([ep, eq])
        return self.occluded_pairs(pts, idx, idx + n, e)

    def occluded_pairs(self, points: np.ndarray, ia: np.ndarray, ib: np.ndarray,
                       elem: np.ndarray | None = None) -> np.ndarray:
        """Whether the open segment points[ia[k]] - points[ib[k]] hits an element, (n,) bool.

        points (m, 3) float64 world coordinates; ia, ib (n,) int indices; elem (m,) int, the
        element each point lies on (optional). A segment cannot cross the planar element it
        starts or ends on, so when it leaves one at a grazing angle (where float32 rounding can
        report such a hit) a reported occlusion is re-checked and hits on those two elements are
        stepped over. The query is symmetric (it always runs from the lexicographically smaller
        endpoint); the segment is shortened by the ray offset at both ends, and segments shorter than
        twice it are never occluded. With `elem` (every end on an element, so inside the
        scene's convex hull) the elements in the hull's supporting planes are left out: they
        cannot block such a segment (_inner_scene).
        """
        n = len(ia)
        out = np.zeros(n, bool)
        points = np.ascontiguousarray(points, np.float64)
        ia = np.ascontiguousarray(ia, np.int64)
        ib = np.ascontiguousarray(ib, np.int64)
        has_e = elem is not None
        elem = np.ascontiguousarray(elem, np.int64) if has_e else np.zeros(1, np.int64)
        # both ends on elements: the elements in the hull's planes cannot block (_inner_scene)
        scene, owner, group_of = self._inner_scene() if has_e and n and elem.min() >= 0 else \
            (self._scene, self.owner, None)
        if scene is None:
            return out
        buf = self._buffers()
        for s in range(0, n, BATCH):
            sl = slice(s, min(n, s + BATCH))
            k = sl.stop - sl.start
            o32, d32, far, graze = (b[:k] for b in buf)
            _segments(points, ia[sl], ib[sl], self.origin, self.scale, self.ray_offset, self.normal,
                      elem, has_e, GRAZING, o32, d32, far, graze)
            occ = np.asarray(scene.run(o32, d32, dists=far, query="OCCLUDED")) != -1
            occ &= far > 0
            g = np.nonzero(occ & graze)[0]
            if len(g):
                x = self._to_frame(points[ia[sl][g]])
                y = self._to_frame(points[ib[sl][g]])
                swap = _lex_less(y, x)
                x, y = np.where(swap[:, None], y, x), np.where(swap[:, None], x, y)
                d = y - x
                length = np.linalg.norm(d, axis=1)
                ea, eb = elem[ia[sl][g]], elem[ib[sl][g]]
                if group_of is not None:
                    ea, eb = group_of[ea], group_of[eb]
                occ[g] = self._beyond_own(x, d / length[:, None], length, ea, eb, scene, owner)
            out[sl] = occ
        return out

    def _buffers(self):
        """Per-thread segment buffers of BATCH rays, allocated once."""
        b = getattr(self._local, "buf", None)
        if b is None:
            b = (np.empty((BATCH, 3), np.float32), np.empty((BATCH, 3), np.float32),
                 np.empty(BATCH, np.float32), np.empty(BATCH, np.bool_))
            self._local.buf = b
        return b

    def _beyond_own(self, a, d, length, ea, eb, scene, owner, rounds: int = 8) -> np.ndarray:
        """For segments reported occluded in `scene` (owner: its triangles' elements, or their
        groups: merged faces): is the first hit on another element (group) than ea, eb?"""
        eps = self.ray_offset
        t0 = np.full(len(a), eps)
        result = np.zeros(len(a), bool)
        live = np.arange(len(a))
        for _ in range(rounds):
            if not len(live):
                break
            o = (a[live] + t0[live, None] * d[live]).astype(np.float32)
            far = (length[live] - eps - t0[live]).astype(np.float32)
            res = scene.run(o, d[live].astype(np.float32), dists=np.maximum(far, 0), output=1)
            prim = res["primID"]
            hit = (prim >= 0) & (far > 0)
            own = np.where(hit, owner[np.maximum(prim, 0)], -1)
            other = hit & (own != ea[live]) & (own != eb[live])
            result[live[other]] = True
            again = hit & ~other
            t0[live[again]] += res["tfar"][again].astype(np.float64) + eps
            live = live[again]
        result[live] = True  # still hitting its own elements after many steps: say occluded
        return result


#: Boxes over the segment queries' occluders (RayCaster.occluder_boxes); more prove few more
#: links clear and cost more a link (docs/src/design/methods-hierarchical-clusters.md).
OCCLUDER_BOXES = 8
#: A second scene for segment queries only where it leaves out more than this share of the
#: elements (RayCaster._inner_scene): it costs a second BVH's memory.
INNER_SHARE = 0.9
GRAZING = 0.1  # |cos| below which a segment leaving its element may self-hit in float32


def _lex_less(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Row-wise lexicographic x < y, (n,) bool (the same order as _segments)."""
    lt = x < y
    eq = x == y
    return lt[:, 0] | (eq[:, 0] & (lt[:, 1] | (eq[:, 1] & lt[:, 2])))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _segments(pts, ia, ib, origin, scale, eps, normal, elem, has_e, grazing, o32, d32, far, graze):
    """Embree's float32 origins, unit directions and lengths of the normalised segments
    pts[ia] - pts[ib], run from the lexicographically smaller end and shortened by eps at both
    ends (length 0 when shorter than 2 eps), and whether a segment leaves the element of either
    end at a grazing angle. Writes into the given buffers (reused: fresh pages cost more than
    the arithmetic)."""
    n = ia.shape[0]
    inv_s = 1.0 / scale
    for k in range(n):
        u, v = ia[k], ib[k]
        px, py, pz = pts[u, 0], pts[u, 1], pts[u, 2]
        qx, qy, qz = pts[v, 0], pts[v, 1], pts[v, 2]
        if qx < px or (qx == px and (qy < py or (qy == py and qz < pz))):
            px, py, pz, qx, qy, qz = qx, qy, qz, px, py, pz
        ax = (px - origin[0]) * inv_s
        ay = (py - origin[1]) * inv_s
        az = (pz - origin[2]) * inv_s
        dx = (qx - origin[0]) * inv_s - ax
        dy = (qy - origin[1]) * inv_s - ay
        dz = (qz - origin[2]) * inv_s - az
        L = np.sqrt(dx * dx + dy * dy + dz * dz)
        inv = 1.0 / L if L > 0 else 0.0
        dx *= inv
        dy *= inv
        dz *= inv
        o32[k, 0] = ax + eps * dx
        o32[k, 1] = ay + eps * dy
        o32[k, 2] = az + eps * dz
        d32[k, 0] = dx
        d32[k, 1] = dy
        d32[k, 2] = dz
        far[k] = L - 2 * eps if L > 2 * eps else 0.0
        if has_e:
            i, j = elem[u], elem[v]
            c1 = abs(normal[i, 0] * dx + normal[i, 1] * dy + normal[i, 2] * dz)
            c2 = abs(normal[j, 0] * dx + normal[j, 1] * dy + normal[j, 2] * dz)
            graze[k] = min(c1, c2) < grazing
        else:
            graze[k] = False


_CACHE: "OrderedDict[tuple, RayCaster]" = OrderedDict()


_CACHE_LOCK = threading.Lock()


def caster_of(verts: np.ndarray, nverts: np.ndarray, ray_offset: float) -> RayCaster:
    """caster_for keyed by the polygons themselves (dask's tokenize of verts, nverts): the
    driver's checks, closure test, preprocess, solve and image share one Embree scene instead
    of building one each (docs/src/measurements/choices.md)."""
    from dask.base import tokenize

    return caster_for(tokenize(verts, nverts), verts, nverts, ray_offset)


def caster_for(key: str, verts: np.ndarray, nverts: np.ndarray, ray_offset: float) -> RayCaster:
    """A RayCaster memoised per process by (key, ray_offset) (built once per worker, then reused;
    safe when a worker runs several tasks in threads)."""
    k = (key, float(ray_offset))
    with _CACHE_LOCK:
        rc = _CACHE.get(k)
        if rc is not None:
            _CACHE.move_to_end(k)
            return rc
    rc = RayCaster(verts, nverts, ray_offset)
    with _CACHE_LOCK:
        _CACHE[k] = rc
        while len(_CACHE) > 4:
            _CACHE.popitem(last=False)
    return rc


# ----------------------------------------------------------------------------- the camera raster

def raster_band(caster, normal, center, camera, subpixel: int, rows: slice):
    """First hits of the camera rays through the fine-raster rows `rows`, against the elements
    the caster was built from (normal, center (n, 3): their planes, for the exact hit points).

    Returns orig (p,) int32 (-1 where nothing is hit) and points (p, 3) float64.
    """
    dirs = ray_directions32(camera, subpixel, rows.start, rows.stop)
    elem = caster.first_hit(camera.center, dirs, unit=True)
    return elem, hit_points(camera, subpixel, rows.start, elem, normal, center)

