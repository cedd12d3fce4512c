"""Contact faces (scene/contact.py) and the closure per element side (scene/closure.py): sides
covered by a touching surface are found and take no part; each side's row target is the
fraction of its hemisphere that reaches geometry (issue 26)."""

from __future__ import annotations

import numpy as np
import pytest

from radiosity.scene.closure import detect_closure
from radiosity.scene.contact import find_contacts
from radiosity.scene.load import load_scene
from radiosity.stages.solve import RowTargets, normalise_rows, resolve_closure, row_mode
from radiosity.methods.base import CAP_PRODUCT
from helpers import scene_path, write_scene
from radiosity.settings import options as settings_of


def _box(lo, hi, inward: bool, n: int = 1, skip=()):
    """Quads (k, 4, 3) of the box lo..hi, n x n per face, facing in (inward) or out; `skip`
    leaves faces out by name (x0 x1 y0 y1 z0 z1)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    c = 0.5 * (lo + hi)
    out = []
    for ax in range(3):
        u, v = [(ax + 1) % 3, (ax + 2) % 3]
        for k, val in ((0, lo[ax]), (1, hi[ax])):
            if f"{'xyz'[ax]}{k}" in skip:
                continue
            for i in range(n):
                for j in range(n):
                    q = []
                    for a, b in ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)):
                        p = np.empty(3)
                        p[ax] = val
                        p[u] = lo[u] + (hi[u] - lo[u]) * a / n
                        p[v] = lo[v] + (hi[v] - lo[v]) * b / n
                        q.append(p)
                    q = np.array(q)
                    nrm = np.cross(q[1] - q[0], q[2] - q[0])
                    toward = (c - q.mean(0)) @ nrm > 0
                    out.append(q if toward == inward else q[::-1])
    return out


def _scene(tmp_path, groups, two_sided: bool = False) -> str:
    """A scene of quad groups [(material, quads)]; material 'light' emits."""
    lines, nv = [], 0
    for mat, quads in groups:
        lines.append(f"usemtl {mat}")
        for q in quads:
            lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in q]
            lines.append(f"f {nv + 1} {nv + 2} {nv + 3} {nv + 4}")
            nv += 4
    mats = "".join(f"[material.{m}]\nreflectance = [0.5, 0.5, 0.5]\n"
                   + ("emission = [1.0, 1.0, 1.0]\n" if m == "light" else "")
                   + ("two_sided = true\n" if two_sided else "")
                   for m in dict.fromkeys(m for m, _ in groups))
    cam = """
    [camera]
    position = [0.5, 0.5, 0.1]
    look_at = [0.5, 0.4, 0.9]
    up = [0.0, 1.0, 0.0]
    fov_y = 60.0
    resolution = [16, 16]
    """
    return write_scene(tmp_path, "\n".join(lines) + "\n", mats, camera=cam)


def _furnished():
    return load_scene(scene_path("furnished-room"), settings=settings_of()).elements


def _material(el, name):
    return np.array([el.material_names[m] == name for m in el.material])


# ----------------------------------------------------------------------------- contact faces

def test_contact_faces_of_the_furnished_room():
    el = _furnished()
    c = find_contacts(el, 1e-6)
    assert not c[:, 1].any()  # one-sided everywhere: no back is covered
    c = c[:, 0]
    table, shelf, wall = _material(el, "table"), _material(el, "shelf"), _material(el, "wall")
    legs_ends = table & np.isclose(el.area, 0.05 * 0.05) & (np.abs(el.normal[:, 1]) > 0.99)
    assert legs_ends.sum() == 8 and c[legs_ends].all()         # tops on the table top, bottoms on the floor
    assert not c[table & ~legs_ends].any()                     # the top's underside is only partly covered
    shelf_bottom = shelf & (el.normal[:, 1] < -0.99)
    shelf_back = shelf & (el.normal[:, 2] > 0.99)
    assert c[shelf_bottom].all() and c[shelf_back].all() and c[shelf].sum() == 2
    # the wall cells wholly behind the shelf's back (1 x 1.8 m against 0.5 m cells): 2 x 3
    assert c[wall].sum() == 6
    assert not c[_material(el, "lamp") | _material(el, "light") | _material(el, "ceiling")].any()
    assert c.sum() == 16


@pytest.mark.parametrize("name", ["cornell-box", "room-2400", "furnace-cube"])
def test_no_contact_faces_in_clean_scenes(name):
    el = load_scene(scene_path(name), settings=settings_of()).elements
    assert not find_contacts(el, 1e-6).any()
    assert detect_closure(el, 1e-6).to_dict()["contact_sides"] == 0


@pytest.mark.parametrize("gap, touching", [(0.0, True), (-2e-6, True), (1e-6, True),
                                           (0.004, False)])
def test_two_boxes_pressed_together(tmp_path, gap, touching):
    """The touching faces of two boxes in a room are contact sides when they meet (or slightly
    interpenetrate) and not when a real gap (4 mm of a 1.7 m scene) separates them."""
    room = _box((0, 0, 0), (1, 1, 1), inward=True, n=2)
    a = _box((0.2, 0.0, 0.3), (0.5, 0.4, 0.6), inward=False)
    b = _box((0.5 + gap, 0.0, 0.3), (0.8, 0.3, 0.6), inward=False)
    el = load_scene(_scene(tmp_path, [("room", room), ("a", a), ("b", b)]), settings=settings_of()).elements
    c = find_contacts(el, 1e-6)[:, 0]
    a_x1 = _material(el, "a") & (el.normal[:, 0] > 0.99)
    b_x0 = _material(el, "b") & (el.normal[:, 0] < -0.99)
    on_floor = (_material(el, "a") | _material(el, "b")) & (el.normal[:, 1] < -0.99)
    assert c[on_floor].all()                      # both bottoms stand on the floor
    assert c[b_x0].all() == touching              # b's face is wholly on a's taller face
    assert not c[a_x1].any()                      # a's face is only partly covered by b's
    assert c.sum() == 2 + touching


# ----------------------------------------------------------------------------- closure per side

def test_furnished_room_is_closed_with_targets_one_but_on_contact_sides():
    el = _furnished()
    cl = detect_closure(el, 1e-6)
    assert cl.closed and cl.reason.startswith("closed") and "16 contact sides" in cl.reason
    assert cl.escaped == 0
    contact = cl.contact[:, 0]
    assert contact.sum() == 16 and (cl.target[contact, 0] == 0).all()
    partly = cl.to_dict()["partly_covered_sides"]
    assert partly > 0                                   # floor, table top, walls by the shelf
    exact = cl.exact[:, 0] & ~contact
    assert (~cl.exact[:, 0]).sum() == partly           # only those are not snapped
    assert np.all(cl.target[exact, 0] == 1.0)
    assert np.all((cl.target[~cl.exact[:, 0], 0] > 0.2) & (cl.target[~cl.exact[:, 0], 0] < 1))
    # the lamp's top, 5 mm under the ceiling, sees the ceiling: target 1, not a contact
    lamp_top = _material(el, "lamp") & (el.normal[:, 1] > 0.99)
    assert lamp_top.sum() == 1 and cl.target[lamp_top, 0] == 1.0 and not contact[lamp_top].any()


def test_two_sided_closed_shell_is_closed_and_its_backs_see_the_void(tmp_path):
    room = _box((0, 0, 0), (1, 1, 1), inward=True, n=2)
    light = [np.array([[0.4, 0.999, 0.4], [0.4, 0.999, 0.6], [0.6, 0.999, 0.6], [0.6, 0.999, 0.4]])]
    el = load_scene(_scene(tmp_path, [("shell", room), ("light", light)], two_sided=True),
                    settings=settings_of()).elements
    assert el.two_sided.all()
    cl = detect_closure(el, 1e-6)
    assert cl.closed, cl.reason
    assert row_mode("auto", cl) == "closed"
    shell = _material(el, "shell")
    assert np.all(cl.target[shell, 1] == 0) and cl.exact[shell, 1].all()   # the outward backs
    assert np.all(cl.target[shell, 0] == 1) and cl.to_dict()["void_sides"] == shell.sum()
    # the light's two sides both see the room
    assert np.all(cl.target[~shell] == 1)
    rt = RowTargets.of(cl, np.arange(len(el)), el.two_sided)
    assert rt.balance.all() and np.allclose(rt.target, np.where(shell, 1.0, 2.0))


def test_open_box_is_open_and_its_sides_that_see_out_have_targets_below_one(tmp_path):
    box = _box((0, 0, 0), (1, 1, 1), inward=True, n=2, skip=("z0",))
    el = load_scene(_scene(tmp_path, [("box", box)]), settings=settings_of()).elements
    cl = detect_closure(el, 1e-6)
    assert not cl.closed and cl.reason.startswith("open")
    far = el.normal[:, 2] < -0.99                          # the face opposite the opening
    assert np.all(cl.target[far, 0] < 0.9) and not cl.exact[far, 0].any()
    # (nearly) every side sees out; sides that lose at most 2 % of their rays are snapped to 1,
    # but in an open scene only a side that lost no ray is exact (its row may be balanced)
    assert (cl.target[:, 0] < 1.0).mean() > 0.8 and cl.target[:, 0].mean() < 0.9
    assert row_mode("auto", cl) == "cap"        # not balanced by default: rows only capped
    assert not cl.exact[(cl.lost[:, 0] > 0), 0].any()
    rt = RowTargets.of(cl, np.arange(len(el)), el.two_sided)
    assert not rt.dead.any() and not rt.balance[far].any()


def test_stated_closure_still_finds_contacts():
    el = _furnished()
    on = resolve_closure("on", el, 1e-6)
    assert on.closed and on.target is None and on.contact[:, 0].sum() == 16
    rt = RowTargets.of(on, np.arange(len(el)), el.two_sided)
    assert rt.dead.sum() == 16 and rt.balance.sum() == len(el) - 16


# ----------------------------------------------------------------------------- row handling

class _Dense:
    """A dense reciprocal operator (A_a K_ab symmetric) for normalise_rows: one side."""

    def __init__(self, K):
        self.K = K

    def row_sums(self):
        return np.stack([self.K.sum(axis=1), np.zeros(len(self.K))])

    def apply(self, L, use_need=True):
        y = np.zeros_like(L)
        y[0, 0] = self.K @ L[0, 0]
        return y


def _reciprocal(m, rng):
    A = rng.uniform(0.8, 1.25, m)
    S = rng.uniform(0.0, 1.0, (m, m))
    S = S + S.T
    np.fill_diagonal(S, 0)
    K = S / A[:, None]
    return A, K / K.sum(axis=1).max() * rng.uniform(0.9, 1.1)


def test_normalise_rows_balances_to_targets_caps_the_rest_and_zeroes_contacts():
    rng = np.random.default_rng(3)
    m = 12
    A, K = _reciprocal(m, rng)
    K = K * 1.3  # rows over 1
    dead = np.zeros(m, bool)
    dead[[2, 7]] = True
    balance = np.ones(m, bool)
    balance[[4, 5]] = False        # e.g. partly covered: capped only
    target = np.ones(m)
    target[9] = 0.8                # a side's measured target
    rt = RowTargets(target, balance & ~dead, dead, np.zeros(m, bool))
    rows, sc = normalise_rows(_Dense(K), "closed", rt)
    assert sc["cmode"] == CAP_PRODUCT and rows["contact_unknowns"] == 2
    d = sc["cap"]
    K2 = d[:, None] * K * d[None, :]
    r = K2.sum(axis=1)
    assert np.all(d[dead] == 0) and np.all(K2[dead] == 0) and np.all(K2[:, dead] == 0)
    ok = balance & ~dead
    assert np.allclose(r[ok], target[ok], atol=1e-10)
    assert np.all(r[[4, 5]] <= 1 + 1e-10)
    S = A[:, None] * K2
    assert np.allclose(S, S.T, atol=1e-14)  # reciprocity kept
    # cap mode with contacts: no row above 1, contacts zero, nothing balanced up
    rows, sc = normalise_rows(_Dense(K), "cap", rt)
    d = sc["cap"]
    r = (d[:, None] * K * d[None, :]).sum(axis=1)
    assert np.all(r <= 1 + 1e-10) and np.all(d[dead] == 0) and np.all(d <= 1)
    # no targets, no contacts: the closed balancing of before (every row to 1)
    rows, sc = normalise_rows(_Dense(K), "closed")
    d = sc["cap"]
    assert np.allclose((d[:, None] * K * d[None, :]).sum(axis=1), 1.0, atol=1e-11)


def test_an_operator_of_coarse_links_caps_rows_leaf_by_leaf_without_passes():
    """leaf_caps (the hierarchical operator): rows past 1 are capped by d = 1 / row sum as
    K -> D K D (dead rows 0), in no pass of the operator; every row then sums to at most 1 and
    reciprocity holds. Without it, the pairs' min(cap_a, cap_b)."""
    from radiosity.methods.base import CAP_MIN

    rng = np.random.default_rng(5)
    m = 12
    A, K = _reciprocal(m, rng)
    K = K * 1.3
    dead = np.zeros(m, bool)
    dead[3] = True
    rt = RowTargets(np.ones(m), np.zeros(m, bool), dead, np.zeros(m, bool))

    class Coarse(_Dense):
        leaf_caps = True

        def apply(self, L, use_need=True):
            raise AssertionError("no pass")

    for rows in (None, rt):
        op = Coarse(K)
        fig, sc = normalise_rows(op, "cap", rows, sums=np.stack([K.sum(axis=1), np.zeros(m)]))
        d = sc["cap"]
        rs = K.sum(axis=1)
        live = ~dead if rows is not None else np.ones(m, bool)
        assert sc["cmode"] == CAP_PRODUCT and fig["normalised"]
        assert np.allclose(d[live], np.minimum(1.0, 1.0 / rs[live]))
        K2 = d[:, None] * K * d[None, :]
        assert np.all(K2.sum(axis=1) <= 1 + 1e-12) and np.all(d[~live] == 0)
        S = A[:, None] * K2
        assert np.allclose(S, S.T, atol=1e-14)
    _, sc = normalise_rows(_Dense(K), "cap")
    assert sc["cmode"] == CAP_MIN
