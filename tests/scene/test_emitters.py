"""Emitters (scene/emitters.py): the area emitters' power, their stratified shadow-ray samples
against the exact contour-integral form factor, the oracle's irradiance bound, the registry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from radiosity.core.bundles import Elements
from radiosity.core.exact import polygon_point_form_factor
from radiosity.core.geometry import polygon_properties
from radiosity.errors import RadiosityError
from radiosity.scene.emitters import (EMITTER_TYPES, NO_EMITTER, AreaEmitters, Emitter,
                                      area_emission, emitter_type, irradiance)
from radiosity.scene.load import load_scene
from radiosity.settings import options
from helpers import scene_path


def _elements(polys, Le, two_sided=None):
    """Elements from polygons (list of (3 or 4, 3)) with emission Le (n, 2, 3)."""
    n = len(polys)
    verts = np.zeros((n, 4, 3))
    nverts = np.array([len(p) for p in polys], np.int8)
    for i, p in enumerate(polys):
        verts[i, :len(p)] = p
        verts[i, len(p):] = p[-1]
    area, normal, center = polygon_properties(verts, nverts)
    two = np.zeros(n, bool) if two_sided is None else np.asarray(two_sided, bool)
    return Elements(verts=verts, nverts=nverts, normal=normal, center=center, area=area,
                    reflectance=np.zeros((n, 2, 3)), emission=np.asarray(Le, float),
                    two_sided=two, material=np.zeros(n, np.int32), source=np.zeros(n, np.int32),
                    face=np.arange(n, dtype=np.int32), material_names=("m",), sources=("t",))


SQUARE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
LE = np.array([1.0, 2.0, 0.5])


def test_area_emitters_follow_the_protocol_and_the_registry():
    el = _elements([SQUARE], [[LE, [0, 0, 0]]])
    assert isinstance(AreaEmitters(el), Emitter)
    assert emitter_type("area") is AreaEmitters
    for name in EMITTER_TYPES:
        assert isinstance(emitter_type(name).of_scene(el), Emitter)


def test_unknown_emitter_type_lists_the_known_ones():
    from radiosity.scene.emitters import EMITTER_TYPES

    known = ", ".join(sorted(EMITTER_TYPES))  # area, sky, ...
    with pytest.raises(RadiosityError, match=rf"unknown emitter type 'ies': one of {known}$"):
        emitter_type("ies")
    assert known.startswith("area, ")


def test_power_is_le_pi_area_per_channel(rng):
    tri = np.array([[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [0.0, 3.0, 1.5]])
    quad = SQUARE * 0.5 + [0.0, 0.0, 2.0]
    Le = rng.random((3, 2, 3))
    Le[2] = 0.0
    el = _elements([tri, quad, SQUARE], Le, two_sided=[True, True, False])
    want = (Le * math.pi * el.area[:, None, None]).sum(axis=(0, 1))
    np.testing.assert_allclose(AreaEmitters(el).power(), want, rtol=1e-14)
    np.testing.assert_array_equal(AreaEmitters(el).emitting(), [True, True, False])
    # the power of the cornell box's lamp: a built-in scene read through the loader
    box = load_scene(scene_path("cornell-box"), settings=options()).elements
    lamp = box.emission.max(axis=(1, 2)) > 0
    want = math.pi * (box.emission[lamp] * box.area[lamp, None, None]).sum(axis=(0, 1))
    np.testing.assert_allclose(AreaEmitters(box).power(), want, rtol=1e-12)
    assert AreaEmitters(box).power().min() > 0


def test_area_emission_zeroes_one_sided_backs():
    emis = np.array([[[1.0, 2, 3], [4, 5, 6]], [[0, 0, 0], [7, 8, 9]]])
    Le = area_emission(emis, np.array([0, 1, 0]), np.array([True, False, False]))
    np.testing.assert_array_equal(Le, [[[1, 2, 3], [4, 5, 6]], [[0, 0, 0], [0, 0, 0]],
                                       [[1, 2, 3], [0, 0, 0]]])


@pytest.mark.parametrize("quad", [True, False])
def test_stratified_samples_give_the_exact_irradiance(quad):
    """E(x) = pi Le F_dx->emitter (Lambert's contour formula, core.exact) against the sampled
    sum of Le cos cos / r^2 dA, at points above, beside (the emitter partly behind the
    receiver's plane) and tilted; the error falls as the strata shrink."""
    polys = [SQUARE] if quad else [SQUARE[[0, 1, 2]], SQUARE[[0, 2, 3]]]
    el = _elements(polys, np.tile([[LE, [0, 0, 0]]], (len(polys), 1, 1)))
    em = AreaEmitters(el)
    pts = np.array([[0.3, 0.4, 0.5], [1.6, 0.5, 0.3], [-0.2, 1.3, 1.0], [0.5, 0.5, 0.2]])
    nrm = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.3, -0.4, -0.8], [0.2, 0.0, -1.0]])
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    exact = np.array([math.pi * polygon_point_form_factor(p, n, SQUARE) for p, n in zip(pts, nrm)])
    err = []
    for k in (8, 32):
        s = em.sample(k)
        assert len(s) == 2 * k * k  # two triangles either way
        np.testing.assert_allclose(s.weight.sum(), 1.0, rtol=1e-14)  # the strata tile the area
        E = irradiance(em, s, pts, nrm)
        np.testing.assert_allclose(E / LE, np.repeat(exact[:, None], 3, axis=1),
                                   rtol=2e-2 if k == 8 else 2e-3)
        err.append(np.abs(E[:, 0] / LE[0] - exact).max())
    assert err[1] < err[0] / 4
    # jittered strata: unbiased, close too
    E = irradiance(em, em.sample(32, np.random.default_rng(5)), pts, nrm)
    np.testing.assert_allclose(E[:, 1] / LE[1], exact, rtol=1e-2)


def test_one_sided_emitters_send_nothing_behind_and_shadows_count():
    el = _elements([SQUARE], [[LE, [0, 0, 0]]])
    em = AreaEmitters(el)
    s = em.sample(4)
    below = np.array([[0.5, 0.5, -0.5]])
    assert np.all(irradiance(em, s, below, [[0.0, 0.0, 1.0]]) == 0)
    above = np.array([[0.5, 0.5, 0.5]])
    E = irradiance(em, s, above, [[0.0, 0.0, -1.0]])
    half = np.arange(len(s)) % 2 == 0
    Eh = irradiance(em, s, above, [[0.0, 0.0, -1.0]], visible=half[None])
    assert np.all(Eh > 0.3 * E) and np.all(Eh < 0.7 * E)
    # two-sided: the back's own radiance
    back = np.array([0.25, 0.5, 1.0])
    el2 = _elements([SQUARE], [[LE, back]], two_sided=[True])
    E2 = irradiance(AreaEmitters(el2), s, below, [[0.0, 0.0, 1.0]])
    np.testing.assert_allclose(E2[0] / back, E[0] / LE, rtol=1e-12)


def test_irradiance_bound_holds_and_is_tight_far_away():
    el = _elements([SQUARE, SQUARE + [3.0, 0, 0]], [[LE, [0, 0, 0]], [2 * LE, [0, 0, 0]]])
    em = AreaEmitters(el)
    rng = np.random.default_rng(3)
    for lo, hi in (([0.2, 0.2, 0.1], [0.8, 0.8, 0.6]), ([-1.0, -1.0, -1.0], [4.0, 2.0, 2.0]),
                   ([0.0, 0.0, 20.0], [1.0, 1.0, 21.0])):
        lo, hi = np.array(lo), np.array(hi)
        bound = em.irradiance_bound(lo, hi)
        pts = lo + rng.random((200, 3)) * (hi - lo)
        nrm = rng.normal(size=(200, 3))
        nrm /= np.linalg.norm(nrm, axis=1)[:, None]
        E = irradiance(em, em.sample(8), pts, nrm)
        assert np.all(E.max(axis=0) <= bound)
    # far above both: the bound sum Le A / d^2 is within 2 % of the irradiance facing down
    far = irradiance(em, em.sample(8), np.array([[2.0, 0.5, 20.0]]), [[0.0, 0.0, -1.0]])[0]
    bound = em.irradiance_bound(np.array([2.0, 0.5, 20.0]), np.array([2.0, 0.5, 20.0]))
    assert np.all(far <= bound) and np.all(far > 0.98 * bound)


def test_a_scene_without_emitters_says_so():
    el = _elements([SQUARE], np.zeros((1, 2, 3)))
    em = AreaEmitters(el)
    assert not em.any() and not em.emitting().any()
    assert em.describe() == NO_EMITTER
    np.testing.assert_array_equal(em.power(), 0.0)
    assert len(em.sample(4)) == 0
    np.testing.assert_array_equal(em.irradiance_bound(np.zeros(3), np.ones(3)), 0.0)
    lit = AreaEmitters(_elements([SQUARE], [[LE, [0, 0, 0]]]))
    assert lit.describe().startswith("1 emitting elements, power (")
