"""Visibility-aware splitting of hidden sub-elements: the parts of the scene the camera does
not see whole that a seen surface sees at close range (issue 26).

The camera-driven rule (seed §3) splits only what pixels hit: a sub-element no pixel hits keeps
its size, however large. Where it lies close to something the camera sees its size matters: one
centroid (or one link) stands for all of it, and when that centroid is covered (under a block
standing on the floor) all of its light to the seen surface is lost. Here a sub-element holding
at most one of the points that made it, whose image covers more than a few pixels (so the
camera does not see it whole), is split by the seed's rule while its diameter exceeds `factor`
times its distance to the nearest camera-seen point that sees it: the importance of the unseen
rule (subdivide.importance_points), with visibility. That distance is the shortest ray from
points spread over the node (its centroid, and points towards its vertices and edge midpoints)
to a surface point the camera sees, on the side the ray arrives at. A region no seen surface
can see (the floor enclosed under a block) gets no such ray and stays whole; a node whose
centroid is covered but whose rim is in the open is found by the rays from its rim.

Design notes and measurements: docs/src/design/scene-subdivide.md.
"""

from __future__ import annotations

import numpy as np

from radiosity.core.camera import project
from radiosity.core.geometry import diameter, polygon_properties
from radiosity.scene.subdivide import (lookup, pixel_size, sides, split_polygons, subdivide,
                                       subdivide_scene, warn_depth_guard)

GOLDEN = np.pi * (3.0 - np.sqrt(5.0))  # the golden angle: azimuths that never repeat
INSET = 0.8  # sample points 80 % of the way from the centroid to each vertex and edge midpoint
CHUNK = 8192  # nodes per batch of rays (72 rays each: 600 k rays, about 40 MB of buffers)
SEEN_PIXELS = 4.0  # a sub-element whose image covers more pixels than this, with at most one
#                    pixel centre on it, is partly hidden (the split rule keeps aspect <= 2)


def sample_points(verts: np.ndarray, nverts: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Nine points on each polygon, (q, 9, 3) float64: its centroid, and the points INSET of the
    way from the centroid to each vertex slot and each edge midpoint (a triangle repeats vertex
    2 in slot 3, so two of its points repeat). Inset so that a point on the rim of a node that
    touches another surface (the floor at a block's base) does not start inside it."""
    v = np.asarray(verts, float)
    mid = 0.5 * (v + v[:, [1, 2, 3, 0]])
    tri = np.asarray(nverts) == 3
    mid[tri, 3] = 0.5 * (v[tri, 2] + v[tri, 0])  # a triangle's third edge is (2, 0)
    c = center[:, None, :]
    return np.concatenate([c, c + INSET * (v - c), c + INSET * (mid - c)], axis=1)


def hemisphere_directions(normal: np.ndarray, tangent: np.ndarray, count: int,
                          two_sided: np.ndarray) -> np.ndarray:
    """`count` unit directions per node spread evenly over its front hemisphere (both
    hemispheres, alternately, where two_sided), (q, count, 3) float64: a spherical Fibonacci
    set (uniform in solid angle, so that grazing directions, where the nearest point of a
    perpendicular surface lies, are as dense as steep ones), turned by a different azimuth per
    node so that neighbouring nodes do not alias. Deterministic."""
    q = len(normal)
    k = np.arange(count)
    z = 1.0 - (k + 0.5) / count
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = k[None, :] * GOLDEN + (np.arange(q) * GOLDEN * 0.5)[:, None]
    t1 = tangent - np.sum(tangent * normal, axis=1, keepdims=True) * normal
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normal, t1)
    sign = np.where(np.asarray(two_sided, bool)[:, None] & (k[None, :] % 2 == 1), -1.0, 1.0)
    return ((r * np.cos(phi))[:, :, None] * t1[:, None, :] + (r * np.sin(phi))[:, :, None] * t2[:, None, :]
            + (sign * z)[:, :, None] * normal[:, None, :])


def camera_sees(x: np.ndarray, e: np.ndarray, side: np.ndarray, elements, camera, caster):
    """Whether the camera sees side `side` (k,) (+1 front, -1 back) of element e[k] at x[k],
    (k,) bool: x in the view, the camera on that side of e's plane, and the camera's ray
    towards x first hits e there (as a pixel's ray does; the first hit may also be another
    element within 8 ray offsets of x: a neighbour sharing the edge x lies on).
    x (k, 3) float64 is first put back on e's plane (a ray's hit point carries Embree's float32
    distance)."""
    ok = np.zeros(len(e), bool)
    if not len(e):
        return ok
    ne = np.asarray(elements.normal, float)[e]
    x = x - np.einsum("kc,kc->k", x - elements.center[e], ne)[:, None] * ne
    ok = side * np.einsum("kc,kc->k", camera.center[None, :] - x, ne) > 0
    col, row, zc = project(camera, x)
    ok &= (zc > 0) & (col >= 0) & (col < camera.width) & (row >= 0) & (row < camera.height)
    g = np.nonzero(ok)[0]
    if len(g):
        d = x[g] - camera.center
        dist = np.linalg.norm(d, axis=1)
        first, t = caster.first_hit(camera.center, d / dist[:, None], distances=True, unit=True)
        ok[g] = (first == e[g]) | (t >= dist - 8 * caster.ray_offset * caster.scale)
    return ok


def nearest_seen(verts, nverts, orig, elements, camera, caster, reach, rays: int):
    """Distance from each node to the nearest camera-seen surface point that sees it, (q,)
    float64 (inf where none is within `reach` (q,)).

    verts (q, 4, 3), nverts (q,), orig (q,) of the nodes; elements: the originals (normal,
    center, two_sided); caster: a RayCaster of the originals; rays: per node, spread over its
    nine sample points. A ray counts when its first hit x (on element e) lies within `reach`,
    on a side e has (the front, or either of a two-sided one), and the camera sees that side
    of e at x (`camera_sees`). Nodes go CHUNK at a time (bounded ray buffers)."""
    q = len(orig)
    if q > CHUNK:
        return np.concatenate([nearest_seen(verts[a:a + CHUNK], nverts[a:a + CHUNK],
                                            orig[a:a + CHUNK], elements, camera, caster,
                                            reach[a:a + CHUNK], rays)
                               for a in range(0, q, CHUNK)])
    near = np.full(q, np.inf)
    if q == 0:
        return near
    normal = np.asarray(elements.normal, float)
    two_sided = np.asarray(elements.two_sided, bool)
    _, _, center = polygon_properties(verts, nverts)
    n_node = normal[orig]
    samples = sample_points(verts, nverts, center)                      # (q, 9, 3)
    dirs = hemisphere_directions(n_node, verts[:, 1] - verts[:, 0], rays, two_sided[orig])
    start = samples[:, np.arange(rays) % samples.shape[1], :]           # (q, rays, 3)
    side = np.sign(np.einsum("qkc,qc->qk", dirs, n_node))
    # leave the node's plane on the side the ray goes, by the ray module's offset (world units)
    lift = caster.ray_offset * caster.scale
    o = (start + (side * lift)[:, :, None] * n_node[:, None, :]).reshape(-1, 3)
    d = dirs.reshape(-1, 3)
    e, t = caster.first_hit(o, d.astype(np.float32), distances=True, unit=True)
    node = np.repeat(np.arange(q), rays)
    idx = np.nonzero((e >= 0) & (t < np.repeat(reach, rays)))[0]
    e, t, node, d, o = e[idx], t[idx], node[idx], d[idx], o[idx]
    hit_side = np.where(np.einsum("kc,kc->k", d, normal[e]) < 0, 1.0, -1.0)
    g = np.nonzero(two_sided[e] | (hit_side > 0))[0]
    g = g[camera_sees(o[g] + t[g, None] * d[g], e[g], hit_side[g], elements, camera, caster)]
    np.minimum.at(near, node[g], t[g])
    return near


def projected_pixels(verts: np.ndarray, camera, subpixel: int = 1) -> np.ndarray:
    """Area of each polygon's image in the camera, in pixels of the K-times finer raster, (q,)
    float64 (inf where a vertex lies behind the camera). verts (q, 4, 3) (a triangle repeats
    vertex 2: a zero edge)."""
    q = len(verts)
    col, row, zc = project(camera, verts.reshape(-1, 3), subpixel)
    col, row, zc = col.reshape(q, 4), row.reshape(q, 4), zc.reshape(q, 4)
    with np.errstate(invalid="ignore"):  # inf - inf behind the camera: replaced below
        area = 0.5 * np.abs(np.sum(col * np.roll(row, -1, axis=1)
                                   - np.roll(col, -1, axis=1) * row, axis=1))
    return np.where((zc > 0).all(axis=1), area, np.inf)


def anchors(part, points: np.ndarray, point_elem: np.ndarray):
    """The points that made a partition, per sub-element: count (m,) int64 and anchor (m, 3)
    float64, the point of each sub-element holding exactly one (zero elsewhere). points (p, 3)
    on originals point_elem (p,)."""
    leaf = lookup(part, points, np.asarray(point_elem, np.int32))
    count = np.bincount(leaf, minlength=len(part))
    anchor = np.zeros((len(part), 3))
    one = count[leaf] == 1
    anchor[leaf[one]] = points[one]
    return count, anchor


def split_hidden(part, count: np.ndarray, anchor: np.ndarray, elements, camera, caster,
                 factor: float, min_size: float, budget: int, max_depth: int = 48,
                 rays: int = 72, subpixel: int = 1):
    """Where to split the parts of sub-elements no pixel hits that a seen surface sees at close
    range.

    part: the camera's Partition (with the unseen rule's leaves); count (m,) int: the points
    that made it on each sub-element (camera pixels, the unseen rule's points); anchor (m, 3)
    float64: the point of each sub-element with one (any value elsewhere); elements: the
    originals; camera and caster (a RayCaster of the originals) for the rays. Candidates are the
    sub-elements with at most one point whose image covers more than SEEN_PIXELS pixels of the
    criterion's raster (`subpixel` times finer than the camera's) (the
    camera does not see them whole: hidden ones, unseen originals' and those with one pixel and
    a hidden part) and whose diameter exceeds `min_size`. A candidate, or a node split from
    one, is split by the seed's rule while its diameter exceeds `factor` times its distance to
    the nearest seen point that sees it (`nearest_seen`), `min_size` (a seen pixel's size) and
    stays within `max_depth`; at most `budget` sub-elements are added (the most important splits
    first, level by level, as in subdivide.importance_points).

    Returns (points (q, 3), originals (q,) int64, figures): the centroid of every final leaf of
    a split candidate except the one holding its anchor (followed through the splits by the
    same side test as `subdivide`). Fed to `subdivide` with the points that made `part`, they
    make exactly these leaves: every leaf holds one point, every split node two or more.
    """
    count = np.asarray(count)
    cand = np.nonzero((count <= 1) & (part.depth < max_depth))[0]
    # the camera's image of a sub-element holds about as many pixel centres as its area in
    # pixels, and the camera split until each holds at most one: larger images with at most
    # one are partly hidden (or out of the view); smaller ones are the camera's own scale
    cand = cand[projected_pixels(part.verts[cand], camera, subpixel) > SEEN_PIXELS]
    if len(cand):
        cand = cand[diameter(part.verts[cand], part.nverts[cand]) > min_size]
    figures = {"candidates": int(len(cand))}
    if not len(cand):
        return np.zeros((0, 3)), np.zeros(0, np.int64), \
            {**figures, "rays": 0, "levels": 0, "split": 0, "added": 0}
    node_v = part.verts[cand]
    node_n = np.asarray(part.nverts[cand], np.int8)
    node_o = part.orig[cand].astype(np.int64)
    node_d = part.depth[cand].astype(np.int64)
    node_r = np.arange(len(cand))                      # the candidate each node descends from
    node_a = np.asarray(anchor, float)[cand]
    node_h = count[cand] == 1                          # the node holds its candidate's anchor
    done = []
    added, cast, levels = 0, 0, 0
    while len(node_r):
        diam = diameter(node_v, node_n)
        reach = diam / factor                          # farther seen points cannot ask a split
        near = nearest_seen(node_v, node_n, node_o, elements, camera, caster, reach, rays)
        cast += len(node_r) * rays
        want = (diam > factor * near) & (diam > min_size) & (node_d < max_depth)
        room = budget - added
        if want.sum() > room:  # over budget: split the most important nodes only
            order = np.argsort(-(diam / np.maximum(near, 1e-300)), kind="stable")
            keep = np.zeros(len(want), bool)
            keep[order[:max(room, 0)]] = True
            want &= keep
        done.append((node_v[~want], node_n[~want], node_r[~want], node_h[~want]))
        if not want.any():
            break
        added += int(want.sum())
        levels += 1
        c0, c1, a, m = split_polygons(node_v[want], node_n[want])
        second = sides(np.ascontiguousarray(node_a[want]), a, m)  # subdivide's own side test
        node_v = np.stack([c0, c1], 1).reshape(-1, 4, 3)
        node_n = np.repeat(node_n[want], 2)
        node_o = np.repeat(node_o[want], 2)
        node_d = np.repeat(node_d[want] + 1, 2)
        node_r = np.repeat(node_r[want], 2)
        node_h = (np.stack([~second, second], 1) & node_h[want][:, None]).reshape(-1)
        node_a = np.repeat(node_a[want], 2, axis=0)
    figures.update(rays=int(cast), levels=levels)
    leaf_v, leaf_n, leaf_r, leaf_h = (np.concatenate(x) for x in zip(*done))
    split = np.bincount(leaf_r, minlength=len(cand)) > 1
    mine = split[leaf_r] & ~leaf_h
    _, _, centre = polygon_properties(leaf_v[mine], leaf_n[mine])
    figures.update(split=int(split.sum()), added=added)
    return centre, part.orig[cand[leaf_r[mine]]].astype(np.int64), figures


def subdivide_scene_hidden(elements, camera, factor: float, per_pixel: float, rays: int,
                           subpixel: int = 1, max_depth: int = 48, caster=None):
    """The sequential preprocessing with the rule (subdivide.hidden: refine) on every original:
    the camera's partition (subdivide.subdivide_scene), then `split_hidden` (factor, a budget of
    per_pixel sub-elements per pixel hit, rays), then `subdivide` again with the new points.
    Returns what subdivide_scene does, with figures["hidden"] the rule's."""
    from radiosity.tracing.rays import RayCaster

    rc = caster or RayCaster(elements.verts, elements.nverts)
    part, raster, pts, fig = subdivide_scene(elements, camera, subpixel, max_depth, rc)
    elem = raster.ravel()
    hit = elem >= 0
    if not hit.any():
        return part, raster, pts, {**fig, "hidden": {"split": 0, "added": 0}}
    hp, he, hfig = split_hidden(part, *anchors(part, pts[hit], elem[hit]), elements, camera, rc,
                                factor, pixel_size(pts[hit]), int(per_pixel * hit.sum()),
                                max_depth, rays, subpixel)
    if len(hp):
        part, fig = subdivide(elements.verts, elements.nverts, elements.normal,
                              np.concatenate([pts[hit], hp]), np.concatenate([elem[hit], he]),
                              max_depth)
        warn_depth_guard(fig["guarded"], fig["guarded_first"], max_depth)
    return part, raster, pts, {**fig, "hidden": hfig}
