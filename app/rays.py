"""The only module that imports embreex: batched first-hit and occlusion-segment queries.

The accelerator is built once from the original elements (a quad is two triangles that map back
to it). Embree works in float32, so geometry is moved to a normalised frame (centred on the
bounding box, divided by its diagonal) and every epsilon is relative to the scene's size:
results do not change when the whole scene is scaled.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from . import config

BATCH = 1 << 20  # rays per Embree call: bounds the temporary float32 buffers


def _embree():
    try:
        from embreex import mesh_construction, rtcore_scene
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("the 'embreex' package is required for ray casting: pip install embreex") from e
    return rtcore_scene, mesh_construction


def element_triangles(verts: np.ndarray, nverts: np.ndarray):
    """Triangles (t, 3, 3) of the elements and the element of each triangle (t,) int32."""
    quad = np.nonzero(nverts == 4)[0]
    tris = np.concatenate([verts[:, [0, 1, 2]], verts[quad][:, [0, 2, 3]]])
    owner = np.concatenate([np.arange(len(verts)), quad]).astype(np.int32)
    return tris, owner


class RayCaster:
    """Embree scene of a set of polygons (verts (n, 4, 3), nverts (n,)), queried in world units."""

    def __init__(self, verts: np.ndarray, nverts: np.ndarray, epsilon: float | None = None):
        rtcore_scene, mesh_construction = _embree()
        tris, self.owner = element_triangles(np.asarray(verts, float), np.asarray(nverts))
        lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
        self.origin = 0.5 * (lo + hi)
        self.scale = float(np.linalg.norm(hi - lo)) or 1.0
        self.epsilon = float(config.get("rays.epsilon", epsilon))  # in the normalised frame
        self._scene = rtcore_scene.EmbreeScene()
        self._mesh = mesh_construction.TriangleMesh(
            self._scene, ((tris - self.origin) / self.scale).astype(np.float32))

    def _to_frame(self, p: np.ndarray) -> np.ndarray:
        return (p - self.origin) / self.scale

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

        ep, eq (n,) int: the elements the endpoints lie on. The segment cannot cross the planar
        element it starts or ends on, so a hit on those is float32 rounding at a grazing angle:
        it is stepped over and the search goes on. The query is symmetric (it always runs from
        the lexicographically smaller endpoint), and the segment is shortened by epsilon at both
        ends; segments shorter than 2 epsilon are never occluded.
        """
        n = len(p)
        out = np.zeros(n, bool)
        swap = _lex_less(q, p)
        p, q = np.where(swap[:, None], q, p), np.where(swap[:, None], p, q)
        if ep is not None:
            ep, eq = np.where(swap, eq, ep), np.where(swap, ep, eq)
        eps = self.epsilon
        for s in range(0, n, BATCH):
            sl = slice(s, min(n, s + BATCH))
            a = self._to_frame(p[sl])
            d = self._to_frame(q[sl]) - a
            length = np.linalg.norm(d, axis=1)
            ok = length > 2 * eps
            d = d / np.where(ok, length, 1.0)[:, None]
            o = (a + eps * d).astype(np.float32)
            d32 = d.astype(np.float32)
            far = np.where(ok, length - 2 * eps, 0.0).astype(np.float32)
            occ = (np.asarray(self._scene.run(o, d32, dists=far, query="OCCLUDED")) != -1) & ok
            if ep is not None and occ.any():
                occ[occ] = self._beyond_own(a[occ], d[occ], length[occ], ep[sl][occ], eq[sl][occ])
            out[sl] = occ
        return out

    def _beyond_own(self, a, d, length, ea, eb, rounds: int = 8) -> np.ndarray:
        """For segments reported occluded: is the first hit on another element than ea, eb?"""
        eps = self.epsilon
        t0 = np.full(len(a), eps)
        result = np.zeros(len(a), bool)
        live = np.arange(len(a))
        for _ in range(rounds):
            if not len(live):
                break
            o = (a[live] + t0[live, None] * d[live]).astype(np.float32)
            far = (length[live] - eps - t0[live]).astype(np.float32)
            res = self._scene.run(o, d[live].astype(np.float32), dists=np.maximum(far, 0), output=1)
            prim = res["primID"]
            hit = (prim >= 0) & (far > 0)
            own = np.where(hit, self.owner[np.maximum(prim, 0)], -1)
            other = hit & (own != ea[live]) & (own != eb[live])
            result[live[other]] = True
            again = hit & ~other
            t0[live[again]] += res["tfar"][again].astype(np.float64) + eps
            live = live[again]
        result[live] = True  # still hitting its own elements after many steps: say occluded
        return result


def _lex_less(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Row-wise lexicographic x < y, (n,) bool."""
    lt = x < y
    eq = x == y
    return lt[:, 0] | (eq[:, 0] & (lt[:, 1] | (eq[:, 1] & lt[:, 2])))


_CACHE: "OrderedDict[str, RayCaster]" = OrderedDict()


def caster_for(key: str, verts: np.ndarray, nverts: np.ndarray) -> RayCaster:
    """A RayCaster memoised per process by `key` (build once per worker, then reuse)."""
    rc = _CACHE.get(key)
    if rc is None:
        rc = RayCaster(verts, nverts)
        _CACHE[key] = rc
        while len(_CACHE) > 4:
            _CACHE.popitem(last=False)
    return rc
