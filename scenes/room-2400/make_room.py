"""Generate room-2400.obj + room-2400.mtl: a furnished room of ~2400 triangles.

Deterministic (numpy + trimesh only); run ``python make_room.py`` to rewrite
the two files next to this script. Units: metres, y up.

The room is the closed box x 0..5, y 0..2.7, z 0..4 whose six sides are
tessellated into triangles facing INTO the room. The ceiling light is a 1 x 1 m
square (x 2..3, z 1.5..2.5) in a matching hole of the ceiling tessellation,
facing down (no coplanar overlap). The furniture (table, four chairs, a
bookshelf with books, a sofa with cushions, a floor lamp) is made of
axis-aligned boxes and vertical cylinders (trimesh.creation), each a closed
triangle mesh with outward normals. Every part is separated from every other
part, from the floor and from the walls by a gap of at least 1 mm
(GAP), so nothing touches or interpenetrates.
"""
import os

import numpy as np
import trimesh

HERE = os.path.dirname(os.path.abspath(__file__))
OBJ_NAME = "room-2400.obj"
MTL_NAME = "room-2400.mtl"

W, H, D = 5.0, 2.7, 4.0          # room extent in x, y, z (m)
GAP = 0.001                      # clearance between parts (m)
LIGHT = (2.0, 3.0, 1.5, 2.5)     # ceiling light x0, x1, z0, z1 (on the ceiling grid)

# (name, Kd, Ke)
MATERIALS = [
    ("floor", (0.45, 0.30, 0.18), (0, 0, 0)),
    ("wall", (0.75, 0.73, 0.68), (0, 0, 0)),
    ("wall_accent", (0.55, 0.65, 0.72), (0, 0, 0)),
    ("ceiling", (0.80, 0.80, 0.80), (0, 0, 0)),
    ("light", (0.80, 0.80, 0.80), (10.0, 10.0, 10.0)),
    ("table", (0.55, 0.35, 0.20), (0, 0, 0)),
    ("chair", (0.15, 0.30, 0.60), (0, 0, 0)),
    ("shelf", (0.40, 0.26, 0.15), (0, 0, 0)),
    ("book_red", (0.70, 0.10, 0.10), (0, 0, 0)),
    ("book_green", (0.10, 0.50, 0.20), (0, 0, 0)),
    ("book_blue", (0.10, 0.20, 0.60), (0, 0, 0)),
    ("book_yellow", (0.80, 0.70, 0.15), (0, 0, 0)),
    ("sofa", (0.60, 0.12, 0.10), (0, 0, 0)),
    ("cushion", (0.75, 0.60, 0.25), (0, 0, 0)),
    ("lamp_metal", (0.30, 0.30, 0.30), (0, 0, 0)),
    ("lampshade", (0.85, 0.80, 0.65), (0, 0, 0)),
]


# ---------------------------------------------------------------- primitives
def box(lo, hi):
    """Closed box mesh (12 triangles, outward normals) spanning lo..hi."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    assert np.all(hi > lo)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    return m


def ycyl(x, z, y0, y1, r, sections):
    """Closed vertical cylinder (4*sections triangles, outward normals)."""
    m = trimesh.creation.cylinder(radius=r, height=y1 - y0, sections=sections)
    rot = trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0])  # z axis -> y axis
    m.apply_transform(rot)
    m.apply_translation([x, (y0 + y1) / 2, z])
    return m


def grid(origin, du, dv, nu, nv, skip=()):
    """Planar grid of nu x nv cells, 2 triangles per cell, normal = du x dv.

    Returns (vertices, faces); cells (i, j) in ``skip`` are left out.
    """
    o, du, dv = (np.asarray(a, float) for a in (origin, du, dv))
    verts = np.array([o + du * (i / nu) + dv * (j / nv) for j in range(nv + 1) for i in range(nu + 1)])
    faces = []
    for j in range(nv):
        for i in range(nu):
            if (i, j) in skip:
                continue
            a = j * (nu + 1) + i
            b, c, d = a + 1, a + nu + 2, a + nu + 1
            faces += [(a, b, c), (a, c, d)]
    return verts, np.array(faces, int)


# ---------------------------------------------------------------- scene parts
def room_shell():
    """The six sides, each facing into the room. Returns list of (name, mat, V, F)."""
    parts = []
    # floor y=0, normal +y: du along z, dv along x  (z x x = +y)
    parts.append(("floor", "floor", *grid([0, 0, 0], [0, 0, D], [W, 0, 0], 16, 20)))
    # ceiling y=H, normal -y: du along x, dv along z  (x x z = -y); hole for the light
    nx, nz = 10, 8
    lx0, lx1, lz0, lz1 = LIGHT
    skip = {(i, j) for i in range(nx) for j in range(nz)
            if lx0 <= i * W / nx < lx1 and lz0 <= j * D / nz < lz1}
    parts.append(("ceiling", "ceiling", *grid([0, H, 0], [W, 0, 0], [0, 0, D], nx, nz, skip)))
    # the light fills the hole exactly, facing down
    parts.append(("ceiling_light", "light",
                  *grid([lx0, H, lz0], [lx1 - lx0, 0, 0], [0, 0, lz1 - lz0], 2, 2)))
    # walls: 0.5 m columns, 7 rows
    parts.append(("wall_back", "wall_accent", *grid([0, 0, D], [0, H, 0], [W, 0, 0], 7, 10)))  # z=D, -z
    parts.append(("wall_front", "wall", *grid([0, 0, 0], [W, 0, 0], [0, H, 0], 10, 7)))        # z=0, +z
    parts.append(("wall_left", "wall", *grid([0, 0, 0], [0, H, 0], [0, 0, D], 7, 8)))          # x=0, +x
    parts.append(("wall_right", "wall", *grid([W, 0, 0], [0, 0, D], [0, H, 0], 8, 7)))         # x=W, -x
    return parts


def table(parts, cx, cz):
    top_y0, top_y1 = 0.71, 0.75
    hx, hz = 0.70, 0.40
    parts.append(("table_top", "table", box([cx - hx, top_y0, cz - hz], [cx + hx, top_y1, cz + hz])))
    for k, (sx, sz) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
        parts.append((f"table_leg{k}", "table",
                      ycyl(cx + sx * (hx - 0.08), cz + sz * (hz - 0.08), GAP, top_y0 - GAP, 0.03, 12)))
    return (cx - hx, cz - hz, cx + hx, cz + hz)


def chair(parts, name, cx, cz, back_dir):
    """Chair centred at (cx, cz); back_dir is the side of the backrest: '+x', '-x', '+z', '-z'."""
    s = 0.225                       # half seat size
    seat_y0, seat_y1 = 0.43, 0.47
    parts.append((f"{name}_seat", "chair", box([cx - s, seat_y0, cz - s], [cx + s, seat_y1, cz + s])))
    leg = 0.035
    for k, (sx, sz) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
        x0 = cx + sx * (s - 0.02) - (leg if sx > 0 else 0)
        z0 = cz + sz * (s - 0.02) - (leg if sz > 0 else 0)
        parts.append((f"{name}_leg{k}", "chair", box([x0, GAP, z0], [x0 + leg, seat_y0 - GAP, z0 + leg])))
    t = 0.03
    y0, y1 = seat_y1 + GAP, 0.97
    if back_dir == "+z":
        lo, hi = [cx - s, y0, cz + s - t], [cx + s, y1, cz + s]
    elif back_dir == "-z":
        lo, hi = [cx - s, y0, cz - s], [cx + s, y1, cz - s + t]
    elif back_dir == "+x":
        lo, hi = [cx + s - t, y0, cz - s], [cx + s, y1, cz + s]
    else:
        lo, hi = [cx - s, y0, cz - s], [cx - s + t, y1, cz + s]
    parts.append((f"{name}_back", "chair", box(lo, hi)))


def bookshelf(parts, x0, x1, z0, z1, height):
    t = 0.02
    g = GAP
    parts.append(("shelf_side_l", "shelf", box([x0, g, z0], [x0 + t, height, z1])))
    parts.append(("shelf_side_r", "shelf", box([x1 - t, g, z0], [x1, height, z1])))
    # back panel between the sides, behind the boards
    parts.append(("shelf_back", "shelf", box([x0 + t + g, g, z1 - 0.01], [x1 - t - g, height, z1])))
    levels = [0.05, 0.45, 0.85, 1.25, height - t]      # board bottoms
    books = ["book_red", "book_green", "book_blue", "book_yellow"]
    nb = 0
    for li, yb in enumerate(levels):
        parts.append((f"shelf_board{li}", "shelf",
                      box([x0 + t + g, yb, z0], [x1 - t - g, yb + t, z1 - 0.01 - g])))
        if li >= len(levels) - 1:
            continue
        # books standing on this board, 1 mm apart, heights varying deterministically
        bx = x0 + t + g + 0.03
        for k in range(3 + (li % 2)):
            wdt = 0.05 + 0.01 * ((k + li) % 3)
            hgt = 0.22 + 0.03 * ((2 * k + li) % 4)
            parts.append((f"book{nb}", books[nb % len(books)],
                          box([bx, yb + t + g, z0 + 0.04], [bx + wdt, yb + t + g + hgt, z1 - 0.01 - 2 * g])))
            bx += wdt + 0.004
            nb += 1


def sofa(parts, x0, x1, z0, z1):
    """Sofa against the right wall (x1 side is the back)."""
    g = GAP
    base_y1 = 0.40
    back_t = 0.18
    arm_w = 0.18
    parts.append(("sofa_base", "sofa", box([x0, g, z0], [x1, base_y1, z1])))
    parts.append(("sofa_back", "sofa", box([x1 - back_t, base_y1 + g, z0], [x1, 0.85, z1])))
    parts.append(("sofa_arm0", "sofa", box([x0, base_y1 + g, z0], [x1 - back_t - g, 0.62, z0 + arm_w])))
    parts.append(("sofa_arm1", "sofa", box([x0, base_y1 + g, z1 - arm_w], [x1 - back_t - g, 0.62, z1])))
    # two seat cushions and two back cushions between the arms
    zs = np.linspace(z0 + arm_w + g, z1 - arm_w - g, 3)
    for k in range(2):
        za, zb = zs[k] + (g if k else 0), zs[k + 1] - (g if k == 0 else 0)
        parts.append((f"sofa_seat_cushion{k}", "cushion",
                      box([x0 + 0.02, base_y1 + g, za], [x1 - back_t - g, base_y1 + 0.12, zb])))
        parts.append((f"sofa_back_cushion{k}", "cushion",
                      box([x1 - back_t - 0.12, base_y1 + 0.12 + g, za], [x1 - back_t - g, 0.80, zb])))


def floor_lamp(parts, x, z):
    parts.append(("lamp_base", "lamp_metal", ycyl(x, z, GAP, 0.03, 0.15, 24)))
    parts.append(("lamp_pole", "lamp_metal", ycyl(x, z, 0.03 + GAP, 1.50, 0.015, 12)))
    parts.append(("lamp_shade", "lampshade", ycyl(x, z, 1.50 + GAP, 1.80, 0.20, 24)))


def build():
    shell = room_shell()
    parts = []
    table(parts, 2.5, 2.3)
    chair(parts, "chair0", 2.1, 2.3 + 0.40 + 0.05 + 0.225, "+z")
    chair(parts, "chair1", 2.9, 2.3 + 0.40 + 0.05 + 0.225, "+z")
    chair(parts, "chair2", 2.5 - 0.70 - 0.05 - 0.225, 2.3, "-x")
    chair(parts, "chair3", 2.5 + 0.70 + 0.05 + 0.225, 2.3, "+x")
    bookshelf(parts, 0.30, 1.30, 3.60, 3.96, 1.80)
    sofa(parts, 4.05, 4.95, 1.20, 3.00)
    floor_lamp(parts, 4.55, 3.55)
    out = list(shell)
    for name, mat, m in parts:
        assert m.is_winding_consistent and m.volume > 0, name
        out.append((name, mat, np.asarray(m.vertices, float), np.asarray(m.faces, int)))
    return out


def check(items):
    """Sanity checks: bounds, gaps between axis-aligned part bounding boxes."""
    boxes = []
    for name, mat, v, f in items:
        if name.startswith(("floor", "ceiling", "wall")):
            continue
        lo, hi = v.min(0), v.max(0)
        assert np.all(lo >= GAP - 1e-9) and np.all(hi <= np.array([W, H, D]) - GAP + 1e-9), name
        boxes.append((name, lo, hi))
    for i in range(len(boxes)):
        for j in range(i):
            (a, alo, ahi), (b, blo, bhi) = boxes[i], boxes[j]
            sep = np.max(np.maximum(blo - ahi, alo - bhi))
            assert sep >= GAP - 1e-9, f"{a} and {b} are closer than {GAP} m ({sep})"


def write(items):
    with open(os.path.join(HERE, MTL_NAME), "w") as fh:
        fh.write("# room-2400 materials (generated by make_room.py)\n")
        for name, kd, ke in MATERIALS:
            fh.write(f"\nnewmtl {name}\nKd {kd[0]:g} {kd[1]:g} {kd[2]:g}\nKe {ke[0]:g} {ke[1]:g} {ke[2]:g}\n")
    ntri = sum(len(f) for _, _, _, f in items)
    with open(os.path.join(HERE, OBJ_NAME), "w") as fh:
        fh.write("# room-2400: furnished room, generated by make_room.py -- do not edit by hand.\n")
        fh.write(f"# Units: metres, y up. Room x 0..{W:g}, y 0..{H:g}, z 0..{D:g}. {ntri} triangles.\n")
        fh.write("# Room sides face into the room; furniture parts are closed meshes with\n")
        fh.write("# outward normals, separated by >= 1 mm gaps.\n")
        fh.write(f"mtllib {MTL_NAME}\n")
        base = 1
        for name, mat, v, f in items:
            fh.write(f"\no {name}\nusemtl {mat}\n")
            for p in v:
                fh.write("v {:.6f} {:.6f} {:.6f}\n".format(*(0.0 if abs(x) < 5e-7 else x for x in p)))
            for t in f + base:
                fh.write("f {} {} {}\n".format(*t))
            base += len(v)
    return ntri


def main():
    items = build()
    check(items)
    ntri = write(items)
    print(f"wrote {OBJ_NAME} ({ntri} triangles) and {MTL_NAME}")


if __name__ == "__main__":
    main()
