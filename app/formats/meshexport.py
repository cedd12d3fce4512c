"""The solved sub-elements as a mesh, coloured like the image (core.colour); the web page is
formats.viewer's.

    mesh.glb     triangles (glTF 2.0, KHR_materials_unlit): COLOR_0 = the exposed, clipped
                 *linear* colour (glTF vertex colours are linear), `_RADIANCE` = the linear
                 radiance (float32 VEC3, per vertex)
    mesh.ply     the same triangles, 8-bit sRGB vertex colours, per-face float properties
                 radiance_r, radiance_g, radiance_b (linear: the sub-element's solved value)

Given a core.smooth.SmoothMesh (`smooth=`), both show the radiance reconstructed at
shared vertices, interpolated across each triangle (smooth; what a render writes); without
it, one flat colour per sub-element (vertices duplicated per triangle).
"""

from __future__ import annotations

import json
import struct

import numpy as np

from radiosity.core.bundles import Partition
from radiosity.core.colour import auto_exposure, tonemap
from radiosity.core.smooth import SmoothMesh
from radiosity.errors import RenderError
from radiosity.formats.files import write_bytes


# ----------------------------------------------------------------------------- meshes

def triangles(part: Partition):
    """Fan triangulation of the sub-elements (quads -> 2 triangles), in sub-element order.

    Returns tri_sub (T,) int64, the sub-element of each triangle, and tri_verts (T, 3, 3)
    float64, counter-clockwise seen from the front (the front normal's side).
    """
    nv = np.asarray(part.nverts)
    m = len(nv)
    quads = np.flatnonzero(nv == 4)
    sub = np.concatenate([np.arange(m), quads])
    corner = np.concatenate([np.tile([0, 1, 2], (m, 1)), np.tile([0, 2, 3], (len(quads), 1))])
    order = np.argsort(sub, kind="stable")
    sub, corner = sub[order], corner[order]
    return sub, part.verts[sub[:, None], corner]


def _mesh_faces(part, radiance, two_sided):
    """Triangles, their sub-element and side: front faces, then reversed back faces of the
    two-sided sub-elements."""
    sub, v = triangles(part)
    side = np.zeros(len(sub), np.intp)
    if two_sided is not None:
        two = np.asarray(two_sided, bool)[sub]
        sub = np.concatenate([sub, sub[two]])
        v = np.concatenate([v, v[two][:, ::-1]])
        side = np.concatenate([side, np.ones(int(two.sum()), np.intp)])
    return sub, v, np.asarray(radiance, np.float64)[sub, side]


def _glb_patch(glb: bytes, extras: dict) -> bytes:
    """Make trimesh's GLB a radiosity mesh: `_COLOR_LINEAR` becomes COLOR_0, one unlit material."""
    magic, version, _ = struct.unpack_from("<4sII", glb, 0)
    jlen, jtype = struct.unpack_from("<I4s", glb, 12)
    if magic != b"glTF" or jtype != b"JSON":
        raise RenderError("trimesh wrote an unexpected GLB layout")
    doc = json.loads(glb[20:20 + jlen])
    rest = glb[20 + jlen:]
    doc["materials"] = [{
        "name": "radiosity",
        "pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0], "metallicFactor": 0.0,
                                 "roughnessFactor": 1.0},
        "doubleSided": False,
        "extensions": {"KHR_materials_unlit": {}},
    }]
    doc["extensionsUsed"] = sorted(set(doc.get("extensionsUsed", [])) | {"KHR_materials_unlit"})
    for mesh in doc.get("meshes", []):
        for prim in mesh["primitives"]:
            at = prim["attributes"]
            if "_COLOR_LINEAR" in at:
                at["COLOR_0"] = at.pop("_COLOR_LINEAR")
            prim["material"] = 0
    doc.setdefault("asset", {})["extras"] = extras
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    body = struct.pack("<I4s", len(js), b"JSON") + js + rest
    return struct.pack("<4sII", b"glTF", version, 12 + len(body)) + body


def export_mesh(path_glb: str, path_ply: str, part: Partition, radiance: np.ndarray,
                exposure: float | None, two_sided: np.ndarray | None = None,
                smooth: SmoothMesh | None = None) -> dict:
    """The sub-elements as a triangle mesh: mesh.glb and mesh.ply.

    smooth: the radiance at shared vertices (core.smooth.smooth_mesh of the same partition
    and radiance): indexed triangles whose colours are interpolated across each face, the
    backs of two-sided sub-elements included (its own vertices). None: flat colours, vertices
    duplicated per triangle, one colour per face: the front radiance (m, 2, 3)[:, 0]; with
    two_sided (m,) bool, each two-sided sub-element's back as a reversed triangle coloured by
    its back radiance (single-sided material, so each side shows its own colour).
    Colours are the radiance times `exposure` (None: automatic over the front radiances).
    GLB: COLOR_0 float linear colour in [0, 1] (glTF's colour space), `_RADIANCE` float32
    linear radiance, KHR_materials_unlit. PLY: 8-bit sRGB vertex colours, vertex properties
    radiance_r/g/b (smooth only) and face properties radiance_r/g/b (float32, linear, the
    sub-element's solved value).
    Returns {"triangles" (front), "faces" (with the backs), "vertices", "exposure", "smooth"}.
    """
    import trimesh

    radiance = np.asarray(radiance, np.float64)
    if exposure is None:
        exposure = auto_exposure(radiance[:, 0])
    exposure = float(exposure)
    if smooth is not None:
        verts, faces = smooth.verts, smooth.faces
        vrad = smooth.radiance
        frad = radiance[smooth.face_sub, smooth.face_side]
        ntri = smooth.front_triangles
    else:
        sub, v, frad = _mesh_faces(part, radiance, two_sided)
        t = len(sub)
        verts = v.reshape(-1, 3)
        faces = np.arange(3 * t, dtype=np.int64).reshape(t, 3)
        vrad = np.repeat(frad, 3, axis=0)
        ntri = int(np.sum(np.asarray(part.nverts, np.int64) - 2))
    t = len(faces)
    vrad32 = vrad.astype(np.float32)

    g = trimesh.Trimesh(verts, faces, process=False, validate=False)
    g.vertex_attributes["_COLOR_LINEAR"] = np.clip(vrad * exposure, 0.0, 1.0).astype(np.float32)
    g.vertex_attributes["_RADIANCE"] = vrad32
    write_bytes(path_glb, _glb_patch(g.export(file_type="glb"), {
        "generator": "radiosity", "exposure": exposure, "faces": t, "sub_elements": len(part),
        "smooth": smooth is not None,
        "_RADIANCE": "linear RGB radiance, W sr^-1 m^-2" + (
            ", reconstructed at vertices (core/smooth.py)" if smooth is not None else "")}))

    rgb = tonemap(vrad, exposure)
    rgba = np.concatenate([rgb, np.full((len(verts), 1), 255, np.uint8)], axis=1)
    p = trimesh.Trimesh(verts, faces, vertex_colors=rgba, process=False, validate=False)
    for i, c in enumerate("rgb"):
        if smooth is not None:
            p.vertex_attributes[f"radiance_{c}"] = np.ascontiguousarray(vrad32[:, i])
        p.face_attributes[f"radiance_{c}"] = np.ascontiguousarray(frad[:, i], np.float32)
    write_bytes(path_ply, p.export(file_type="ply", encoding="binary"))
    return {"triangles": ntri, "faces": t, "vertices": len(verts), "exposure": exposure,
            "smooth": smooth is not None}
