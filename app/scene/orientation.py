"""Which way the faces point: the fix (`orient` in a [[mesh]] entry, per connected part: a
room's shell in, its furniture out) and the facts the checks before any heavy work need
(runtime/checks.py): what the camera sees of the one-sided elements, whether each emitter's
light reaches any element, and which meshes enclose the camera with their normals pointing out.

A one-sided element is black from behind, so a room modelled with its normals out, a camera
inside a wall or a lamp outside the room renders an all-black image with no error otherwise
(issue 26). Everything here is cheap: a few thousand Embree rays and one pass over the faces.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radiosity.core.bundles import Elements
from radiosity.core.geometry import element_triangles
from radiosity.errors import SceneError

#: Values of a [[mesh]] entry's `orient` key. as-is: the file's winding (counter-clockwise seen
#: from the front); flip: every face reversed; inward / outward / auto: each connected part of
#: the mesh turned by what it is (`part_kinds`, `orient_mesh`): inward for a room and its
#: furniture, outward for solid objects, auto (a bare mesh file's default) for a mesh whose
#: kind is unknown: only what is certainly inside out is turned.
ORIENTS = ("as-is", "flip", "inward", "outward", "auto")
#: Sample rays per emitter (one material of one mesh): enough that a lamp whose light reaches
#: only a small part of its hemisphere is still seen to reach something (a miss of all 256
#: rays means under about 1 % of its light reaches any element), few enough to be free.
EMITTER_RAYS = 256
#: At most this many emitter rays in all (scenes with very many emitting materials).
MAX_EMITTER_RAYS = 1 << 16
#: A mesh whose one-sided faces wind this much or more around the camera encloses it with its
#: normals pointing out (a closed mesh gives exactly 1, an open one less; 0: the camera is
#: outside, -1: inside and pointing in).
ENCLOSING = 0.5
#: A part that is not closed still holds a volume (a box without its bottom) when its faces'
#: |facing_volume| is at least this share of its bounding box's volume (a flat or bent sheet
#: gives 0 to about 0.2; a box without one face 0.83, a sphere 0.52).
SOLID = 0.4
#: At most this many other parts are tested for lying inside the room (the largest by area).
ROOM_PROBES = 64


class OrientationError(SceneError):
    """A scene whose faces point the wrong way for its camera or its lights: the image would be
    black or wrong. One line naming the mesh and the fix."""


# ----------------------------------------------------------------------------- the fix

def flip_polygons(verts: np.ndarray, nverts: np.ndarray) -> np.ndarray:
    """The same polygons wound the other way (their normals reversed): (n, 4, 3) float64.

    verts (n, 4, 3), nverts (n,) in {3, 4} as in Elements; the first vertex stays first, a
    triangle's slot 3 keeps repeating its last vertex."""
    verts = np.asarray(verts, np.float64)
    tri = np.asarray(nverts) == 3
    out = verts[:, [0, 3, 2, 1]]
    out[tri] = verts[tri][:, [0, 2, 1, 1]]
    return out


def facing_volume(verts: np.ndarray, nverts: np.ndarray, origin=None) -> float:
    """sum over faces of A n . (c - o) / 3 with o the mean vertex (or `origin`): the enclosed
    volume for a closed mesh (positive when the normals point out of it, negative when in), and
    for an open one (a room without a wall) still positive when the faces point away from its
    middle."""
    from radiosity.core.geometry import polygon_properties

    verts = np.asarray(verts, np.float64)
    area, normal, center = polygon_properties(verts, np.asarray(nverts))
    o = verts.reshape(-1, 3).mean(axis=0) if origin is None else np.asarray(origin, np.float64)
    return float(np.sum(area * np.einsum("ij,ij->i", normal, center - o)) / 3.0)


def orient_polygons(verts: np.ndarray, nverts: np.ndarray, orient: str, where: str) -> np.ndarray:
    """A mesh's polygons (n, 4, 3) wound as its `orient` key says (ORIENTS); `where` names the
    [[mesh]] entry in the error for an unknown value. orient_mesh without its account."""
    return orient_mesh(verts, nverts, orient, where)[0]


@dataclass(frozen=True)
class Turned:
    """What orient_mesh did to one mesh: its connected parts by kind and which were turned."""

    kinds: tuple         # per part: "room", "solid" or "sheet" (part_kinds)
    turned: tuple        # per part: its faces were reversed

    def describe(self, name: str) -> str:
        """One line for the user, e.g. "office.glb: turned 6 of its 7 connected parts that were
        wound inside out (the room's shell, 5 closed solids)"; "" when nothing was turned."""
        n = sum(self.turned)
        if not n:
            return ""
        what = {k: sum(1 for kk, t in zip(self.kinds, self.turned) if t and kk == k)
                for k in ("room", "solid", "sheet")}
        words = [w for w in (what["room"] and "the room's shell (its normals pointed out)",
                             what["solid"] and f"{what['solid']} closed solid"
                             f"{'s' * (what['solid'] > 1)} (normals in)",
                             what["sheet"] and f"{what['sheet']} open part"
                             f"{'s' * (what['sheet'] > 1)} (with the rest)") if w]
        return (f"{name}: turned {n} of its {len(self.kinds)} connected parts that were wound "
                f"inside out: {', '.join(words)} (orient = \"auto\"; a scene file's [[mesh]] "
                f"entry with orient = \"as-is\" keeps the file's winding)")


def orient_mesh(verts: np.ndarray, nverts: np.ndarray, orient: str, where: str):
    """A mesh's polygons (n, 4, 3) wound as `orient` says, and a Turned account.

    Per connected part (`connected_parts`) and its kind (`part_kinds`): the room's shell faces
    into its volume and every solid out of its own. inward: the room is the largest part that
    holds a volume; outward: there is none; auto (a bare mesh file): only a room with things
    inside it, and nothing is turned in any other mesh (a room or a solid alone, objects side by
    side: nothing tells which way is meant). Sheets (open parts that hold no volume) have no
    inside of their own: for inward / outward they are turned together so that on the whole
    they face toward / away from the mesh's middle (the old rule for a whole mesh, right for a
    ceiling panel or walls modelled apart); for auto they follow the parts that have an inside
    (turned when most of those parts' area was turned).
    """
    if orient not in ORIENTS:
        raise SceneError(f"{where}: orient = {orient!r} is not one of {', '.join(ORIENTS)}")
    verts = np.asarray(verts, np.float64)
    nverts = np.asarray(nverts)
    if orient == "as-is" or not len(verts):
        return verts, Turned((), ())
    if orient == "flip":
        return flip_polygons(verts, nverts), Turned((), ())
    ids = _vertex_ids(verts, nverts)
    label, count = connected_parts(verts, nverts, ids)
    kinds = part_kinds(verts, nverts, label, count,
                       room={"inward": "largest", "outward": "none", "auto": "holds"}[orient],
                       ids=ids)
    if orient == "auto" and "room" not in kinds:  # not a room with things in it: nothing is sure
        return verts, Turned(tuple(kinds), (False,) * count)
    volume, area, _ = _part_sums(verts, nverts, label, count, ids)
    kind = np.array(kinds)
    turn = np.where(kind == "room", volume > 0.0, volume < 0.0) & (kind != "sheet")
    area = np.where(kind == "sheet", 0.0, area)
    sheets = np.array([k == "sheet" for k in kinds])
    if sheets.any():
        sel = sheets[label]
        if orient == "auto":
            flip_sheets = area.sum() > 0 and area[turn].sum() > 0.5 * area.sum()
        else:
            middle = verts.reshape(-1, 3).mean(axis=0)
            v = facing_volume(verts[sel], nverts[sel], middle)
            flip_sheets = (v > 0.0) if orient == "inward" else (v < 0.0)
        turn[sheets] = flip_sheets
    out = verts
    if turn.any():
        out = verts.copy()
        sel = turn[label]
        out[sel] = flip_polygons(verts[sel], nverts[sel])
    return out, Turned(tuple(kinds), tuple(bool(t) for t in turn))


def _vertex_ids(verts: np.ndarray, nverts: np.ndarray) -> np.ndarray:
    """Each polygon's corners as ids of distinct positions (n, 4) int64, positions equal to
    1e-9 of the mesh's size counting as one (separately exported walls meet at their corners); a
    triangle's slot 3 repeats slot 2."""
    pts = verts.reshape(-1, 3)
    scale = float(np.abs(pts).max()) or 1.0
    key = np.round(pts / (1e-9 * scale)).astype(np.int64)
    return _row_ids(key).reshape(len(verts), 4)


def _row_ids(rows: np.ndarray) -> np.ndarray:
    """An id per row of `rows` (k, d) int, equal rows the same id (np.unique(axis=0)'s inverse,
    without its slow structured sort)."""
    if not len(rows):
        return np.zeros(0, np.int64)
    order = np.lexsort(rows.T[::-1])
    r = rows[order]
    new = np.ones(len(r), bool)
    new[1:] = (r[1:] != r[:-1]).any(axis=1)
    ids = np.empty(len(r), np.int64)
    ids[order] = np.cumsum(new) - 1
    return ids


def connected_parts(verts: np.ndarray, nverts: np.ndarray, ids=None):
    """The mesh's connected parts: polygons that share a corner position belong together
    (ids: their _vertex_ids, when known). Returns (label (n,) int, count), labels 0.. in order
    of first appearance."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n = len(verts)
    ids = _vertex_ids(verts, nverts) if ids is None else ids
    m = int(ids.max()) + 1 if n else 0
    rows = np.repeat(np.arange(n), 4)
    g = coo_matrix((np.ones(4 * n, np.int8), (rows, n + ids.ravel())), shape=(n + m, n + m))
    count, lab = connected_components(g, directed=False)
    lab = lab[:n]
    _, first, label = np.unique(lab, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))  # renumber by first polygon
    return order[label].astype(np.int64), len(first)


def _part_sums(verts: np.ndarray, nverts: np.ndarray, label: np.ndarray, count: int, ids=None):
    """Per part (count,): facing_volume about its own mean vertex, its area, and whether it is
    closed (every edge shared by exactly two of its polygons), in a few passes over all the
    polygons (a triangle soup may have as many parts as faces)."""
    from radiosity.core.geometry import polygon_properties

    area, normal, center = polygon_properties(verts, nverts)
    an = area[:, None] * normal
    s1 = np.bincount(label, np.einsum("ij,ij->i", an, center), count)
    s2 = np.stack([np.bincount(label, an[:, k], count) for k in range(3)], axis=1)
    k = np.bincount(label, minlength=count) * 4.0
    o = np.stack([np.bincount(label, verts[:, :, j].sum(axis=1), count) for j in range(3)],
                 axis=1) / k[:, None]
    volume = (s1 - np.einsum("ij,ij->i", s2, o)) / 3.0
    # edges: corner ids (and the next corner), a triangle's slot 3 left out
    ids = _vertex_ids(verts, nverts) if ids is None else ids
    tri = np.asarray(nverts) == 3
    nxt = np.where(tri[:, None], ids[:, [1, 2, 0, 0]], ids[:, [1, 2, 3, 0]])
    keep = np.ones(ids.shape, bool)
    keep[tri, 3] = False
    e = np.sort(np.stack([ids[keep], nxt[keep]], axis=1), axis=1)
    owner = np.broadcast_to(label[:, None], ids.shape)[keep]
    real = e[:, 0] != e[:, 1]
    inv = _row_ids(e[real])
    counts = np.bincount(inv)
    bad = np.bincount(owner[real], counts[inv] != 2, count)
    edges = np.bincount(owner[real], minlength=count)
    return volume, np.bincount(label, area, count), (bad == 0) & (edges > 0)


def part_kinds(verts: np.ndarray, nverts: np.ndarray, label: np.ndarray, count: int,
               room: str = "largest", ids=None) -> list:
    """What each connected part is: "room", "solid" or "sheet".

    solid: a part that holds a volume: closed (every edge shared by two of its faces) or nearly
    (|facing_volume| at least SOLID of its bounding box's); a room may have openings. sheet: the
    rest (a panel, a bent sheet, a wall on its own). room, by `room`: "largest": the part of
    the largest bounding box, when it holds a volume (a mesh of one part: that part, whatever
    it holds); "holds": that part only when the middles of the others (their bounding boxes'
    centres; the ROOM_PROBES largest by area) lie inside it (its winding number there ENCLOSING
    or more in size): a room with its furniture, not a solid beside other things; "none": no
    room. ids: the polygons' _vertex_ids, when known."""
    lo = np.full((count, 3), np.inf)
    hi = np.full((count, 3), -np.inf)
    pts = verts.reshape(-1, 4, 3)
    np.minimum.at(lo, label, pts.min(axis=1))
    np.maximum.at(hi, label, pts.max(axis=1))
    volume, areas, closed = _part_sums(verts, nverts, label, count, ids)
    box = np.prod(hi - lo, axis=1)
    solid = closed | ((box > 0) & (np.abs(volume) >= SOLID * box))
    kinds = ["solid" if x else "sheet" for x in solid]
    if room == "none" or not count:
        return kinds
    if count == 1:
        return ["room"] if room == "largest" else kinds
    big = int(np.argmax(np.linalg.norm(hi - lo, axis=1)))
    if kinds[big] != "solid":
        return kinds
    if room == "holds":
        others = np.array([p for p in range(count) if p != big])
        others = others[np.argsort(-areas[others], kind="stable")][:ROOM_PROBES]
        sel = label == big
        mids = (lo[others] + hi[others]) / 2
        if not all(abs(winding_number(verts[sel], nverts[sel], m)) >= ENCLOSING for m in mids):
            return kinds
    kinds[big] = "room"
    return kinds


# ----------------------------------------------------------------------------- the camera

def winding_number(verts: np.ndarray, nverts: np.ndarray, point: np.ndarray) -> float:
    """How many times the polygons wind around `point` (the generalised winding number,
    Jacobson et al. 2013): the sum of their signed solid angles seen from it over 4 pi (Van
    Oosterom & Strackee's formula per triangle). 1 inside a closed mesh whose normals point
    out, -1 inside one whose normals point in, 0 outside; an open mesh gives the fraction of
    the sphere of directions it covers."""
    if not len(verts):
        return 0.0
    tris, _ = element_triangles(np.asarray(verts, np.float64), np.asarray(nverts))
    r = tris - np.asarray(point, np.float64)[None, None, :]
    a, b, c = r[:, 0], r[:, 1], r[:, 2]
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    num = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", a, c) * lb
           + np.einsum("ij,ij->i", b, c) * la)
    # solid angle of each triangle, positive when its front faces away from the point
    return float(np.sum(2.0 * np.arctan2(num, den)) / (4.0 * np.pi))


@dataclass(frozen=True)
class Enclosure:
    """A [[mesh]] entry that winds around the camera with its normals pointing out."""

    source: int          # index into Elements.sources (one per [[mesh]] entry)
    winding: float       # the one-sided faces' winding number at the camera (about 1)
    watertight: bool     # trimesh finds the mesh closed (every edge shared by two faces)
    faces: int           # its one-sided elements


def outward_enclosures(elements: Elements, point: np.ndarray) -> list:
    """The [[mesh]] entries whose one-sided faces wind ENCLOSING or more around `point` (the
    camera centre): their normals point out of a volume that holds the camera, so it sees their
    backs (black). Returns [Enclosure], in the entries' order."""
    out = []
    two = np.asarray(elements.two_sided, bool)
    for s in np.unique(elements.source):
        sel = (elements.source == s) & ~two
        if not sel.any():
            continue
        w = winding_number(elements.verts[sel], elements.nverts[sel], point)
        if w >= ENCLOSING:
            out.append(Enclosure(int(s), w, _watertight(elements.verts[sel], elements.nverts[sel]),
                                 int(sel.sum())))
    return out


def _watertight(verts: np.ndarray, nverts: np.ndarray) -> bool:
    """trimesh's answer: every edge of the (vertex-merged) triangles shared by exactly two."""
    import trimesh

    tris, _ = element_triangles(np.asarray(verts, np.float64), np.asarray(nverts))
    m = trimesh.Trimesh(vertices=tris.reshape(-1, 3), faces=np.arange(3 * len(tris)).reshape(-1, 3),
                        process=True)
    return bool(m.is_watertight)


def facing(elements: Elements, elem: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Whether each hit element `elem` (k,) int (-1: none) shows a lit side to `origin` ((3,),
    or (k, 3) one per hit): its front, or either side of a two-sided element. (k,) bool, False
    for -1."""
    elem = np.asarray(elem)
    out = np.zeros(len(elem), bool)
    h = elem >= 0
    e = elem[h]
    o = np.asarray(origin, np.float64)
    o = o[h] if o.ndim == 2 else o[None, :]
    front = np.einsum("ij,ij->i", elements.normal[e], o - elements.center[e]) > 0
    out[h] = front | np.asarray(elements.two_sided, bool)[e]
    return out


# ----------------------------------------------------------------------------- the emitters

@dataclass(frozen=True)
class EmitterReach:
    """The emitting elements of one material in one [[mesh]] entry and where their rays went."""

    source: int          # index into Elements.sources
    material: int        # index into Elements.material_names
    elements: int        # emitting elements of the group
    example: int         # one of them (the largest), for the message
    rays: int            # rays cast from their emitting sides
    reached: int         # rays that met the lit side of an element of another group
    backs: int           # rays that met the back of a one-sided element
    escaped: int         # rays that met nothing


def emitter_reach(elements: Elements, caster, rays: int = EMITTER_RAYS,
                  max_rays: int = MAX_EMITTER_RAYS, seed: int = 0) -> list:
    """Where the light of each emitter goes: cosine-distributed rays from area-uniform points
    on the emitting sides of each group (one material of one [[mesh]] entry), against the
    scene (`caster`: a tracing.rays.RayCaster of `elements`). A ray counts as reaching the
    scene when it meets the lit side of an element of another group (of any element, when the
    group is the whole scene): a lamp box wound inside out lights only its own inside.
    Returns [EmitterReach]; empty when nothing emits."""
    from radiosity.scene.closure import stratified_directions, tangent_frame
    from radiosity.scene.emitters import AreaEmitters

    side_emits = AreaEmitters(elements).emitting_sides()  # (n, 2): front, back
    if not side_emits.any():
        return []
    rng = np.random.default_rng(seed)
    two = np.asarray(elements.two_sided, bool)
    groups = {}
    for i in np.nonzero(side_emits.any(axis=1))[0]:
        groups.setdefault((int(elements.source[i]), int(elements.material[i])), []).append(i)
    per = max(16, min(rays, max_rays // max(1, len(groups))))
    # a group whose light can only light itself does not count as lighting the scene, unless the
    # scene is that group (a furnace: everything emits)
    alone = {g: bool((~_in_group(elements, np.arange(len(elements)), *g)).any()) for g in groups}
    lo = elements.verts.reshape(-1, 3).min(0)
    hi = elements.verts.reshape(-1, 3).max(0)
    # off the surface beyond Embree's float32 rounding (rays.epsilon is relative to the scene)
    step = 64.0 * caster.ray_offset * float(np.linalg.norm(hi - lo) or 1.0)
    out = []
    for (src, mat), ids in groups.items():
        ids = np.asarray(ids)
        # the emitting sides: (element, sign of the normal), chosen by area
        sides = [(i, 1.0) for i in ids if side_emits[i, 0]] + \
                [(i, -1.0) for i in ids if side_emits[i, 1] and two[i]]
        if not sides:
            continue
        el = np.array([s[0] for s in sides])
        sign = np.array([s[1] for s in sides])
        p = elements.area[el] / elements.area[el].sum()
        pick = rng.choice(len(el), size=per, p=p)
        e, sg = el[pick], sign[pick]
        pts = _points_on(elements.verts[e], elements.nverts[e], rng)
        nrm = sg[:, None] * elements.normal[e]
        t1, t2 = tangent_frame(nrm)
        loc = stratified_directions(per, rng)
        d = loc[:, :1] * t1 + loc[:, 1:2] * t2 + loc[:, 2:] * nrm
        hit = caster.first_hit(pts + step * nrm, d)
        lit = facing(elements, hit, pts)
        # a hit on the emitter itself (rounding at the start) says nothing: not counted
        own = hit == e
        if alone[(src, mat)]:  # light that stays in its own group (a lamp box inside out)
            lit &= ~_in_group(elements, hit, src, mat)
        reached = int((lit & ~own).sum())
        escaped = int((hit < 0).sum())
        backs = int(((hit >= 0) & ~lit & ~own).sum())
        big = ids[np.argmax(elements.area[ids])]
        out.append(EmitterReach(src, mat, len(ids), int(big), int(per - own.sum()), reached,
                                backs, escaped))
    return out


def _in_group(elements: Elements, elem: np.ndarray, source: int, material: int) -> np.ndarray:
    """Whether each element `elem` (k,) int (-1: none) is of material `material` in [[mesh]]
    entry `source`: (k,) bool."""
    e = np.maximum(elem, 0)
    return (elem >= 0) & (elements.source[e] == source) & (elements.material[e] == material)


def _points_on(verts: np.ndarray, nverts: np.ndarray, rng) -> np.ndarray:
    """One uniformly distributed point on each polygon (k, 4, 3), (k, 3): a quad's triangle
    by area, then uniform barycentric coordinates."""
    v0, v1, v2, v3 = (verts[:, i] for i in range(4))
    a1 = np.linalg.norm(np.cross(v1 - v0, v2 - v0), axis=1)
    a2 = np.where(nverts == 4, np.linalg.norm(np.cross(v2 - v0, v3 - v0), axis=1), 0.0)
    second = rng.random(len(verts)) * (a1 + a2) >= a1
    b, c = np.where(second[:, None], v2, v1), np.where(second[:, None], v3, v2)
    r1, r2 = rng.random(len(verts)), rng.random(len(verts))
    s = np.sqrt(r1)
    return (1 - s)[:, None] * v0 + (s * (1 - r2))[:, None] * b + (s * r2)[:, None] * c
