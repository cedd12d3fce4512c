"""Writes the CIE 171:2006-style validation scenes of this folder (issue 52): rooms of quads,
normals into the room, as OBJ + scene.toml. Run: python3 scenes/cie171/make_scenes.py."""

import os

HERE = os.path.dirname(os.path.abspath(__file__))


def quad(p, u, v):
    """The quad p, p + u, p + u + v, p + v (front normal u x v)."""
    a = tuple(p)
    b = tuple(p[i] + u[i] for i in range(3))
    c = tuple(p[i] + u[i] + v[i] for i in range(3))
    d = tuple(p[i] + v[i] for i in range(3))
    return (a, b, c, d)


def ceiling_ring(W, D, H, x0, x1, y0, y1):
    """The ceiling z = H (normal -z) less the rectangle [x0, x1] x [y0, y1]: four quads."""
    out = []
    for (a, b, c, d) in ((0, W, 0, y0), (0, W, y1, D), (0, x0, y0, y1), (x1, W, y0, y1)):
        if b > a and d > c:
            out.append(quad((a, c, H), (0, d - c, 0), (b - a, 0, 0)))
    return out


def room(W, D, H, emitter, floor_split=None):
    """Quads of a closed box [0, W] x [0, D] x [0, H], normals inwards, and the ceiling's
    emitter rectangle emitter = (x0, x1, y0, y1): {material: [quads]}."""
    x0, x1, y0, y1 = emitter
    return {
        "floor": [quad((0, 0, 0), (W, 0, 0), (0, D, 0))],
        "ceiling": ceiling_ring(W, D, H, x0, x1, y0, y1),
        "walls": [quad((0, 0, 0), (0, 0, H), (W, 0, 0)),          # y = 0, normal +y
                  quad((0, D, 0), (W, 0, 0), (0, 0, H)),          # y = D, normal -y
                  quad((0, 0, 0), (0, D, 0), (0, 0, H)),          # x = 0, normal +x
                  quad((W, 0, 0), (0, 0, H), (0, D, 0))],         # x = W, normal -x
        "emitter": [quad((x0, y0, H), (0, y1 - y0, 0), (x1 - x0, 0, 0))],
    }


def write(name, groups, toml):
    d = os.path.join(HERE, name)
    os.makedirs(d, exist_ok=True)
    lines = [f"# {name}: written by make_scenes.py", f"mtllib {name}.mtl"]
    faces, vs = [], []
    for mat, quads in groups.items():
        faces.append(f"usemtl {mat}")
        for q in quads:
            idx = []
            for p in q:
                vs.append("v " + " ".join(f"{x:g}" for x in p))
                idx.append(str(len(vs)))
            faces.append("f " + " ".join(idx))
    with open(os.path.join(d, f"{name}.obj"), "w") as f:
        f.write("\n".join(lines + vs + faces) + "\n")
    with open(os.path.join(d, f"{name}.mtl"), "w") as f:
        for mat in groups:
            f.write(f"newmtl {mat}\nKd 0 0 0\n\n")
    with open(os.path.join(d, "scene.toml"), "w") as f:
        f.write(toml.replace("OBJ", f"{name}.obj"))


CAMERA = """
[camera]
position = [0.2, 0.2, 2.8]
look_at = [3.0, 3.0, 0.5]
up = [0.0, 0.0, 1.0]
fov_y = 90.0
resolution = [32, 32]
"""

#: The scene files' shared pieces: the mesh and the black 1 x 1 m source of Le = 10 grey, the
#: floor's grid (its spacing follows) and the wall y = 0's grid.
SOURCE_TOML = """
[[mesh]]
path = "OBJ"

[material.emitter]
reflectance = [0.0, 0.0, 0.0]
emission = [10.0, 10.0, 10.0]
"""
FLOOR_GRID = """
[[grid]]
name = "floor"
origin = [0.0, 0.0, 0.0]
u = [4.0, 0.0, 0.0]
v = [0.0, 4.0, 0.0]
"""
WALL_GRID = """
[[grid]]
name = "wall"
origin = [0.0, 0.0, 0.0]
u = [4.0, 0.0, 0.0]
v = [0.0, 0.0, 3.0]
spacing = 0.5
normal = [0.0, 1.0, 0.0]
"""

AREA = """# CIE 171:2006 5.3-style: a 1 x 1 m Lambertian area source in the ceiling of a 4 x 4 x 3 m
# room whose surfaces are black (reflectance 0): the illuminance at each point is the direct
# light of the source alone, pi Le F(point -> source), exact by Howell's B-3 (floor) and by
# quadrature (walls). Le = 10 W sr^-1 m^-2 grey: 683 x pi x 10 x F lx.
name = "cie171-area-source"
description = "CIE 171 5.3-style: area source, black room, floor and wall grids"
""" + SOURCE_TOML + FLOOR_GRID + """spacing = 0.5
""" + WALL_GRID + CAMERA

CUBE = """# CIE 171:2006 5.8-style interreflections: a closed 4 m cube, every surface of reflectance
# RHO, a 1 x 1 m source in the ceiling (Le = 10 W sr^-1 m^-2 grey, reflectance RHO too). In a
# closed enclosure of uniform reflectance the light reflected arrives, over all its surfaces,
# at rho Phi / (S (1 - rho)) on average (Phi = pi Le A_source, S its area): exact, whatever
# the shape. The six grids cover the six faces (0.25 m cells).
name = "cie171-interreflection-RHON"
description = "CIE 171 5.8-style: closed cube of reflectance RHO"

[[mesh]]
path = "OBJ"

[material.emitter]
reflectance = [RHO, RHO, RHO]
emission = [10.0, 10.0, 10.0]

[material.floor]
reflectance = [RHO, RHO, RHO]

[material.ceiling]
reflectance = [RHO, RHO, RHO]

[material.walls]
reflectance = [RHO, RHO, RHO]
""" + "".join(f"""
[[grid]]
name = "{n}"
origin = {o}
u = {u}
v = {v}
spacing = 0.25
""" for n, o, u, v in (
    ("floor", [0, 0, 0], [4, 0, 0], [0, 4, 0]), ("ceiling", [0, 0, 4], [0, 4, 0], [4, 0, 0]),
    ("south", [0, 0, 0], [0, 0, 4], [4, 0, 0]), ("north", [0, 4, 0], [4, 0, 0], [0, 0, 4]),
    ("west", [0, 0, 0], [0, 4, 0], [0, 0, 4]), ("east", [4, 0, 0], [0, 0, 4], [0, 4, 0]))) \
    + CAMERA.replace("2.8", "3.8")

REFLECTION = """# CIE 171:2006 5.6-style diffuse reflections: the area source of area-source/ over a floor of
# reflectance 0.5 in an otherwise black 4 x 4 x 3 m room: the ceiling and the walls receive
# the floor's one reflection, rho / pi E_floor(y) cos cos / r^2 integrated over the floor
# (E_floor exact by Howell's B-3), nothing else.
name = "cie171-diffuse-reflection"
description = "CIE 171 5.6-style: one diffuse reflection off the floor"
""" + SOURCE_TOML + """
[material.floor]
reflectance = [0.5, 0.5, 0.5]

[[grid]]
name = "ceiling"
origin = [0.0, 0.0, 3.0]
u = [0.0, 4.0, 0.0]
v = [4.0, 0.0, 0.0]
spacing = 0.5
""" + WALL_GRID + CAMERA

OBSTRUCTION = """# CIE 171:2006 5.7-style internal obstruction: the area source of area-source/ and, half way
# down (z = 1.5), a black opaque square plate 1 x 1 m centred at (2.5, 2, 1.5), in an
# otherwise black 4 x 4 x 3 m room: the floor has an umbra, a penumbra and full light; exact
# by quadrature over the source with the plate's shadow tested segment by segment.
name = "cie171-obstruction"
description = "CIE 171 5.7-style: an opaque plate between an area source and the floor"
""" + SOURCE_TOML + """
[material.plate]
two_sided = true
""" + FLOOR_GRID + """spacing = 0.25
""" + CAMERA

if __name__ == "__main__":
    write("diffuse-reflection", room(4, 4, 3, (1.5, 2.5, 1.5, 2.5)), REFLECTION)
    g = room(4, 4, 3, (1.5, 2.5, 1.5, 2.5))
    g["plate"] = [quad((2.0, 1.5, 1.5), (1.0, 0, 0), (0, 1.0, 0))]
    write("obstruction", g, OBSTRUCTION)
    write("area-source", room(4, 4, 3, (1.5, 2.5, 1.5, 2.5)), AREA)
    for rho in (0.2, 0.5, 0.8, 0.95):
        n = f"{round(rho * 100):02d}"
        write(f"interreflection-{n}", room(4, 4, 4, (1.5, 2.5, 1.5, 2.5)),
              CUBE.replace("RHON", n).replace("RHO", f"{rho:g}"))
