"""Convert a Mitsuba scene (XML version 0.6 or 3, as Benedikt Bitterli's rendering resources
publish them) into this project's scene format, all diffuse: one OBJ (`usemtl` per material)
and a scene.toml with the materials, their emission and the source's camera.

    python benchmarks/real/convert.py SRC/scene.xml OUT_DIR --name NAME [--drop ID,...]
    python benchmarks/real/convert.py --all   # the suite's scenes, from the fetched mirrors

The conversion (what a diffuse radiosity engine can represent; README.md says it per scene):
- every BSDF becomes a diffuse reflectance: `diffuse` its reflectance; `plastic`,
  `roughplastic` their diffuse reflectance; `principled` its base colour; conductors half
  their specular reflectance (a grey metal); a bitmap texture its mean linear colour (8-bit
  images are sRGB-encoded, as Mitsuba reads them), a checkerboard the mean of its colours;
  `twosided` makes the material two-sided, `mask` and `bumpmap` take the BSDF they wrap;
- dielectrics (glass, water) are transparent in the source: their shapes are dropped, or a
  window pane would block the light behind it;
- area emitters keep their radiance, on the shape's front side (one-sided, as in Mitsuba);
- shapes: OBJ and PLY meshes, `rectangle` (a quad), `disk` (a 32-gon fan), `cube` and
  `sphere` (tessellated), all with their to_world transform applied; shapegroups and
  instances are unrolled;
- the camera: the sensor's position, viewing direction, up and field of view (Mitsuba's
  `fov` is along x by default; the benchmark's image is square, so it is the same along y).
"""

from __future__ import annotations

import argparse
import io
import math
import os
import re
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
MIRRORS = os.environ.get("RADIOSITY_MIRRORS", "/work/.mirror")

NIKLAS = ("niklassanden/ReSTIR_GI_DR", "4e71bd940e50f0e0f408206f1ea368cd9dfb6325")
DPPM = ("hchoi405/dppm-scenes", "8fdb2dcb3fe575bb04bc586fded35e81d76787d5")

#: The suite: folder -> (GitHub repository mirrored under MIRRORS, its commit, the scene XML
#: in it, shape ids or mesh file names to drop, the scene's triangle budget or None). Each
#: source is a copy of a Bitterli scene (its LICENSE.txt says which; README.md here gives the
#: attribution). The budget decimates the meshes of DECIMATE_FROM triangles or more
#: (quadric error metric, fast-simplification) by one common ratio so that the scene holds
#: about that many triangles.
SUITE = {
    "modern-hall": (*NIKLAS, "scenes/staircase2/scene.xml", (), None),
    # a radiator's panels (Mesh130) are missing from every mirror found: dropped
    "white-room": (*NIKLAS, "scenes/living-room-2/scene.xml", ("Mesh130.obj",), 80_000),
    "wooden-staircase": (*DPPM, "scenes/staircase/scene.xml", (), 70_000),
    # the teapots (Mesh000, Mesh009) are missing from every mirror found: dropped
    "veach-ajar": (*NIKLAS, "scenes/veach-ajar/scene.xml",
                   ("Pot2_0001", "Pot2_0002", "Pot3_0001", "Pot3_0002", "Material_0001",
                    "Material_0002"), None),
}
#: a mesh of fewer triangles is never decimated
DECIMATE_FROM = 200

#: no real diffuse surface reflects more (white paint about 0.9); a source of 1 would make a
#: closed room never lose light
MAX_REFLECTANCE = 0.95

TRANSPARENT = {"dielectric", "thindielectric", "roughdielectric", "null"}


def _snake(name: str) -> str:
    """Mitsuba 0.6's camelCase names (toWorld, diffuseReflectance) as version 3's."""
    return re.sub(r"(?<=[a-z0-9])([A-Z])", lambda m: "_" + m.group(1).lower(), name)


def _floats(s: str) -> list[float]:
    return [float(x) for x in re.split(r"[,\s]+", s.strip()) if x]


def srgb_to_linear(c):
    c = np.asarray(c, float)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


class Source:
    """The scene XML and the files beside it: a folder, or a path inside a git mirror (read
    with `git show`, the mirrors being bare repositories)."""

    def __init__(self, xml_path: str, git_dir: str | None = None, commit: str = "HEAD"):
        self.xml_path, self.git_dir, self.commit = xml_path, git_dir, commit
        self.base = os.path.dirname(xml_path)

    def read(self, rel: str) -> bytes:
        path = os.path.normpath(os.path.join(self.base, rel))
        if self.git_dir is None:
            with open(path, "rb") as f:
                return f.read()
        r = subprocess.run(["git", "--git-dir", self.git_dir, "show", f"{self.commit}:{path}"],
                           capture_output=True)
        if r.returncode:
            raise FileNotFoundError(f"{path} is not in {self.git_dir}")
        return r.stdout

    def root(self):
        return ET.fromstring(self.read(os.path.basename(self.xml_path)))


# ----------------------------------------------------------------------------- transforms

def _rotation(axis, angle_deg):
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    t = math.radians(angle_deg)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    R = np.eye(3) + math.sin(t) * K + (1 - math.cos(t)) * K @ K
    M = np.eye(4)
    M[:3, :3] = R
    return M


def _xyz(el, default):
    if "value" in el.attrib:
        v = _floats(el.get("value"))
        return v * 3 if len(v) == 1 else v
    return [float(el.get(k, default)) for k in "xyz"]


def transform(el, subst) -> np.ndarray:
    """(4, 4) matrix of a <transform>: each child applied after the ones before it."""
    M = np.eye(4)
    for op in el:
        tag = op.tag
        if tag == "matrix":
            T = np.array(_floats(subst(op.get("value"))), float).reshape(4, 4)
        elif tag == "translate":
            T = np.eye(4)
            T[:3, 3] = _xyz(op, 0.0)
        elif tag == "scale":
            T = np.diag([*_xyz(op, 1.0), 1.0])
        elif tag == "rotate":
            T = _rotation(_xyz(op, 0.0), float(op.get("angle")))
        elif tag == "lookat" or tag == "lookAt":
            o = np.array(_floats(op.get("origin")))
            t = np.array(_floats(op.get("target")))
            up = np.array(_floats(op.get("up", "0 1 0")))
            z = (t - o) / np.linalg.norm(t - o)
            x = np.cross(up, z)
            x /= np.linalg.norm(x)
            y = np.cross(z, x)
            T = np.eye(4)
            T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, o
        else:
            raise ValueError(f"transform {tag!r} is not supported")
        M = T @ M
    return M


# ----------------------------------------------------------------------------- materials

class Materials:
    """BSDFs as diffuse materials: {name: {"reflectance", "two_sided", "emission"}}."""

    def __init__(self, src: Source, subst):
        self.src, self.subst = src, subst
        self.defs: dict = {}       # id -> <bsdf> element
        self.mats: dict = {}       # material name -> properties
        self._by_key: dict = {}
        self._tex: dict = {}

    def colour(self, el) -> np.ndarray:
        """Linear RGB (3,) of a spectrum-valued child (<rgb>, <srgb>, <spectrum>, <float>,
        <texture>)."""
        tag = el.tag
        if tag in ("rgb", "color"):
            v = _floats(self.subst(el.get("value")))
            return np.array(v * 3 if len(v) == 1 else v[:3])
        if tag == "srgb":
            v = el.get("value").strip()
            if v.startswith("#"):
                v = [int(v[i:i + 2], 16) / 255 for i in (1, 3, 5)]
            else:
                v = _floats(v)
            return srgb_to_linear(v * 3 if len(v) == 1 else v[:3])
        if tag in ("spectrum", "float"):
            v = _floats(self.subst(el.get("value")))
            return np.full(3, float(np.mean(v)))
        if tag == "texture":
            return self.texture(el)
        if tag == "ref":
            raise ValueError("a texture by reference is not supported")
        raise ValueError(f"colour <{tag}> is not supported")

    def texture(self, el) -> np.ndarray:
        kind = el.get("type")
        if kind == "bitmap":
            fn = next(c.get("value") for c in el if c.get("name") == "filename")
            raw = any(c.get("name") == "raw" and c.get("value") == "true" for c in el)
            if fn not in self._tex:
                from PIL import Image

                im = Image.open(io.BytesIO(self.src.read(fn)))
                if im.mode in ("F", "I", "I;16"):
                    px = np.asarray(im.convert("F"), float).reshape(-1, 1).repeat(3, 1)
                    lin = px
                else:
                    im = im.convert("RGB")
                    im.thumbnail((256, 256))
                    px = np.asarray(im, float).reshape(-1, 3) / 255.0
                    lin = px if raw else srgb_to_linear(px)
                self._tex[fn] = lin.mean(axis=0)
            return self._tex[fn]
        if kind == "checkerboard":
            cols = {c.get("name"): self.colour(c) for c in el if c.get("name") in ("color0", "color1")}
            return 0.5 * (cols.get("color0", np.full(3, 0.4)) + cols.get("color1", np.full(3, 0.2)))
        raise ValueError(f"texture {kind!r} is not supported")

    def _param(self, el, names, default):
        for c in el:
            if _snake(c.get("name", "")) in names:
                return self.colour(c)
        return np.full(3, default)

    def diffuse(self, el):
        """(reflectance (3,), two_sided, transparent) of a <bsdf>."""
        if el.tag == "ref":
            el = self.defs[el.get("id")]
        kind = el.get("type")
        nested = [c for c in el if c.tag in ("bsdf", "ref")]
        if kind == "twosided":
            rho, _, tr = self.diffuse(nested[0])
            return rho, True, tr
        if kind in ("mask", "bumpmap", "normalmap", "coating", "roughcoating"):
            return self.diffuse(nested[0])
        if kind == "blendbsdf":
            (a, ta, _), (b, tb, _) = self.diffuse(nested[0]), self.diffuse(nested[1])
            return 0.5 * (a + b), ta or tb, False
        if kind in TRANSPARENT:
            return np.zeros(3), False, True
        if kind in ("diffuse", "roughdiffuse"):
            return self._param(el, ("reflectance",), 0.5), False, False
        if kind in ("plastic", "roughplastic"):
            return self._param(el, ("diffuse_reflectance",), 0.5), False, False
        if kind == "principled":
            return self._param(el, ("base_color",), 0.5), False, False
        if kind in ("conductor", "roughconductor"):
            return 0.5 * self._param(el, ("specular_reflectance",), 1.0), False, False
        raise ValueError(f"BSDF {kind!r} is not supported")

    def material(self, bsdf_el, emission, hint: str) -> str | None:
        """The material name of a shape with this BSDF (None: transparent, drop the shape)."""
        if bsdf_el is None:
            rho, two, tr = np.full(3, 0.5), False, False
            bid = "default"
        else:
            rho, two, tr = self.diffuse(bsdf_el)
            bid = bsdf_el.get("id") or hint
        if tr and emission is None:
            return None
        rho = np.clip(rho, 0.0, MAX_REFLECTANCE)
        if emission is not None:
            two = False  # Mitsuba's area emitter is one-sided
        key = (tuple(np.round(rho, 6)), two, None if emission is None else tuple(emission))
        if key in self._by_key:
            return self._by_key[key]
        base = re.sub(r"[^A-Za-z0-9_-]+", "-", bid if emission is None else "light").strip("-") or "m"
        name, k = base, 1
        while name in self.mats:
            k += 1
            name = f"{base}-{k}"
        self.mats[name] = {"reflectance": rho, "two_sided": two, "emission": emission}
        self._by_key[key] = name
        return name


# ----------------------------------------------------------------------------- shapes

def _mesh(src: Source, kind: str, fn: str):
    import trimesh

    data = src.read(fn)
    m = trimesh.load(io.BytesIO(data), file_type=kind, process=False, force="mesh")
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def _analytic(kind: str, el, subst):
    """Vertices and faces of a rectangle, disk, cube or sphere in its own frame."""
    if kind == "rectangle":
        return np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float), [[0, 1, 2, 3]]
    if kind == "disk":
        n = 32
        t = 2 * np.pi * np.arange(n) / n
        v = np.concatenate([[[0, 0, 0]], np.stack([np.cos(t), np.sin(t), 0 * t], 1)])
        return v, [[0, 1 + i, 1 + (i + 1) % n] for i in range(n)]
    if kind == "cube":
        v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
        quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
        return v, quads
    if kind == "sphere":
        c, r = np.zeros(3), 1.0
        for ch in el:
            if ch.get("name") == "center":
                c = np.array(_xyz(ch, 0.0))
            if ch.get("name") == "radius":
                r = float(subst(ch.get("value")))
        sys.path.insert(0, os.path.dirname(HERE))
        from scenes_generated import sphere_tris

        tris = sphere_tris(16, 32, c, r).reshape(-1, 3)
        return tris, np.arange(len(tris)).reshape(-1, 3).tolist()
    raise ValueError(f"shape {kind!r} is not supported")


def decimate(by_mat: dict, budget: int) -> None:
    """Decimate, in place, the meshes of DECIMATE_FROM triangles or more by one ratio so that
    the scene holds about `budget` triangles (quads count two)."""
    import fast_simplification

    def ntri(f):
        return sum(len(x) - 2 for x in f)

    parts = [(m, k) for m, ps in by_mat.items() for k in range(len(ps))]
    sizes = {p: ntri(by_mat[p[0]][p[1]][1]) for p in parts}
    big = [p for p in parts if sizes[p] >= DECIMATE_FROM]
    small = sum(n for p, n in sizes.items() if p not in big)
    big_total = sum(sizes[p] for p in big)
    if small + big_total <= budget or not big_total:
        return
    keep = max(0.02, (budget - small) / big_total)
    for m, k in big:
        v, f = by_mat[m][k]
        f = np.asarray([x for x in f if len(x) == 3], np.int64)  # meshes hold triangles only
        v2, f2 = fast_simplification.simplify(np.asarray(v, np.float32), f, target_reduction=1 - keep)
        by_mat[m][k] = (np.asarray(v2, float), np.asarray(f2, np.int64).tolist())


def convert(src: Source, out: str, name: str, drop=(), budget: int | None = None,
            resolution: int = 128) -> dict:
    """Write OUT/NAME.obj and OUT/scene.toml from the source scene (decimated to about
    `budget` triangles when one is given). Returns counts."""
    root = src.root()
    defaults = {d.get("name"): d.get("value") for d in root.iter("default")}

    def subst(s):
        return re.sub(r"\$(\w+)", lambda m: defaults.get(m.group(1), m.group(0)), s)

    mats = Materials(src, subst)
    for el in root:
        if el.tag == "bsdf" and el.get("id"):
            mats.defs[el.get("id")] = el
    groups = {el.get("id"): el for el in root.iter("shape") if el.get("type") == "shapegroup"}
    by_mat: dict = {}
    counts = {"shapes": 0, "dropped_transparent": [], "dropped": []}

    def add_shape(el, parent=np.eye(4)):
        kind = el.get("type")
        sid = el.get("id") or ""
        if kind == "shapegroup":
            return
        M = parent
        for ch in el:
            if ch.tag == "transform" and _snake(ch.get("name", "")) == "to_world":
                M = parent @ transform(ch, subst)
        if kind == "instance":
            ref = next(c for c in el if c.tag == "ref")
            for s in groups[ref.get("id")]:
                if s.tag == "shape":
                    add_shape(s, M)
            return
        fn = next((c.get("value") for c in el if c.get("name") == "filename"), None)
        if sid in drop or (fn and os.path.basename(fn) in drop):
            counts["dropped"].append(sid or os.path.basename(fn))
            return
        bsdf = next((c for c in el if c.tag == "bsdf" or (c.tag == "ref" and c.get("id") in mats.defs)), None)
        em = next((c for c in el if c.tag == "emitter"), None)
        emission = None
        if em is not None:
            rad = next(c for c in em if c.get("name") == "radiance")
            emission = tuple(float(x) for x in mats.colour(rad))
        mname = mats.material(bsdf, emission, sid or kind)
        if mname is None:
            counts["dropped_transparent"].append(sid or (os.path.basename(fn) if fn else kind))
            return
        if kind in ("obj", "ply"):
            v, f = _mesh(src, kind, subst(fn))
        else:
            v, f = _analytic(kind, el, subst)
        vw = (np.c_[v, np.ones(len(v))] @ M.T)[:, :3]
        if kind in ("rectangle", "disk", "cube") and np.linalg.det(M[:3, :3]) < 0:
            f = [face[::-1] for face in f]  # keep the front side along the transformed +z
        by_mat.setdefault(mname, []).append((vw, f))
        counts["shapes"] += 1

    for el in root:
        if el.tag == "shape":
            add_shape(el)
    counts["source_triangles"] = sum(len(x) - 2 for ps in by_mat.values() for _, f in ps for x in f)
    if budget:
        decimate(by_mat, budget)
    cam = _camera(root, subst)
    os.makedirs(out, exist_ok=True)
    tris, slivers = _write_obj(os.path.join(out, f"{name}.obj"), by_mat)
    _write_toml(os.path.join(out, "scene.toml"), name, mats.mats, cam, resolution)
    counts.update(triangles=tris, slivers_dropped=slivers, materials=len(mats.mats),
                  lights=sum(1 for m in mats.mats.values() if m["emission"] is not None))
    return counts


def _camera(root, subst) -> dict:
    s = next(root.iter("sensor"))
    fov, axis, M = None, "x", np.eye(4)
    for ch in s:
        n = _snake(ch.get("name", ""))
        if n == "fov":
            fov = float(subst(ch.get("value")))
        elif n == "fov_axis":
            axis = ch.get("value")
        elif ch.tag == "transform" and n == "to_world":
            M = transform(ch, subst)
    if axis not in ("x", "y", "smaller", "larger"):
        raise ValueError(f"fov_axis {axis!r} is not supported")
    z = M[:3, 2] / np.linalg.norm(M[:3, 2])
    y = M[:3, 1] / np.linalg.norm(M[:3, 1])
    return {"position": M[:3, 3], "look_at": M[:3, 3] + z, "up": y, "fov_y": fov}


def _round7(v: np.ndarray) -> np.ndarray:
    """`v` rounded to 7 significant digits, as the OBJ writes it."""
    v = np.asarray(v, float)
    with np.errstate(divide="ignore"):
        e = np.where(v == 0, 0.0, np.floor(np.log10(np.abs(np.where(v == 0, 1.0, v)))) - 6)
    return np.round(v / 10.0 ** e) * 10.0 ** e


def _slivers(v: np.ndarray, faces) -> np.ndarray:
    """(F,) bool: faces of (nearly) no area, area <= 1e-9 of their longest edge squared (the
    loader refuses those of no area; decimation and 7 digits make some)."""
    out = np.zeros(len(faces), bool)
    for k, f in enumerate(faces):
        p = v[np.asarray(f)]
        area = 0.5 * sum(np.linalg.norm(np.cross(p[i] - p[0], p[i + 1] - p[0])) for i in range(1, len(f) - 1))
        edge = max(np.sum((p[i] - p[i - 1]) ** 2) for i in range(len(f)))
        out[k] = not area > 1e-9 * edge
    return out


def _write_obj(fn: str, by_mat: dict) -> tuple[int, int]:
    """One OBJ, the faces grouped by material (`usemtl`), faces of no area left out; returns
    (triangles written (a quad counts two), faces left out)."""
    tris = dropped = 0
    with open(fn, "w") as f:
        f.write("# converted by benchmarks/real/convert.py; materials in scene.toml\n")
        base = 1
        for mname, parts in by_mat.items():
            f.write(f"usemtl {mname}\n")
            for v, faces in parts:
                v = _round7(v)
                bad = _slivers(v, faces)
                dropped += int(bad.sum())
                np.savetxt(f, v, fmt="v %.7g %.7g %.7g")
                for face, b in zip(faces, bad):
                    if b:
                        continue
                    f.write("f " + " ".join(str(base + int(i)) for i in face) + "\n")
                    tris += len(face) - 2
                base += len(v)
    return tris, dropped


def _vec(v) -> str:
    return "[" + ", ".join(f"{float(x):.7g}" for x in v) + "]"


def _write_toml(fn: str, name: str, mats: dict, cam: dict, resolution: int) -> None:
    lines = [f'name = "{name}"', "# converted by benchmarks/real/convert.py: see README.md", "",
             "[[mesh]]", f'path = "{name}.obj"', ""]
    for m, p in mats.items():
        lines.append(f"[material.{m}]")
        lines.append(f"reflectance = {_vec(p['reflectance'])}")
        if p["emission"] is not None:
            lines.append(f"emission = {_vec(p['emission'])}")
        lines.append(f"two_sided = {'true' if p['two_sided'] else 'false'}")
        lines.append("")
    lines += ["[camera]", f"position = {_vec(cam['position'])}", f"look_at = {_vec(cam['look_at'])}",
              f"up = {_vec(cam['up'])}", f"fov_y = {cam['fov_y']:.6g}",
              f"resolution = [{resolution}, {resolution}]", ""]
    with open(fn, "w") as f:
        f.write("\n".join(lines))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("xml", nargs="?", help="the Mitsuba scene XML (its meshes beside it)")
    ap.add_argument("out", nargs="?")
    ap.add_argument("--name")
    ap.add_argument("--drop", default="", help="shape ids to leave out, comma-separated")
    ap.add_argument("--all", action="store_true", help="convert the suite from the mirrors")
    args = ap.parse_args()
    if args.all:
        for folder, (repo, commit, xml, drop, budget) in SUITE.items():
            git_dir = os.path.join(MIRRORS, repo.replace("/", "+"), "repo")
            c = convert(Source(xml, git_dir, commit), os.path.join(HERE, folder), folder, drop, budget)
            print(folder, c)
        return
    if not (args.xml and args.out and args.name):
        ap.error("give XML OUT --name NAME, or --all")
    print(convert(Source(args.xml), args.out, args.name, [d for d in args.drop.split(",") if d]))


if __name__ == "__main__":
    main()
