"""Smooth exports (core/smooth.py, formats/meshexport.py, formats/viewer.py): radiance at shared vertices, no step
across any edge (T-junctions of the adaptive subdivision included), nothing blended across a
crease, linear fields reproduced exactly, and on a floor lit by a small lamp (conftest.py) the
exported mesh.glb is continuous and within 2 % of the exact radiance where the flat export
jumps by a fifth."""

from __future__ import annotations

import base64
import os
import re
import warnings

import numpy as np
import pytest
from scipy.spatial import cKDTree

from helpers import prepared, scene_path
from radiosity.core.exact import polygon_point_form_factor
from radiosity.runtime.store import RunStore
from radiosity.core.colour import tonemap
from radiosity.core.smooth import smooth_mesh, smoothing_surfaces
from radiosity.formats.meshexport import export_mesh, triangles
from radiosity.formats.viewer import write_viewer

Y = np.array([0.2126, 0.7152, 0.0722])


# ----------------------------------------------------------------------------- the measures

def edge_jump(pos: np.ndarray, val: np.ndarray, tol: float = 1e-7) -> float:
    """The largest relative step of a piecewise-linear surface across its edges.

    pos (T, 3, 3) triangle corners, val (T, 3) a value at each corner. For every triangle edge
    and every corner of any triangle lying on that edge (a shared corner, or a T-junction
    inside it), |edge interpolation - corner value| / max of the two. 0 for a continuous
    surface; the difference of neighbouring faces for flat colours."""
    pts, pv = pos.reshape(-1, 3), val.reshape(-1)
    tree = cKDTree(pts)
    worst = 0.0
    for k in range(3):
        a, b = pos[:, k], pos[:, (k + 1) % 3]
        va, vb = val[:, k], val[:, (k + 1) % 3]
        hits = tree.query_ball_point(0.5 * (a + b), 0.5 * np.linalg.norm(b - a, axis=1) + tol)
        cnt = np.fromiter((len(h) for h in hits), np.int64, len(hits))
        t = np.repeat(np.arange(len(a)), cnt)
        q = np.fromiter((i for h in hits for i in h), np.int64, int(cnt.sum()))
        d = b[t] - a[t]
        s = np.einsum("ij,ij->i", pts[q] - a[t], d) / np.einsum("ij,ij->i", d, d)
        off = np.linalg.norm(pts[q] - a[t] - s[:, None] * d, axis=1)
        on = (off < tol) & (s > -1e-9) & (s < 1 + 1e-9)
        interp = (1 - s[on]) * va[t[on]] + s[on] * vb[t[on]]
        other = pv[q[on]]
        rel = np.abs(interp - other) / np.maximum(np.maximum(interp, other), 1e-300)
        worst = max(worst, float(rel.max(initial=0.0)))
    return worst


def neighbour_jumps(verts: np.ndarray, faces: np.ndarray, val: np.ndarray, tol: float = 1e-7):
    """Relative jumps |a - b| / max(a, b) between neighbouring vertices: those of a mesh edge
    and those at the same position (the corners of flat faces). Returns (jumps, pairs)."""
    pairs = [faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]],
             cKDTree(verts).query_pairs(tol, output_type="ndarray").reshape(-1, 2)]
    p = np.concatenate(pairs)
    a, b = val[p[:, 0]], val[p[:, 1]]
    return np.abs(a - b) / np.maximum(np.maximum(a, b), 1e-300), p


def test_the_measures_on_hand_made_triangles():
    # two triangles sharing the edge (1,0,0)-(0,1,0), a ramp: continuous
    pos = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[1, 0, 0], [1, 1, 0], [0, 1, 0]]], float)
    ramp = pos[..., 0] + 1.0
    assert edge_jump(pos, ramp) == 0.0
    flat = np.array([[1.0] * 3, [1.5] * 3])
    assert edge_jump(pos, flat) == pytest.approx(0.5 / 1.5)
    # a T-junction: a corner inside the other triangle's edge with the wrong value
    tj = np.array([[[0, 0, 0], [2, 0, 0], [0, 2, 0]], [[1, 1, 0], [2, 2, 0], [0, 2, 0]]], float)
    val = np.array([[1.0, 3.0, 1.0], [2.0 + 0.2, 3.0, 1.0]])  # the edge gives 2.0 at (1, 1)
    assert edge_jump(tj, val) == pytest.approx(0.2 / 2.2)
    j, _ = neighbour_jumps(pos.reshape(-1, 3), np.arange(6).reshape(2, 3), flat.ravel())
    assert j.max() == pytest.approx(0.5 / 1.5)


# ----------------------------------------------------------------------------- hand-made mesh

class _Bundle:
    def __init__(self, n, **kw):
        self.n = n
        self.__dict__.update(kw)

    def __len__(self):
        return self.n


def _quad(x0, x1, z0, z1):
    """A floor quad (y = 0, normal +y), counter-clockwise seen from above."""
    return [[x0, 0, z0], [x0, 0, z1], [x1, 0, z1], [x1, 0, z0]]


def test_t_junction_crease_and_back_side_by_hand():
    """Floor [0, 2]^2 (two-sided): the left half one coarse cell, the right half two cells,
    which leaves a T-junction at (1, 0, 1); a wall (x = 2, normal -x) of the same material
    stands on the floor's right edge: a crease."""
    floor = np.array(_quad(0, 2, 0, 2), float)
    wall = np.array([[2, 0, 0], [2, 2, 0], [2, 2, 2], [2, 0, 2]], float)
    el = _Bundle(2, verts=np.stack([floor, wall]), nverts=np.array([4, 4]),
                 normal=np.array([[0.0, 1, 0], [-1, 0, 0]]), material=np.array([0, 0]),
                 two_sided=np.array([True, False]))
    cells = [_quad(0, 1, 0, 2), _quad(1, 2, 0, 1), _quad(1, 2, 1, 2),
             [[2, 0, 0], [2, 2, 0], [2, 2, 2], [2, 0, 2]]]
    V = np.array(cells, float)
    part = _Bundle(4, verts=V, nverts=np.array([4, 4, 4, 4]), orig=np.array([0, 0, 0, 1]),
                   center=V.mean(1), area=np.array([2.0, 1, 1, 4]))
    L = np.zeros((4, 2, 3))
    L[:3, 0] = np.array([1.0, 2.0, 4.0])[:, None]
    L[:3, 1] = np.array([0.5, 0.5, 0.5])[:, None]   # the floor's back: uniform
    L[3, 0] = 7.0
    sm = smooth_mesh(part, el, L)
    np.testing.assert_array_equal(smoothing_surfaces(el), [0, 1])  # the crease splits them
    assert sm.hanging == 1
    front = sm.corner[:3, 0]
    tv = front[2, 0]  # (1, 0, 1): the right cells' shared corner, inside the coarse cell's edge
    np.testing.assert_allclose(sm.verts[tv], [1, 0, 1])
    ends = [front[0, 2], front[0, 3]]  # the coarse cell's corners (1, 0, 2) and (1, 0, 0)
    np.testing.assert_allclose(sm.radiance[tv], sm.radiance[ends].mean(0), rtol=1e-12)
    # no step anywhere on the floor, although the cells differ by 4x
    fl = sm.face_sub[(sm.face_side == 0)] < 3
    f = sm.faces[sm.face_side == 0][fl]
    assert edge_jump(sm.verts[f], sm.radiance[f, 0]) < 1e-9
    # ... while the flat colours step at every shared edge
    sub, tri = triangles(part)
    keep = sub < 3
    assert edge_jump(tri[keep], np.repeat(L[sub[keep], 0, :1], 3, 1)) > 0.4
    assert np.all(sm.radiance >= 0.0)
    # the wall (uniform 7) is not blended with the floor at the crease: its vertices are its own
    wv = sm.corner[3, 0]
    np.testing.assert_array_equal(sm.radiance[wv], 7.0)
    assert not set(wv) & set(front.ravel())
    # the back of the two-sided floor: own vertices, reversed triangles, its own value
    back = sm.face_side == 1
    assert back.sum() == 6 and np.all(sm.face_sub[back] < 3)
    assert not set(sm.faces[back].ravel()) & set(sm.faces[~back].ravel())
    np.testing.assert_allclose(sm.radiance[sm.faces[back]], 0.5)
    nb = np.cross(*(sm.verts[sm.faces[back][:, i]] - sm.verts[sm.faces[back][:, 0]]
                    for i in (1, 2)))
    assert np.all(nb[:, 1] < 0)  # facing down, like the floor's back
    np.testing.assert_array_equal(sm.corner[3, 1], -1)  # one-sided: no back


# ----------------------------------------------------------------------------- a real partition

@pytest.fixture(scope="module")
def cornell_part(client, tmp_path_factory):
    """The Cornell box preprocessed at 16^2, sub-pixel 2 (T-junctions wherever a coarse
    element meets a finer one)."""
    with warnings.catch_warnings():  # the published red wall is non-planar: split, warned
        warnings.simplefilter("ignore")
        out = prepared(client, tmp_path_factory.mktemp("cornell"), scene_path("cornell-box"), 16,
                       visibility=False, subpixel=2)
    rs = RunStore(out)
    return rs.load_partition(), rs.load_elements()


def test_linear_radiance_is_reproduced_at_every_vertex(cornell_part):
    """A radiance linear in position comes back exactly at every vertex of every surface of
    more than one sub-element, at borders and T-junctions too (plain vertex averaging is
    half a cell off at borders: 3-8 % here)."""
    part, el = cornell_part
    coef = np.array([0.001, 0.002, 0.0005])

    def field(p):
        return 1.0 + p @ coef

    L = np.repeat(np.repeat(field(part.center)[:, None, None], 2, 1), 3, 2)
    sm = smooth_mesh(part, el, L)
    assert sm.hanging > 50
    cells = np.bincount(sm.surface[part.orig], minlength=sm.surface.max() + 1)
    several = cells[sm.surface[part.orig]] > 1
    used = np.unique(sm.corner[several, 0])
    err = np.abs(sm.radiance[used, 1] / field(sm.verts[used]) - 1)
    # the red wall is 3 mm out of plane (two triangles): a 3-D ramp is not linear in it
    assert err.max() < 1e-4, err.max()


def test_any_radiance_is_continuous_within_each_surface(cornell_part, rng):
    """Random cell values: the smooth mesh has no step across any edge of a surface (the
    T-junctions of the subdivision and of the ceiling's four pieces included), stays within
    the values' range, and a constant stays constant; the flat colours step everywhere."""
    part, el = cornell_part
    m = len(part)
    L = rng.random((m, 2, 3)) + 0.1
    sm = smooth_mesh(part, el, L)
    sub, tri = triangles(part)
    surf = sm.surface[part.orig]
    front = sm.face_side == 0
    worst_smooth, worst_flat = 0.0, 0.0
    for s in np.unique(surf):
        f = sm.faces[front & (surf[sm.face_sub] == s)]
        worst_smooth = max(worst_smooth, edge_jump(sm.verts[f], sm.radiance[f, 0]))
        k = surf[sub] == s
        worst_flat = max(worst_flat, edge_jump(tri[k], np.repeat(L[sub[k], 0, :1], 3, 1)))
    assert worst_smooth < 1e-9, worst_smooth
    assert worst_flat > 0.5
    assert sm.radiance.min() >= 0.0 and sm.radiance.max() <= 2 * L.max()
    const = smooth_mesh(part, el, np.full((m, 2, 3), 0.25))
    np.testing.assert_allclose(const.radiance, 0.25, rtol=1e-9)
    assert len(sm.faces) == int(np.sum(part.nverts.astype(int) - 2))  # one-sided: no backs
    np.testing.assert_array_equal(sm.face_sub, sub)  # the flat export's triangle order


# ----------------------------------------------------------------------------- the lit floor

def _floor(glb):
    import trimesh

    g = trimesh.load(glb, force="mesh", process=False, skip_materials=True)
    V, F = np.asarray(g.vertices, np.float64), np.asarray(g.faces)
    R = np.asarray(g.vertex_attributes["_RADIANCE"], np.float64) @ Y
    return V, F[np.all(np.abs(V[F][:, :, 1]) < 1e-6, axis=1)], R


def test_mesh_glb_is_smooth_on_a_lit_floor(lamp_run, lamp, tmp_path):
    """The floor of mesh.glb under the lamp, luminance-weighted radiance Y at its vertices.

    Bounds: (1) no step across any edge: at most 1e-4 relative (the float32 of _RADIANCE
    rounds at 6e-8; the eye sees steps of about 1 %); (2) the largest jump between
    neighbouring vertices (an edge, or the same position) exceeds the exact radiance's own
    jump between the same two points by at most 2 %: each vertex is within 1 % or so of the
    exact radiance (the cells are 0.5 % from it; linear reconstruction adds h^2 L''/8, under
    1 % on the coarsest cells at the edge of the view), so a pair is off by at most twice
    that; (3) every vertex within 2 % of the exact radiance rho Le F(point -> lamp).
    The flat export of the same solution fails (1) and (2): its faces step by up to the
    field's change across one element, 23 % here."""
    V, F, R = _floor(os.path.join(lamp_run, "mesh.glb"))
    rs = RunStore(lamp_run)
    part, L = rs.load_partition(), rs.read_arrays("solution")["radiance"]
    flat = str(tmp_path / "flat.glb")
    export_mesh(flat, str(tmp_path / "flat.ply"), part, L, 1.0)
    Vf, Ff, Rf = _floor(flat)
    assert len(F) == len(Ff) > 1000

    rho_le_y = np.asarray(lamp.floor_rho) * np.asarray(lamp.le) @ Y

    def exact(p):
        return rho_le_y * np.array([polygon_point_form_factor(x, [0, 1, 0], lamp.polygon)
                                    for x in p])

    step, step_flat = edge_jump(V[F], R[F]), edge_jump(Vf[Ff], Rf[Ff])
    used, used_f = np.unique(F), np.unique(Ff)
    ex, ex_f = np.zeros(len(V)), np.zeros(len(Vf))
    ex[used], ex_f[used_f] = exact(V[used]), exact(Vf[used_f])
    j, _ = neighbour_jumps(V, F, R)
    je, _ = neighbour_jumps(V, F, ex)
    jf, _ = neighbour_jumps(Vf, Ff, Rf)
    jfe, _ = neighbour_jumps(Vf, Ff, ex_f)
    excess, excess_flat = float(np.max(j - je)), float(np.max(jf - jfe))
    err = float(np.max(np.abs(R[used] / ex[used] - 1)))
    print(f"step across edges: smooth {step:.2g}, flat {step_flat:.3g}; neighbour jump over the "
          f"exact: smooth {excess:.3g} (largest jump {j.max():.3g}, exact {je.max():.3g}), flat "
          f"{excess_flat:.3g}; vertex error {err:.3g}")
    assert step < 1e-4
    assert excess < 0.02
    assert err < 0.02
    assert step_flat > 1e-4 and excess_flat > 0.02  # the bounds can fail


def test_ply_and_viewer_carry_the_vertex_radiance(lamp_run, tmp_path):
    import trimesh

    rs = RunStore(lamp_run)
    part, el = rs.load_partition(), rs.load_elements()
    L = rs.read_arrays("solution")["radiance"]
    sm = smooth_mesh(part, el, L)
    glb, ply = str(tmp_path / "m.glb"), str(tmp_path / "m.ply")
    info = export_mesh(glb, ply, part, L, 2.0, smooth=sm)
    assert info["smooth"] and info["triangles"] == int(np.sum(part.nverts.astype(int) - 2))
    assert info["vertices"] == len(sm.verts) < 3 * info["faces"]  # shared, not per face
    p = trimesh.load(ply, process=False)
    raw = p.metadata["_ply_raw"]
    np.testing.assert_allclose(raw["vertex"]["data"]["radiance_g"], sm.radiance[:, 1], rtol=1e-6)
    np.testing.assert_allclose(raw["face"]["data"]["radiance_g"],
                               L[sm.face_sub, sm.face_side, 1], rtol=1e-6)
    np.testing.assert_array_equal(p.visual.vertex_colors[:, :3], tonemap(sm.radiance, 2.0))

    def colours(page):
        b64 = re.search(r'id="d-col">([^<]*)<', page).group(1)
        return np.frombuffer(base64.b64decode(b64), np.uint8).reshape(len(part), 25)

    fn = str(tmp_path / "v.html")
    assert write_viewer(fn, part, L, 2.0, "lamp", smooth=sm)["smooth"]
    col = colours(open(fn, encoding="utf-8").read())
    front = col[:, :24].reshape(-1, 4, 2, 3)[:, :, 0]
    n3 = part.nverts == 3
    want = tonemap(sm.radiance[np.maximum(sm.corner[:, 0], 0)], 2.0)
    np.testing.assert_array_equal(front[~n3], want[~n3])
    np.testing.assert_array_equal(front[n3, :3], want[n3, :3])
    write_viewer(fn, part, L, 2.0, "lamp")  # flat: each sub-element's colour at its corners
    front = colours(open(fn, encoding="utf-8").read())[:, :24].reshape(-1, 4, 2, 3)[:, :, 0]
    np.testing.assert_array_equal(front, np.repeat(tonemap(L[:, 0], 2.0)[:, None], 4, 1))


def test_the_cells_fits_are_the_pseudo_inverse_least_squares():
    """_cell_models (one numba pass, the 2 x 2 pseudo-inverse in closed form) against the
    weighted least squares by numpy.linalg.pinv: cells with neighbours all round, a strip cell
    whose neighbours lie on one line (the minimum-norm gradient), one with a single neighbour,
    and one with none (flat, its own range); a linear field's in-plane gradient is exact."""
    from radiosity.core.geometry import tangent_basis
    from radiosity.core.smooth import PINV_RCOND, _cell_models

    rng = np.random.default_rng(5)
    k = 40
    n = rng.normal(size=(k, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    c = rng.normal(size=(k, 3))
    L = rng.random((k, 3))
    ci, cj = [], []
    for i in range(k - 3):  # cells 0..k-4: neighbours all round
        for j in rng.choice(k, 5, replace=False):
            if j != i:
                ci.append(i)
                cj.append(j)
    t1, t2 = tangent_basis(n)
    strip = k - 3  # its neighbours on the line through it along t1
    for s in (-1.0, 1.0, 2.0):
        c = np.vstack([c, c[strip] + s * t1[strip]])
        L = np.vstack([L, rng.random((1, 3))])
        n = np.vstack([n, n[strip]])
        ci.append(strip)
        cj.append(len(c) - 1)
    ci.append(k - 2)  # a single neighbour; cell k - 1 has none
    cj.append(0)
    ci, cj = np.array(ci), np.array(cj)
    grad, lo, hi = _cell_models(c, n, L, ci, cj)
    t1, t2 = tangent_basis(n)
    for i in range(len(L)):
        sel = ci == i
        d = c[cj[sel]] - c[i]
        x, y = d @ t1[i], d @ t2[i]
        w = 1.0 / np.maximum(x * x + y * y, 1e-300)
        M = np.array([[np.sum(w * x * x), np.sum(w * x * y)],
                      [np.sum(w * x * y), np.sum(w * y * y)]])
        rhs = np.stack([(w * x) @ (L[cj[sel]] - L[i]), (w * y) @ (L[cj[sel]] - L[i])])
        g = np.linalg.pinv(M, rcond=PINV_RCOND, hermitian=True) @ rhs if sel.any() \
            else np.zeros((2, 3))
        want = g[0][:, None] * t1[i] + g[1][:, None] * t2[i]
        np.testing.assert_allclose(grad[i], want, rtol=1e-9, atol=1e-12)
        vals = np.vstack([L[i], L[cj[sel]]])
        np.testing.assert_array_equal(lo[i], vals.min(0))
        np.testing.assert_array_equal(hi[i], vals.max(0))
    assert np.abs(grad[strip] @ t2[strip]).max() < 1e-12  # nothing across the strip
    assert np.abs(grad[strip]).max() > 0 and not grad[len(L) - 1].any()
    # a linear field over cells in one plane: its gradient in the plane, exactly
    c = np.column_stack([rng.random((k, 2)), np.zeros(k)])
    n = np.tile([0.0, 0.0, 1.0], (k, 1))
    G = rng.normal(size=(3, 3))
    keep = (ci < k) & (cj < k)
    grad, _, _ = _cell_models(c, n, c @ G.T, ci[keep], cj[keep])
    G[:, 2] = 0.0
    for i in range(k - 3):
        np.testing.assert_allclose(grad[i], G, rtol=1e-9, atol=1e-9)
