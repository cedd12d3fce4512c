"""What tests share besides fixtures: paths, the scenes on disk, a preprocessed run, the
solved radiance, scenes written on the fly, and which external components are here."""

from __future__ import annotations

import functools
import os
import shutil
import textwrap

import numpy as np
from radiosity.settings import options as settings_of

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = os.path.join(ROOT, "scenes")
# the one place that says where headless Chromium is (viewer and dashboard tests)
CHROMIUM = os.environ.get("RADIOSITY_CHROMIUM", "/usr/bin/chromium")
IN_CI = os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")


@functools.lru_cache(maxsize=None)
def missing(component: str) -> str | None:
    """Why `component` cannot be used here (None: it can). Checked once per session: asking a
    Slurm that does not run takes `sinfo` about 9 s."""
    if component == "chromium":
        if os.path.isfile(CHROMIUM) and os.access(CHROMIUM, os.X_OK):
            return None
        return (f"headless Chromium not found at {CHROMIUM} (apt-get install chromium, or point "
                "RADIOSITY_CHROMIUM at it)")
    if component == "slurm":
        from radiosity.runtime.cluster import slurm_unavailable

        why = slurm_unavailable()
        if why is None:
            return None
        return f"Slurm is not running here: start it with bash deploy/slurm-up.sh ({why})"
    if component == "mitsuba":
        try:
            import mitsuba  # noqa: F401
        except ImportError as e:
            return f"mitsuba is not installed ({e}): pip install mitsuba"
        return None
    if component == "radiance":
        try:
            import pyradiance  # noqa: F401
        except ImportError as e:
            return f"pyradiance is not installed ({e}): pip install pyradiance"
        return None
    if component in ("sbatch", "squeue"):
        return None if shutil.which(component) else f"{component} is not on PATH"
    raise ValueError(f"unknown component {component!r}")


def stop_process(proc, wait_s: float) -> None:
    """Terminate a test's subprocess (a browser, a docs server); kill it if it outlives wait_s."""
    import subprocess

    proc.terminate()
    try:
        proc.wait(wait_s)
    except subprocess.TimeoutExpired:
        proc.kill()


def scene_path(name: str) -> str:
    return os.path.join(SCENES, name, "scene.toml")


def prepared(client, tmp_path, scene: str, res: int, name: str = "run", visibility: bool = True,
             **kw) -> str:
    """A run directory of `scene` (a TOML path) preprocessed at `res` (kw: preprocess options),
    with its one-ray visibility matrix unless `visibility` is False."""
    from radiosity.stages.preprocess import preprocess
    from radiosity.scene.load import load_scene
    from radiosity.methods.pairs.visibility import compute_visibility

    out = str(tmp_path / name)
    preprocess(load_scene(scene, resolution=res, settings=settings_of()), out, client,
               settings_of(**kw), progress=False)
    if visibility:
        compute_visibility(out, client, settings_of(), progress=False)
    return out


def radiance(out: str) -> np.ndarray:
    """The solved radiance (m, 2, 3) of a run directory."""
    from radiosity.runtime.store import RunStore

    return RunStore(out).read_arrays("solution")["radiance"]


def write_scene(tmp_path, obj: str, toml_extra: str = "", camera: str | None = None,
                mtl: str | None = None, name: str = "scene.toml") -> str:
    """Write an OBJ (and MTL) plus a scene TOML into tmp_path; return the TOML path."""
    (tmp_path / "mesh.obj").write_text(textwrap.dedent(obj))
    if mtl is not None:
        (tmp_path / "mesh.mtl").write_text(textwrap.dedent(mtl))
    if camera is None:
        camera = """
        [camera]
        position = [0.5, 2.0, -1.5]
        look_at = [0.5, 0.0, 0.5]
        up = [0.0, 1.0, 0.0]
        fov_y = 50.0
        resolution = [32, 24]
        """
    text = '[[mesh]]\npath = "mesh.obj"\n' + textwrap.dedent(toml_extra) + textwrap.dedent(camera)
    p = tmp_path / name
    p.write_text(text)
    return str(p)


FLOOR_AND_TRIANGLE = """
v 0 0 0
v 1 0 0
v 1 0 1
v 0 0 1
v 0 0.5 0.2
v 0.5 0.6 0.2
v 0.2 0.9 0.3
f 1 4 3 2
f 5 6 7
"""


def box_polygons(lo=(0.0, 0.0, 0.0), hi=(1.0, 1.0, 1.0), inward=True, faces=range(6)):
    """The faces of an axis-aligned box as quads (k, 4, 3), nverts (k,): normals into the box
    (inward) or out of it; faces: which of -x, +x, -y, +y, -z, +z."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    out = []
    for f in faces:
        ax, side = divmod(f, 2)
        u, v = [a for a in range(3) if a != ax]
        c = []
        for a, b in ((0, 0), (1, 0), (1, 1), (0, 1)):
            p = lo.copy()
            p[ax] = hi[ax] if side else lo[ax]
            p[u] = hi[u] if a else lo[u]
            p[v] = hi[v] if b else lo[v]
            c.append(p)
        q = np.array(c)
        n = np.cross(q[1] - q[0], q[2] - q[0])
        want = (-1.0 if side else 1.0) * (1.0 if inward else -1.0)  # inward: towards the middle
        if np.sign(n[ax]) != want:
            q = q[[0, 3, 2, 1]]
        out.append(q)
    return np.array(out), np.full(len(out), 4, np.int8)


# ----------------------------------------------------------------------------- a GLB room

ROOM = (4.0, 2.5, 3.0)  # the GLB room: x, y (up), z


def _quad(p0, u, v):
    import trimesh

    p0, u, v = (np.asarray(x, float) for x in (p0, u, v))
    return trimesh.Trimesh([p0, p0 + u, p0 + u + v, p0 + v], [[0, 1, 2], [0, 2, 3]], process=False)


def glb_room(emissive=(1.0, 1.0, 1.0), closed=True, strength=None, **lamp_material):
    """A GLB (bytes): a box room L x H x D = 4 x 2.5 x 3 (y up), normals inward, white walls and
    a red one (x = 0), without its z = 0 wall unless closed, and a lamp: a 1 x 1 quad just below
    the ceiling facing down, of emissiveFactor `emissive` (KHR strength `strength`), other
    PBRMaterial keywords in lamp_material (a texture: the lamp gets texture coordinates)."""
    import trimesh
    from trimesh.visual.material import PBRMaterial

    L, H, D = ROOM
    s = trimesh.Scene()
    walls = {"floor": _quad([0, 0, 0], [0, 0, D], [L, 0, 0]),
             "ceiling": _quad([0, H, 0], [L, 0, 0], [0, 0, D]),
             "back": _quad([0, 0, D], [0, H, 0], [L, 0, 0]),
             "left": _quad([0, 0, 0], [0, H, 0], [0, 0, D]),
             "right": _quad([L, 0, 0], [0, 0, D], [0, H, 0])}
    if closed:
        walls["front"] = _quad([0, 0, 0], [L, 0, 0], [0, H, 0])
    for k, m in walls.items():
        red = k == "left"
        m.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(
            name="red" if red else "white",
            baseColorFactor=[0.7, 0.1, 0.1, 1.0] if red else [0.7, 0.7, 0.7, 1.0]))
        s.add_geometry(m, node_name=k)
    lamp = _quad([1.5, H - 0.01, 1.0], [1.0, 0, 0], [0, 0, 1.0])
    uv = np.zeros((4, 2)) if lamp_material else None  # a texture is written with coordinates
    lamp.visual = trimesh.visual.TextureVisuals(uv=uv, material=PBRMaterial(
        name="lamp", baseColorFactor=[0.5, 0.5, 0.5, 1.0], emissiveFactor=list(emissive),
        **lamp_material))
    s.add_geometry(lamp, node_name="lamp")
    data = s.export(file_type="glb")
    if strength is not None:  # KHR_materials_emissive_strength, which trimesh does not write
        data = edit_glb(data, lambda doc: [m.setdefault("extensions", {}).update(
            KHR_materials_emissive_strength={"emissiveStrength": strength})
            for m in doc["materials"] if m.get("name") == "lamp"])
    return data


def edit_glb(data: bytes, edit) -> bytes:
    """The GLB with its JSON chunk edited in place (edit(doc) changes the dict)."""
    import json
    import struct

    n = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20:20 + n])
    edit(doc)
    body = json.dumps(doc).encode()
    body += b" " * (-len(body) % 4)
    rest = data[20 + n:]
    out = struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(body) + len(rest))
    return out + struct.pack("<I4s", len(body), b"JSON") + body + rest


def link_power_balance(run_dir: str) -> tuple[float, float, float]:
    """(emitted, absorbed, escaped) power of a solved hierarchical run, the escaped part from
    each leaf's total outgoing form factor summed directly from the stored links over its
    ancestors (not through the operator): they balance only if pull and push weigh by area
    consistently. With the emitters' light at points (the solution's attrs say direct: points)
    the leaves hold R = L1 + rho K R and what the leaves emit is the first bounce L1, the
    solve's right-hand side (the method's open)."""
    import numpy as np

    from radiosity.methods.hierarchical.solve.leaves import leaf_vectors
    from radiosity.methods.hierarchical.solve.transport import open_link_operator, task_link_arrays
    from radiosity.runtime.store import RunStore

    rs = RunStore(run_dir)
    op, table, el, _ = open_link_operator(rs, None, "auto", settings_of())
    Le, rho, A = leaf_vectors(table, el)
    if rs.group_attrs("solution").get("direct") == "points":
        from radiosity.methods.hierarchical.method import HIERARCHICAL

        Le = HIERARCHICAL.open(rs, None, settings_of(direct="points")).Le
    L = np.transpose(rs.read_arrays("solution")["leaf_radiance"], (1, 2, 0))
    H = op.apply(L)
    # independently: sum of F v over the links of each node, per side, then down the tree
    N = len(table["orig"])
    R = np.zeros((2, N))
    for t in range(len(op.inp.entries)):
        p, q, wpq, wqp, sp, sq, _ = task_link_arrays(op.inp, t)
        np.add.at(R, (sp, p), wpq)
        np.add.at(R, (sq, q), wqp)
    for i in range(N):
        if table["parent"][i] >= 0:
            R[:, i] += R[:, table["parent"][i]]
    R = R[:, table["leaf_node"]][:, None, :]
    emitted = np.pi * np.sum(A * Le)
    absorbed = np.pi * np.sum(A * (1 - rho) * H)
    escaped = np.pi * np.sum(A * L * (1 - R))
    return float(emitted), float(absorbed), float(escaped)


def per_surface(img, ref, orig, min_pixels: int = 40) -> dict:
    """Relative difference of two images summed over each original's pixels (orig: the raster
    of originals), for originals covering at least min_pixels: {original: img / ref - 1}."""
    import numpy as np

    out = {}
    for o in np.unique(orig[orig >= 0]):
        m = orig == o
        if m.sum() >= min_pixels:
            out[int(o)] = float(img[m].sum() / ref[m].sum() - 1)
    return out
