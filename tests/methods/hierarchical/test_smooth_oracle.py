"""The link oracle with the emitters' light at points (radiosity.direct.oracle smooth, SPEC §10):
the links carry only R, the light after its first bounce, so a link weighs by how far its
source's R is from the scene's mean and relative to its receiver's own radiance
(params.smooth_weights). Its weights are never above the first round's (plain), the links are
coarser, and the answer stays where it was."""

from __future__ import annotations

import numpy as np
import pytest

from radiosity.errors import RadiosityError
from radiosity.methods.hierarchical.params import (ambient, direct_estimate, oracle_weights,
                                                   resolve_params, smooth_source)
from radiosity.scene.emitters import AreaEmitters
from radiosity.scene.load import load_scene
from radiosity.settings import options as settings_of
from helpers import prepared, scene_path


def test_smooth_weights_are_the_light_after_the_first_bounce_off_its_mean():
    """On the Cornell box: a source weighs |R - La| + floor La, never more than R (plain);
    a receiver lit directly above the scene's mean radiance lref weighs lref / its own
    radiance less, the others as before; the sources' weights fall by about half."""
    s = settings_of()
    el = load_scene(scene_path("cornell-box"), settings=s).elements
    est = direct_estimate(el, s.rays.offset)
    w0, l0, r0 = oracle_weights(el, "bf", est)
    w1, l1, r1 = oracle_weights(el, "bf", est, 0.25)
    _, _, La = ambient(el)
    assert r1 == r0 and La > 0
    np.testing.assert_allclose(l1, np.minimum(l0, np.abs(l0 - La) + 0.25 * La))
    assert (l1 <= l0).all() and (w1 <= w0 + 1e-15).all()
    A, live = el.area, w0[:, 0] > 0
    assert np.average((l1 / l0)[live, 0], weights=A[live]) < 0.7
    own = AreaEmitters(el).peak() + est + el.reflectance.max(axis=2) * La
    bright = (own > r0) & (w0 > 0)
    assert bright.any() and (~bright & (w0 > 0)).any()
    np.testing.assert_allclose(w1[bright], w0[bright] * r0 / own[bright])
    np.testing.assert_allclose(w1[~bright], w0[~bright])
    # the furnace's uniform R weighs only the floor
    np.testing.assert_allclose(smooth_source(np.full((3, 2), 99.0), 99.0, 0.25), 0.25 * 99.0)


def test_the_oracle_setting_reaches_the_link_params_and_refuses_bad_values():
    """smooth only with the emitters' light at points; plain (the default) keeps the first
    round's weights; a bad value is one line naming the setting."""
    el = load_scene(scene_path("cornell-box"), settings=settings_of()).elements
    smooth = settings_of(direct="points").replace({"direct.oracle": "smooth"})
    prm, _ = resolve_params(el, smooth)
    assert prm.smooth and prm.smooth_args() == 0.25
    assert resolve_params(el, smooth.replace({"direct.mode": "links"}))[0].smooth_args() is None
    assert resolve_params(el, settings_of(direct="points"))[0].smooth_args() is None
    with pytest.raises(RadiosityError, match="radiosity.direct.oracle must be one of smooth, plain"):
        settings_of(base=settings_of().replace({"direct.oracle": "coarse"}))
    with pytest.raises(RadiosityError, match="radiosity.direct.smooth-floor must be a number >= 0"):
        settings_of(base=settings_of().replace({"direct.smooth-floor": -0.5}))


def _links_and_means(client, out, oracle, eps):
    from radiosity.methods.hierarchical.links.master import compute_links
    from radiosity.runtime.store import RunStore
    from radiosity.stages.solve import run_solve
    from helpers import radiance

    s = settings_of(direct="points", epsilon=eps).replace({"direct.oracle": oracle})
    lf = compute_links(out, client, s, progress=False)
    run_solve(out, client, s.replace({"solve.solver": "cg", "solve.tol": 1e-10}),
              method="hierarchical", progress=False)
    rs = RunStore(out)
    part, L = rs.load_partition(), radiance(out)[:, 0, :]
    n = len(part.offsets) - 1
    w = np.zeros((n, 3))
    np.add.at(w, part.orig, part.area[:, None] * L)
    return lf.links, w / np.bincount(part.orig, part.area, n)[:, None]


@pytest.mark.slow
def test_smooth_links_are_coarser_and_the_surfaces_stay(client, tmp_path):
    """The Cornell box (24^2, emitters' light at points, epsilon 2e-4): the smooth oracle keeps
    fewer links than the plain one, and every surface's mean stays within 0.5 % of the plain
    oracle's (a finer answer at the same epsilon)."""
    got = {}
    for oracle in ("plain", "smooth"):
        out = prepared(client, tmp_path, scene_path("cornell-box"), 24, name=oracle,
                       visibility=False)
        got[oracle] = _links_and_means(client, out, oracle, 2e-4)
    (n0, m0), (n1, m1) = got["plain"], got["smooth"]
    gap = np.abs(m1 / m0 - 1)[m0.max(axis=1) > 0]
    print(f"cornell 24^2 points: links plain {n0}, smooth {n1} ({n1 / n0:.2f}); surfaces within "
          f"{gap.max():.4f}")
    assert n1 < 0.85 * n0
    assert gap.max() < 0.005


def test_the_furnace_stays_exact_with_the_smooth_oracle(client, tmp_path):
    """Closed cube, Le = 1, rho = 0.99, the emitters' light at points and the smooth oracle (a
    uniform R weighs only the floor): Le + R = 100 to 1e-6 after the final gather."""
    import os

    from radiosity.methods.hierarchical.links.master import compute_links
    from radiosity.stages.solve import run_solve
    from helpers import radiance

    cube = scene_path("furnace-cube")
    src = open(cube).read().replace("reflectance = [0.5, 0.5, 0.5]", "reflectance = [0.99, 0.99, 0.99]")
    src = src.replace('path = "furnace-cube.obj"',
                      f'path = "{os.path.join(os.path.dirname(cube), "furnace-cube.obj")}"')
    (tmp_path / "furnace.toml").write_text(src)
    out = prepared(client, tmp_path, str(tmp_path / "furnace.toml"), 8, visibility=False)
    s = settings_of(direct="points", epsilon=0.3).replace({"direct.oracle": "smooth"})
    compute_links(out, client, s, progress=False)
    fig = run_solve(out, client, s.replace({"solve.solver": "cg", "solve.tol": 1e-12}),
                    method="hierarchical", progress=False)
    assert fig["converged"] and fig["direct"] == "points"
    np.testing.assert_allclose(radiance(out)[:, 0, :], 100.0, rtol=1e-6)
