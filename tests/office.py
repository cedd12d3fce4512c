"""An office as a user brings it (issue 50, "meshes as users bring them"): one GLB holding a
room L x H x D = 5 x 3 x 4 (y up) with a window opening in its z = D wall, a table (a top and
four legs, each a closed box) and a ceiling panel that emits (a thin closed box), every part
modelled the usual way: the room's normals inward, the furniture's out of its own volume."""

from __future__ import annotations

import numpy as np

OFFICE = (5.0, 3.0, 4.0)  # x, y (up), z
WINDOW = ((1.5, 1.0), (3.5, 2.2))  # (x, y) corners of the opening in the z = D wall
TABLE = ((1.8, 0.0, 1.2), (3.2, 0.75, 2.4))  # its bounding box
PANEL = ((2.0, 2.9, 1.5), (3.0, 2.95, 2.5))  # the emitting ceiling panel


def _grid_wall(xs, ys, z, skip=()):
    """Quads of the z = const wall on the grid xs x ys (cells `skip` left out: the opening),
    normals toward -z (into a room that lies at z < D), as (vertices, triangles)."""
    vs, fs = [], []
    for i in range(len(xs) - 1):
        for j in range(len(ys) - 1):
            if (i, j) in skip:
                continue
            k = len(vs)
            vs += [[xs[i], ys[j], z], [xs[i + 1], ys[j], z], [xs[i + 1], ys[j + 1], z],
                   [xs[i], ys[j + 1], z]]
            fs += [[k, k + 2, k + 1], [k, k + 3, k + 2]]
    return np.array(vs, float), np.array(fs)


def office_parts(window=True, panel=PANEL):
    """{name: trimesh.Trimesh} of the office: 'room' (one connected shell, normals inward),
    'top' and 'leg0'..'leg3' (the table), 'panel' (the lamp)."""
    import trimesh

    L, H, D = OFFICE
    box = trimesh.creation.box(bounds=[[0, 0, 0], [L, H, D]])
    box.invert()  # normals into the room
    # the z = D wall again, as a 3 x 3 grid of quads without its middle cell: the window
    keep = box.triangles_center[:, 2] < D - 1e-9
    (x0, y0), (x1, y1) = WINDOW
    wv, wf = _grid_wall([0, x0, x1, L], [0, y0, y1, H], D, skip={(1, 1)} if window else ())
    room = trimesh.util.concatenate([trimesh.Trimesh(box.vertices, box.faces[keep]),
                                     trimesh.Trimesh(wv, wf)])
    room.merge_vertices()
    parts = {"room": room}
    (a, b) = np.array(TABLE)
    top = np.array([[a[0], b[1] - 0.05, a[2]], b])
    parts["top"] = trimesh.creation.box(bounds=top)
    for k, (x, z) in enumerate([(a[0], a[2]), (b[0] - 0.08, a[2]), (a[0], b[2] - 0.08),
                                (b[0] - 0.08, b[2] - 0.08)]):
        parts[f"leg{k}"] = trimesh.creation.box(bounds=[[x, 0.0, z], [x + 0.08, b[1] - 0.05,
                                                                    z + 0.08]])
    parts["panel"] = trimesh.creation.box(bounds=np.array(panel))
    return parts


def glb_office(flipped=False, window=True, emission=8.0, panel=PANEL) -> bytes:
    """The office as GLB bytes; `flipped`: every face wound the other way (an exporter's
    mistake; True: every part, or the names of some, e.g. {"room"}: a room modelled from a box
    whose normals point out); `panel`: the lamp box's corners. Materials: 'wall' (0.7), 'wood'
    (0.4, 0.25, 0.1) for the table, 'lamp' emitting `emission` (KHR_materials_emissive_strength)."""
    import trimesh
    from trimesh.visual.material import PBRMaterial

    from helpers import edit_glb

    mats = {"wall": [0.7, 0.7, 0.7, 1.0], "wood": [0.4, 0.25, 0.1, 1.0],
            "lamp": [0.5, 0.5, 0.5, 1.0]}
    s = trimesh.Scene()
    for name, m in office_parts(window, panel).items():
        if flipped is True or name in (flipped or ()):
            m.invert()
        mat = "wall" if name == "room" else "lamp" if name == "panel" else "wood"
        m.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(
            name=mat, baseColorFactor=mats[mat],
            emissiveFactor=[1.0, 1.0, 1.0] if mat == "lamp" else [0.0, 0.0, 0.0]))
        s.add_geometry(m, node_name=name)
    return edit_glb(s.export(file_type="glb"), lambda doc: [m.setdefault("extensions", {}).update(
        KHR_materials_emissive_strength={"emissiveStrength": emission})
        for m in doc["materials"] if m.get("name") == "lamp"])


def office_polygons(flipped=False, window=True):
    """The office's triangles as Elements-style polygons: verts (n, 4, 3) (slot 3 repeats slot
    2), nverts (n,) all 3, and the name of the part (office_parts) of each."""
    verts, names = [], []
    for name, m in office_parts(window).items():
        if flipped:
            m.invert()
        t = m.triangles
        verts.append(t[:, [0, 1, 2, 2]])
        names += [name] * len(t)
    verts = np.concatenate(verts)
    return verts, np.full(len(verts), 3, np.int8), np.array(names)
