"""Splitting the sub-elements no pixel hits that seen surfaces see at close range
(scene/hidden.py, subdivide.hidden; issue 26).

The scene: a 2 x 2 floor, a short block in front of a tall one (both closed but for their
bottoms), a light above, and a camera in front looking down over the short block. The short
block hides the floor between the blocks (the gap) and the middle of the tall block's front
face's bottom; the camera's partition leaves the gap as 0.25 m sub-elements whose centroids lie
under the blocks (as the Cornell box's floor behind its short block), so one centroid ray loses
each one's light to the tall face whole.
"""

from __future__ import annotations

import numpy as np
import pytest

from helpers import box_polygons
from radiosity.settings import options as settings_of

SHORT = ((0.75, 0.0, 0.5), (1.25, 0.45, 0.9))
TALL = ((0.5, 0.0, 1.1), (1.5, 0.9, 1.5))
GAP = ((0.8, 1.2), (0.92, 1.08))  # x and z ranges of floor points between the blocks
FLOOR, TALL_FRONT = 0, 9          # element ids in the scene (floor first, then the boxes' faces)
RULE = (0.5, 1.0, 72)             # subdivide.hidden-factor, unseen-budget, hidden-rays as shipped


def _grid(q: np.ndarray, cell: float | None) -> list:
    """Quad q (4, 3) as cells of about `cell` metres (None: whole)."""
    if cell is None:
        return [q]
    u, v = q[1] - q[0], q[3] - q[0]
    nu = max(1, round(np.linalg.norm(u) / cell))
    nv = max(1, round(np.linalg.norm(v) / cell))
    return [np.array([p, p + u / nu, p + u / nu + v / nv, p + v / nv])
            for i in range(nu) for j in range(nv) for p in [q[0] + u * i / nu + v * j / nv]]


def blocks_scene(tmp_path, cell: float | None = None, resolution: int = 32) -> str:
    """The scene's TOML path; cell: every face pre-split into cells of that size (a reference
    with every hidden part finely meshed)."""
    lines, faces = [], []
    quads = [("floor", np.array([(0, 0, 0), (0, 0, 2), (2, 0, 2), (2, 0, 0)], float))]
    for (lo, hi), mat in ((SHORT, "short"), (TALL, "tall")):
        v, _ = box_polygons(lo, hi, inward=False, faces=[0, 1, 3, 4, 5])  # -x +x +y -z +z
        quads += [(mat, q) for q in v]
    quads.append(("light", np.array([(0.8, 2, 0.7), (1.2, 2, 0.7), (1.2, 2, 1.1),
                                     (0.8, 2, 1.1)], float)))
    cur = None
    for mat, q in quads:
        for c in _grid(q, cell):
            base = len(lines) + 1
            lines += ["v %r %r %r" % tuple(float(x) for x in p) for p in c]
            faces += ([f"usemtl {mat}"] if mat != cur else []) + [f"f {base} {base + 1} {base + 2} {base + 3}"]
            cur = mat
    name = "blocks" if cell is None else f"blocks-{cell}"
    (tmp_path / f"{name}.obj").write_text("\n".join(lines + faces) + "\n")
    toml = tmp_path / f"{name}.toml"
    toml.write_text(f"""[[mesh]]
path = "{name}.obj"
[material.floor]
reflectance = [0.7, 0.7, 0.7]
[material.short]
reflectance = [0.7, 0.7, 0.7]
[material.tall]
reflectance = [0.7, 0.7, 0.7]
[material.light]
reflectance = [0.0, 0.0, 0.0]
emission = [10.0, 10.0, 10.0]
[camera]
position = [1.0, 1.6, -1.2]
look_at = [1.0, 0.2, 1.0]
up = [0.0, 1.0, 0.0]
fov_y = 50.0
resolution = [{resolution}, {resolution}]
""")
    return str(toml)


def _under(verts: np.ndarray) -> np.ndarray:
    """Polygons (k, 4, 3) of the floor wholly under a block (vertices within its footprint)."""
    out = np.zeros(len(verts), bool)
    for lo, hi in (SHORT, TALL):
        inside = ((verts[:, :, 0] >= lo[0] - 1e-12) & (verts[:, :, 0] <= hi[0] + 1e-12)
                  & (verts[:, :, 2] >= lo[2] - 1e-12) & (verts[:, :, 2] <= hi[2] + 1e-12))
        out |= inside.all(axis=1)
    return out


@pytest.fixture(scope="module")
def partitions(tmp_path_factory):
    """The camera's partition (hidden keep) and the rule's (refine), sequentially."""
    from radiosity.scene.hidden import subdivide_scene_hidden
    from radiosity.scene.load import load_scene
    from radiosity.scene.subdivide import subdivide_scene

    sc = load_scene(blocks_scene(tmp_path_factory.mktemp("blocks")), settings=settings_of())
    keep = subdivide_scene(sc.elements, sc.camera, 1)
    refine = subdivide_scene_hidden(sc.elements, sc.camera, *RULE)
    return sc, keep, refine


def test_the_hidden_gap_is_split_and_the_floor_under_the_blocks_is_not(partitions):
    """The gap's floor is seen by the tall face at close range: the camera leaves it in
    sub-elements of 0.35 m diameter, the rule in ones of at most 0.18 m (measured: 0.354 and
    0.177). No node of the floor's split tree wholly under a block is split (no seen point
    sees it), and the count grows by at most 1.7x (measured: 665 -> 1048 at 32^2; most of it
    the blocks' unseen sides, which the seen floor beside them sees at close range)."""
    from radiosity.scene.splittrees import tree_nodes
    from radiosity.core.geometry import diameter
    from radiosity.scene.subdivide import lookup

    sc, (keep, *_), (part, _, _, fig) = partitions
    x, z = np.meshgrid(np.linspace(*GAP[0], 9), np.linspace(*GAP[1], 5))
    gap = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], 1)
    on = np.full(len(gap), FLOOR, np.int32)
    d = {name: diameter(p.verts[lookup(p, gap, on)], p.nverts[lookup(p, gap, on)])
         for name, p in (("keep", keep), ("refine", part))}
    assert d["keep"].max() > 0.3 and d["refine"].max() < 0.18, d
    assert fig["hidden"]["split"] > 0
    nodes = tree_nodes(part, sc.elements)
    inner = (nodes.child[:, 0] >= 0) & (nodes.orig == FLOOR)
    assert not np.any(_under(nodes.verts[inner]))
    assert len(keep) < len(part) <= 1.7 * len(keep)


def test_a_node_whose_centroid_is_under_a_block_is_seen_through_its_rim(partitions):
    """The Cornell box's case: a floor node centred under the short block, its back 0.1 m in
    the gap. The seed's one centroid ray to the tall face is blocked, but the rays from the
    node's rim find the face the camera sees; a node wholly under the block sees nothing."""
    from radiosity.scene.hidden import nearest_seen
    from radiosity.tracing.rays import RayCaster

    sc, *_ = partitions
    el = sc.elements
    rc = RayCaster(el.verts, el.nverts)
    straddling = [(0.8, 0, 0.6), (0.8, 0, 1.0), (1.2, 0, 1.0), (1.2, 0, 0.6)]
    under = [(0.8, 0, 0.55), (0.8, 0, 0.85), (1.2, 0, 0.85), (1.2, 0, 0.55)]
    verts = np.array([straddling, under], float)
    near = nearest_seen(verts, np.full(2, 4, np.int8), np.array([FLOOR, FLOOR]), el,
                        sc.camera, rc, np.full(2, 10.0), 72)
    assert np.isfinite(near[0]) and near[0] < 0.5, near
    assert near[1] == np.inf, near
    centre = np.array([[1.0, 0.0, 0.8]])
    assert rc.occluded(centre, el.center[[TALL_FRONT]])[0]


def test_the_rule_is_deterministic_and_each_new_leaf_holds_one_point(partitions):
    """Twice the same partition, to the bit; the rule's points and the camera's pixels make
    exactly its leaves: at most one point per leaf, the leaves added all hold one."""
    from radiosity.scene.hidden import anchors, split_hidden, subdivide_scene_hidden
    from radiosity.scene.subdivide import lookup, pixel_size
    from radiosity.tracing.rays import RayCaster

    sc, (keep, raster, pts, _), (part, *_) = partitions
    again = subdivide_scene_hidden(sc.elements, sc.camera, *RULE)[0]
    for k, v in part.arrays().items():
        assert np.array_equal(getattr(again, k), v), k
    e = raster.ravel()
    hit = e >= 0
    el = sc.elements
    rc = RayCaster(el.verts, el.nverts)
    hp, he, fig = split_hidden(keep, *anchors(keep, pts[hit], e[hit]), el, sc.camera, rc,
                               RULE[0], pixel_size(pts[hit]), int(hit.sum()), 48, RULE[2])
    count = np.bincount(lookup(part, np.concatenate([pts[hit], hp]),
                               np.concatenate([e[hit], he]).astype(np.int32)),
                        minlength=len(part))
    assert count.max() == 1
    assert len(part) == len(keep) + fig["added"]
    # a budget bounds what the rule adds
    _, _, small = split_hidden(keep, *anchors(keep, pts[hit], e[hit]), el, sc.camera, rc,
                               RULE[0], pixel_size(pts[hit]), 10, 48, RULE[2])
    assert small["added"] <= 10


def test_the_tall_face_gets_the_gaps_light(client, tmp_path):
    """The tall block's front face (its pixels, surface mean of the RGB sums) against the same
    scene with every face pre-split into 6.25 cm cells (hidden: keep, unseen: keep; a 4 cm mesh
    agrees with it within 0.3 % on this face): with the rule within 2.5 % (measured -1.3 %),
    without it more than 3.5 % dark (measured -4.8 %; the pairs method, 32^2)."""
    import dask.config

    from radiosity.pipeline import render_scene
    from radiosity.runtime.store import RunStore
    from radiosity.scene.load import load_scene
    from radiosity.stages.image import read_exr

    runs = {"keep": ("blocks", {"hidden": "keep"}), "refine": ("blocks", {}),
            "reference": ("blocks-0.0625", {"hidden": "keep", "unseen": "keep"})}
    blocks_scene(tmp_path)
    blocks_scene(tmp_path, cell=0.0625)
    img, figures = {}, {}
    for name, (toml, cfg) in runs.items():
        out = str(tmp_path / name)
        with dask.config.set({f"radiosity.subdivide.{k}": v for k, v in cfg.items()}):
            rep = render_scene(load_scene(str(tmp_path / f"{toml}.toml"), settings=settings_of()),
                               out, client, settings_of(method="pairs"), preview=False,
                               progress=False, echo=lambda *a: None)
        img[name] = read_exr(f"{out}/image.exr").astype(float).sum(-1)
        figures[name] = rep["preprocess"]
    face = RunStore(str(tmp_path / "keep")).read_arrays("raster")["orig"] == TALL_FRONT
    assert face.sum() > 100
    rel = {k: img[k][face].mean() / img["reference"][face].mean() - 1 for k in ("keep", "refine")}
    assert abs(rel["refine"]) < 0.025 and rel["keep"] < -0.035, rel
    assert figures["refine"]["hidden_split"] > 0 and figures["keep"]["hidden_split"] == 0
    assert figures["refine"]["sub_elements"] <= 1.5 * figures["keep"]["sub_elements"]
