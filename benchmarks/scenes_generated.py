"""Scenes of many small triangles, generated (bench_clusters.py, bench_real.py): a terrain lit by
a rectangular light, smooth or rough, a room with a finely tessellated sphere, the Cornell box
with every quad cut into triangles. Each writer puts an OBJ and a scene TOML into a folder and returns the TOML path."""

from __future__ import annotations

import os

import numpy as np
from radiosity.settings import options as settings_of


def _write(folder: str, name: str, tris_by_material: dict, camera: dict, materials: str) -> str:
    os.makedirs(folder, exist_ok=True)
    obj = os.path.join(folder, f"{name}.obj")
    with open(obj, "w") as f:
        k = 1
        for mat, tris in tris_by_material.items():
            f.write(f"usemtl {mat}\n")
            v = np.asarray(tris, np.float64).reshape(-1, 3)
            np.savetxt(f, v, fmt="v %.9g %.9g %.9g")
            n = len(tris)
            nv = len(tris[0]) if n else 3
            idx = k + np.arange(n * nv).reshape(n, nv)
            np.savetxt(f, idx, fmt="f" + " %d" * nv)
            k += n * nv
    cam = "\n".join(f"{key} = {val}" for key, val in camera.items())
    toml = os.path.join(folder, "scene.toml")
    with open(toml, "w") as f:
        f.write(f'name = "{name}"\n[[mesh]]\npath = "{name}.obj"\n{materials}\n[camera]\n{cam}\n')
    return toml


def _grid_tris(nx: int, ny: int, height, size: float = 1.0):
    """2 nx ny triangles of the height field z = height(x, y) over [0, size]^2, facing up."""
    x = np.linspace(0, size, nx + 1)
    y = np.linspace(0, size, ny + 1)
    X, Y = np.meshgrid(x, y, indexing="ij")
    P = np.stack([X, Y, height(X, Y)], -1)
    a, b, c, d = P[:-1, :-1], P[1:, :-1], P[1:, 1:], P[:-1, 1:]
    t1 = np.stack([a, b, c], -2).reshape(-1, 3, 3)
    t2 = np.stack([a, c, d], -2).reshape(-1, 3, 3)
    return np.concatenate([t1, t2])


def terrain(folder: str, triangles: int, resolution: int = 128, rough: float = 0.0,
            seed: int = 0) -> str:
    """A rolling terrain of about `triangles` triangles, 10 x 10 units, lit by a 2 x 2 light
    4 units above its centre facing down; the camera looks at it from a corner above.

    `rough` > 0: every vertex's height gets independent normal noise of standard deviation
    `rough` grid spacings (seeded), as photogrammetry and LiDAR meshes have: at 1.5 the noise is
    larger than the grid spacing, so neighbouring triangles face every way and no two clusters
    of it are flat."""
    n = max(2, int(round(np.sqrt(triangles / 2))))
    noise = None
    if rough > 0:
        noise = np.random.default_rng(seed).normal(0.0, rough * 10.0 / n, (n + 1, n + 1))

    def h(X, Y):
        z = 0.6 * np.sin(0.9 * X) * np.cos(0.7 * Y) + 0.25 * np.sin(2.3 * X + 1.1 * Y)
        return z if noise is None else z + noise

    ground = _grid_tris(n, n, h, 10.0)
    L = [(4.0, 4.0, 4.0), (4.0, 6.0, 4.0), (6.0, 6.0, 4.0), (6.0, 4.0, 4.0)]  # facing down
    camera = {"position": "[-3.0, -3.0, 6.0]", "look_at": "[5.0, 5.0, 0.0]",
              "up": "[0.0, 0.0, 1.0]", "fov_y": 50.0,
              "resolution": f"[{resolution}, {resolution}]"}
    materials = ("[material.ground]\nreflectance = [0.5, 0.45, 0.4]\n"
                 "[material.light]\nreflectance = [0.0, 0.0, 0.0]\nemission = [30.0, 30.0, 30.0]\n")
    return _write(folder, "terrain", {"ground": ground, "light": [L]}, camera, materials)


def sphere_tris(n_theta: int, n_phi: int, centre, radius: float, inward: bool = False):
    th = np.linspace(0, np.pi, n_theta + 1)
    ph = np.linspace(0, 2 * np.pi, n_phi + 1)
    P = radius * np.stack([np.sin(th)[:, None] * np.cos(ph)[None, :],
                           np.sin(th)[:, None] * np.sin(ph)[None, :],
                           np.cos(th)[:, None] * np.ones_like(ph)[None, :]], -1) + centre
    out = []
    for i in range(n_theta):
        a, b, c, d = P[i, :-1], P[i + 1, :-1], P[i + 1, 1:], P[i, 1:]
        if i > 0:
            out.append(np.stack([a, b, d], 1))
        if i < n_theta - 1:
            out.append(np.stack([b, c, d], 1))
    t = np.concatenate(out)
    return t[:, [0, 2, 1]] if inward else t


def room_with_sphere(folder: str, triangles: int, resolution: int = 128) -> str:
    """A 4 x 3 x 4 room (quads, facing in), a ceiling light, and a sphere of about `triangles`
    triangles on the floor."""
    W, H, D = 4.0, 3.0, 4.0
    walls = [[(0, 0, 0), (W, 0, 0), (W, 0, D), (0, 0, D)][::-1],            # floor, up
             [(0, H, 0), (0, H, D), (W, H, D), (W, H, 0)][::-1],            # ceiling, down
             [(0, 0, D), (W, 0, D), (W, H, D), (0, H, D)][::-1],            # back, -z
             [(0, 0, 0), (0, H, 0), (W, H, 0), (W, 0, 0)][::-1],            # front, +z
             [(0, 0, 0), (0, 0, D), (0, H, D), (0, H, 0)][::-1],            # left, +x
             [(W, 0, 0), (W, H, 0), (W, H, D), (W, 0, D)][::-1]]            # right, -x
    n_phi = max(8, int(round(np.sqrt(triangles))))
    n_theta = max(4, n_phi // 2)
    ball = sphere_tris(n_theta, n_phi, np.array([2.0, 0.8, 2.0]), 0.8)
    light = [(1.5, H - 1e-3, 1.5), (2.5, H - 1e-3, 1.5), (2.5, H - 1e-3, 2.5), (1.5, H - 1e-3, 2.5)]
    camera = {"position": "[2.0, 1.5, 0.2]", "look_at": "[2.0, 1.0, 3.0]", "up": "[0.0, 1.0, 0.0]",
              "fov_y": 60.0, "resolution": f"[{resolution}, {resolution}]"}
    materials = ("[material.wall]\nreflectance = [0.7, 0.7, 0.7]\n"
                 "[material.ball]\nreflectance = [0.6, 0.3, 0.2]\n"
                 "[material.light]\nreflectance = [0.0, 0.0, 0.0]\nemission = [20.0, 20.0, 20.0]\n")
    return _write(folder, "room-sphere", {"wall": walls, "ball": ball, "light": [light]},  # down
                  camera, materials)


def tessellated_cornell(folder: str, per_quad: int = 2000, resolution: int = 128) -> str:
    """The built-in Cornell box with every face cut into about `per_quad` triangles (a quad: a
    k x k grid of cells, four triangles each around a point near the cell's centre; a triangle,
    as the red wall's two: a barycentric grid, three triangles a cell; no two of them form a
    parallelogram, so the loader keeps them as triangles), same materials and camera."""
    import shutil

    from radiosity.scene.load import load_scene

    src = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scenes",
                       "cornell-box", "scene.toml")
    sc = load_scene(src, settings=settings_of())
    el = sc.elements
    k = max(1, int(round(np.sqrt(per_quad / 4))))
    by_mat: dict = {}
    for v, nv, m in zip(el.verts, el.nverts, el.material):
        name = el.material_names[m]
        tris = []
        if nv == 4:
            p0, p1, p2, p3 = v
            u = np.linspace(0, 1, k + 1)
            for i in range(k):
                for j in range(k):
                    def at(a, b):
                        return (1 - a) * (1 - b) * p0 + a * (1 - b) * p1 + a * b * p2 + (1 - a) * b * p3
                    # off the cell's centre: two triangles of neighbouring cells that share a
                    # cell edge then form no parallelogram either
                    c = at(u[i] + 0.43 * (u[i + 1] - u[i]), u[j] + 0.47 * (u[j + 1] - u[j]))
                    q = [at(u[i], u[j]), at(u[i + 1], u[j]), at(u[i + 1], u[j + 1]), at(u[i], u[j + 1])]
                    tris += [(c, q[s], q[(s + 1) % 4]) for s in range(4)]
        else:  # a triangle (the red wall is two): about per_quad / 2 triangles, a k x k
            # barycentric grid of cells, each cut into three around a point off its centre
            p0, p1, p2 = v[:3]
            kt = max(1, int(round(np.sqrt(per_quad / 6))))

            def bary(a, b):
                return p0 + (a / kt) * (p1 - p0) + (b / kt) * (p2 - p0)
            for i in range(kt):
                for j in range(kt - i):
                    cells = [(bary(i, j), bary(i + 1, j), bary(i, j + 1))]
                    if i + j + 1 < kt:
                        cells.append((bary(i + 1, j), bary(i + 1, j + 1), bary(i, j + 1)))
                    for a, b, c in cells:
                        m = 0.30 * a + 0.33 * b + 0.37 * c
                        tris += [(m, a, b), (m, b, c), (m, c, a)]
        by_mat.setdefault(name, []).extend(tris)
    os.makedirs(folder, exist_ok=True)
    toml = open(src).read()
    mesh_line = toml[toml.index("[[mesh]]"):].split("\n")[1]
    toml = toml.replace(mesh_line, 'path = "cornell-tess.obj"')
    toml = toml.replace("resolution = [128, 128]", f"resolution = [{resolution}, {resolution}]")
    _write(folder, "cornell-tess", by_mat, {}, "")  # writes the OBJ (the TOML is replaced)
    obj = os.path.join(folder, "cornell-tess.obj")
    with open(obj) as f:
        body = f.read()
    with open(obj, "w") as f:
        f.write("mtllib cornell-box.mtl\n" + body)
    with open(os.path.join(folder, "scene.toml"), "w") as f:
        f.write(toml)
    for ext in (".mtl",):
        m = src.replace("scene.toml", "cornell-box" + ext)
        if os.path.exists(m):
            shutil.copy(m, os.path.join(folder, "cornell-box" + ext))
    return os.path.join(folder, "scene.toml")
