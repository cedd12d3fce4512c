"""Mesh files read through trimesh (glTF/GLB, PLY, STL) -> RawMesh, with their materials: glTF's
PBR base colour and emission (with KHR_materials_emissive_strength and texture means), PLY's
face or vertex colours; STL (the common CAD export) has none: its faces take the mesh's
material (`default` unless the scene names one)."""

from __future__ import annotations

import json
import struct

import numpy as np

from radiosity.core.colour import srgb_to_linear
from radiosity.errors import SceneError
from radiosity.formats.raw import RawMesh, warn


def _gltf_json(fn: str) -> dict:
    """The glTF JSON document (for factors trimesh rounds or drops, e.g. emissive strength)."""
    with open(fn, "rb") as f:
        data = f.read()
    if data[:4] == b"glTF":
        n = struct.unpack("<I", data[12:16])[0]
        return json.loads(data[20:20 + n])
    return json.loads(data)


def load_trimesh(fn: str, default_material: str) -> RawMesh:
    """glTF/GLB, PLY and STL through trimesh (node transforms applied). Materials: glTF's by name
    (baseColorFactor, and its texture's mean, as reflectance; emissiveFactor x
    KHR_materials_emissive_strength, and its texture's mean, as emission; doubleSided); a PLY's
    face or vertex colours as materials `colour-RRGGBB` unless `default_material` names one."""
    import trimesh

    try:
        loaded = trimesh.load(fn, force="scene", process=False)
    except Exception as e:  # trimesh raises many types for corrupt files
        raise SceneError(f"cannot read mesh file {fn}: {e}") from None
    gmats = {}
    gltf, gnames = [], []
    if fn.lower().endswith((".gltf", ".glb")):
        try:
            doc = _gltf_json(fn)
        except Exception as e:
            raise SceneError(f"cannot parse glTF JSON of {fn}: {e}") from None
        gltf = doc.get("materials", [])
        gnames = _gltf_material_names(gltf, fn)
        for name, m in zip(gnames, gltf):
            pbr = m.get("pbrMetallicRoughness", {})
            # no baseColorFactor: the default reflectance, as an MTL material without Kd (glTF's
            # own default, 1, would create energy); a texture scales it (_texture_means)
            props = {}
            if "baseColorFactor" in pbr or "baseColorTexture" in pbr:
                props["reflectance"] = list(pbr.get("baseColorFactor", [1, 1, 1, 1]))[:3]
            strength = m.get("extensions", {}).get("KHR_materials_emissive_strength", {})
            e = np.asarray(m.get("emissiveFactor", [0, 0, 0]), float) * float(
                strength.get("emissiveStrength", 1.0))
            props["emission"] = e.tolist()
            props["two_sided"] = bool(m.get("doubleSided", False))
            gmats[name] = props
    verts, faces, fmat = [], [], []
    base = 0
    textured = set()
    for node in loaded.graph.nodes_geometry:
        transform, gname = loaded.graph[node]
        mesh = loaded.geometry[gname]
        if not hasattr(mesh, "faces"):
            continue
        v = trimesh.transformations.transform_points(np.asarray(mesh.vertices, float), transform)
        name = default_material
        mat = getattr(getattr(mesh, "visual", None), "material", None)
        f = np.asarray(mesh.faces)
        names = None
        if gltf and mat is not None:
            idx = _gltf_material_of(mat, gltf, fn)
            if idx is not None:
                name = gnames[idx]
                if name not in textured:
                    textured.add(name)
                    _texture_means(gmats[name], mat, gltf[idx])
        elif not gltf and default_material == "default" and len(f):
            names = _colour_materials(mesh, gmats)  # PLY: its face or vertex colours
        verts.append(v)
        if len(f):
            faces.extend((f.astype(np.int64) + base).tolist())
            fmat.extend(names if names is not None else [name] * len(f))
        base += len(v)
    v = np.concatenate(verts) if verts else np.zeros((0, 3))
    return RawMesh(v, faces, fmat, gmats)


def _image_mean(img) -> np.ndarray | None:
    """The mean linear RGB (3,) of an sRGB texture image (PIL), from at most 256 x 256 pixels;
    None if it cannot be read."""
    try:
        im = img.convert("RGB")
        im.thumbnail((256, 256))
        px = np.asarray(im, float).reshape(-1, 3) / 255.0
    except Exception:  # noqa: BLE001 - a texture we cannot read: the factor alone
        return None
    return srgb_to_linear(px).mean(axis=0) if len(px) else None


def _texture_means(props: dict, mat, doc: dict) -> None:
    """A glTF material's baseColorTexture and emissiveTexture, as their means: the
    reflectance and emission factors scaled by the mean linear colour of the texture (the
    elements are flat-coloured; a texture's detail below them is averaged)."""
    pbr = doc.get("pbrMetallicRoughness", {})
    if "baseColorTexture" in pbr:
        m = _image_mean(getattr(mat, "baseColorTexture", None))
        if m is not None:
            props["reflectance"] = (np.asarray(props["reflectance"], float) * m).tolist()
    if "emissiveTexture" in doc:
        m = _image_mean(getattr(mat, "emissiveTexture", None))
        if m is not None:
            props["emission"] = (np.asarray(props["emission"], float) * m).tolist()


def _colour_materials(mesh, mats: dict) -> list | None:
    """Per-face material names of a mesh with face or vertex colours (PLY), one material per
    distinct colour, named `colour-RRGGBB` (8-bit sRGB, as stored) with that colour, linear,
    as its reflectance; a face of vertex colours takes their mean. None without colours."""
    visual = getattr(mesh, "visual", None)
    kind = getattr(visual, "kind", None)
    if kind == "face":
        rgb = np.asarray(visual.face_colors, float)[:, :3]
    elif kind == "vertex":
        rgb = np.asarray(visual.vertex_colors, float)[:, :3][np.asarray(mesh.faces)].mean(axis=1)
    else:
        return None
    rgb = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    uniq, inv = np.unique(rgb, axis=0, return_inverse=True)
    names = []
    for c in uniq:
        name = "colour-" + "".join(f"{int(x):02x}" for x in c)
        mats.setdefault(name, {"reflectance": srgb_to_linear(c / 255.0).tolist()})
        names.append(name)
    return [names[k] for k in inv.ravel().tolist()]


def _gltf_material_names(gltf: list, fn: str) -> list[str]:
    """A distinct name per glTF material (by index): its own name; `unnamed-<i>` for one without
    a name; `<name>#<i>` for a later material that reuses a name with other properties (said,
    with a warning: the TOML overrides materials by these names)."""
    names, first = [], {}
    for i, m in enumerate(gltf):
        name = m.get("name") or f"unnamed-{i}"
        props = {k: v for k, v in m.items() if k != "name"}
        if name in first and first[name] != props:
            new = f"{name}#{i}"
            warn(f"{fn}: glTF material {i} reuses the name '{name}' with other properties; "
                  f"it is called '{new}' here (override it as [material.\"{new}\"])")
            name = new
        first.setdefault(name, props)
        names.append(name)
    return names


def _gltf_material_of(mat, gltf: list, fn: str) -> int | None:
    """The index of the glTF material trimesh made `mat` (a PBRMaterial) from: the one of that
    name (or of no name), and among several of the same name the one whose factors match
    (trimesh keeps baseColorFactor to 8 bits only). None if no glTF material matches."""
    name = getattr(mat, "name", None) or None
    cands = [i for i, m in enumerate(gltf) if (m.get("name") or None) == name]
    if len(cands) <= 1:
        return cands[0] if cands else None

    def distance(i):
        m = gltf[i]
        pbr = m.get("pbrMetallicRoughness", {})
        want = np.asarray(pbr.get("baseColorFactor", [1, 1, 1, 1]), float)
        got = getattr(mat, "baseColorFactor", None)
        got = np.ones(4) if got is None else np.asarray(got, float) / (
            255.0 if np.asarray(got).dtype.kind in "ui" else 1.0)
        e_want = np.asarray(m.get("emissiveFactor", [0, 0, 0]), float)
        e_got = getattr(mat, "emissiveFactor", None)
        e_got = np.zeros(3) if e_got is None else np.asarray(e_got, float)[:3]
        sided = bool(m.get("doubleSided", False)) == bool(getattr(mat, "doubleSided", False))
        return float(np.abs(want - got).max() + np.abs(e_want - e_got).max()) + (0.0 if sided else 10.0)

    d = np.array([distance(i) for i in cands])
    tied = [cands[k] for k in np.nonzero(d <= d.min() + 1.0 / 255)[0]]
    if any(gltf[t] != gltf[tied[0]] for t in tied[1:]):
        raise SceneError(f"{fn}: glTF materials {', '.join(map(str, tied))} are all named "
                         f"'{name}' and differ by less than 1/255: give them distinct names")
    return tied[0]


#: The readers of this module, by file extension (merged in formats.load).
loaders = {".gltf": load_trimesh, ".glb": load_trimesh, ".ply": load_trimesh, ".stl": load_trimesh}
