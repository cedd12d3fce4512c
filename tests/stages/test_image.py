"""Image and export stage: camera-facing side, filters, sRGB, EXR/PNG, meshes, WebGL viewer.

Real preprocess (on the session's LocalCluster) into real Zarr stores, a fabricated solution
(written the way the solver writes it), real OpenEXR, trimesh and headless Chromium.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import warnings

import numpy as np
import pytest
from PIL import Image

from radiosity.stages import image as render
from radiosity.stages.preprocess import preprocess
from radiosity.scene.load import load_scene
from radiosity.runtime.store import RunStore
from helpers import CHROMIUM, scene_path, write_scene
from radiosity.settings import options as settings_of

# Three vertical unit panels in the plane z = 0, the camera in front at z = -3 looking +z.
# "twosided" (left) and "onesided" (right) face +z, away from the camera: we see their backs.
# "facing" (bottom) is wound the other way: its front (-z) faces the camera.
PANELS = """
v -1.1 0.1 0
v -0.1 0.1 0
v -0.1 1.1 0
v -1.1 1.1 0
v 0.1 0.1 0
v 1.1 0.1 0
v 1.1 1.1 0
v 0.1 1.1 0
v -0.5 -1.1 0
v 0.5 -1.1 0
v 0.5 -0.1 0
v -0.5 -0.1 0
usemtl twosided
f 1 2 3 4
usemtl onesided
f 5 6 7 8
usemtl facing
f 12 11 10 9
"""
PANELS_TOML = """
[material.twosided]
reflectance = [0.2, 0.3, 0.4]
two_sided = true
back_reflectance = [0.9, 0.1, 0.1]
[material.onesided]
reflectance = [0.5, 0.5, 0.5]
[material.facing]
reflectance = [0.1, 0.6, 0.2]
emission = [1.0, 0.0, 0.0]
"""
PANELS_CAMERA = """
[camera]
position = [0.0, 0.0, -3.0]
look_at = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov_y = 50.0
resolution = [16, 12]
"""


def fabricate_solution(run_dir: str) -> np.ndarray:
    """A deterministic stand-in for the solver: L = Le + rho of the original, both sides."""
    rs = RunStore(run_dir, "r+")
    part, el = rs.load_partition(), rs.load_elements()
    L = el.emission[part.orig] + el.reflectance[part.orig]
    rs.write_arrays("solution", {"radiance": L})
    return L


def _prepare(client, path, out, resolution, k):
    preprocess(load_scene(path, resolution=resolution, settings=settings_of()), str(out), client,
               settings_of(subpixel=k), progress=False)
    fabricate_solution(str(out))
    return str(out)


@pytest.fixture(scope="module")
def panels_run(client, tmp_path_factory):
    d = tmp_path_factory.mktemp("panels")
    path = write_scene(d, PANELS, PANELS_TOML, camera=PANELS_CAMERA)
    return _prepare(client, path, d / "run", None, 2)


@pytest.fixture(scope="module")
def cornell_run(client, tmp_path_factory):
    d = tmp_path_factory.mktemp("cornell")
    with warnings.catch_warnings():  # the published red wall is non-planar: split, warned
        warnings.simplefilter("ignore")
        return _prepare(client, scene_path("cornell-box"), d / "run", 16, 2)


def _load(run_dir):
    rs = RunStore(run_dir)
    return (rs, rs.load_partition(), rs.load_elements(), rs.load_camera(),
            rs.read_arrays("raster"), rs.read_arrays("solution")["radiance"])


# ----------------------------------------------------------------------------- fine image

def test_pixel_radiance_shows_the_side_facing_the_camera(panels_run):
    rs, part, el, cam, raster, L = _load(panels_run)
    k = rs.attrs["subpixel"]
    fine = render.pixel_radiance(part, el, cam, raster["sub"], L)
    assert fine.shape == (cam.height * k, cam.width * k, 3) and fine.dtype == np.float64
    names = [el.material_names[m] for m in el.material]
    expect = {"twosided": [0.9, 0.1, 0.1],   # seen from behind: its back
              "onesided": [0.0, 0.0, 0.0],   # seen from behind: black
              "facing": [1.1, 0.6, 0.2]}     # seen from the front: Le + rho
    for i, name in enumerate(names):
        px = raster["orig"] == i
        assert px.sum() > 4, f"{name} is not in the image"
        np.testing.assert_allclose(fine[px], np.broadcast_to(expect[name], (px.sum(), 3)))
    np.testing.assert_array_equal(fine[raster["sub"] < 0], 0.0)  # misses are black
    assert (raster["sub"] < 0).any()
    side = render.facing_side(part, cam)
    assert set(side[el.two_sided[part.orig]]) == {1}


def test_pixel_radiance_ignores_the_back_of_one_sided_elements(panels_run):
    rs, part, el, cam, raster, L = _load(panels_run)
    junk = L.copy()
    junk[:, 1] += 7.0  # a solver that left garbage on one-sided backs
    fine = render.pixel_radiance(part, el, cam, raster["sub"], junk)
    one = ~el.two_sided
    for i in np.flatnonzero(one):
        seen = render.facing_side(part, cam)[part.orig == i]
        px = raster["orig"] == i
        if (seen == 1).all():
            np.testing.assert_array_equal(fine[px], 0.0)
    with pytest.raises(Exception, match="solution"):
        render.pixel_radiance(part, el, cam, raster["sub"], L[:-1])


# ----------------------------------------------------------------------------- filters

def test_box_downsample_constant_and_hand_computed_mean(rng):
    const = np.full((12, 9, 3), 0.37)
    for k in (1, 3):
        out = render.downsample(const, k, "box")
        assert out.shape == (12 // k, 9 // k, 3)
        np.testing.assert_allclose(out, 0.37, rtol=1e-15)
    a = rng.random((4, 6, 3))
    out = render.downsample(a, 2, "box")
    assert out.shape == (2, 3, 3)
    for r in range(2):
        for c in range(3):
            hand = (a[2 * r, 2 * c] + a[2 * r, 2 * c + 1]
                    + a[2 * r + 1, 2 * c] + a[2 * r + 1, 2 * c + 1]) / 4
            np.testing.assert_allclose(out[r, c], hand, rtol=1e-14)
    with pytest.raises(render.RenderError):
        render.downsample(a, 4, "box")  # 4 does not divide 6
    with pytest.raises(render.RenderError, match="filter"):
        render.downsample(a, 2, "lanczos")


def test_gaussian_preserves_the_mean_and_is_centred(rng):
    y, x = np.mgrid[0:48, 0:64] + 0.5
    smooth = np.stack([1 + 0.5 * np.sin(x / 9.0) * np.cos(y / 7.0), 2 + 0.01 * x, 0.3 + 0 * x], -1)
    for k in (1, 2, 4):
        out = render.downsample(smooth, k, "gaussian", sigma=1.5)
        assert out.shape == (48 // k, 64 // k, 3)
        np.testing.assert_allclose(out.mean(axis=(0, 1)), smooth.mean(axis=(0, 1)), rtol=2e-3)
        np.testing.assert_allclose(out[..., 2], 0.3, rtol=1e-13)  # a constant stays constant
    # K = 1 is an ordinary blur; K even samples the block centres without a half-pixel shift
    img = rng.random((20, 16, 3))
    out1 = render.downsample(img, 1, "gaussian", sigma=1.5)
    np.testing.assert_allclose(out1.mean(axis=(0, 1)), img.mean(axis=(0, 1)), rtol=1e-12)
    sym = img + img[:, ::-1]
    out2 = render.downsample(sym, 2, "gaussian", sigma=2.0)
    np.testing.assert_allclose(out2, out2[:, ::-1], atol=1e-14)
    with pytest.raises(render.RenderError, match="sigma"):
        render.downsample(img, 2, "gaussian", sigma=0.0)


def test_gaussian_with_k1_equals_scipy_reflect_filter(rng):
    from scipy import ndimage  # a dependency: never skipped
    img = rng.random((17, 23, 3))
    for sigma in (0.8, 1.5, 3.0):
        ours = render.downsample(img, 1, "gaussian", sigma=sigma)
        ref = ndimage.gaussian_filter(img, sigma=(sigma, sigma, 0), mode="reflect", truncate=4.0)
        np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=1e-14)


# ----------------------------------------------------------------------------- colour and files

def test_srgb_curve_and_tonemap():
    enc = render.srgb_encode(np.array([0.0, 1.0, 0.0031308, 0.5, -1.0, 3.0]))
    np.testing.assert_allclose(enc[:2], [0.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(enc[2], 12.92 * 0.0031308, rtol=1e-12)
    # the two branches meet at the knee (continuity of the standard curve)
    np.testing.assert_allclose(1.055 * 0.0031308 ** (1 / 2.4) - 0.055, 12.92 * 0.0031308, rtol=1e-4)
    np.testing.assert_allclose(enc[3], 1.055 * 0.5 ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(enc[4:], [0.0, 1.0])  # clipped
    img = np.zeros((4, 5, 3))
    img[1:] = 2.0
    t = render.tonemap(img, exposure=0.25)
    assert t.dtype == np.uint8 and t.shape == (4, 5, 3)
    assert t[0].max() == 0 and np.all(t[1:] == round(255 * (1.055 * 0.5 ** (1 / 2.4) - 0.055)))
    # automatic exposure: the 99th percentile of the lit pixels' luminance -> 0.9 (linear)
    assert render.auto_exposure(img) == pytest.approx(0.45)
    np.testing.assert_array_equal(render.tonemap(img), render.tonemap(img, 0.45))
    assert render.auto_exposure(np.zeros((2, 2, 3))) == 1.0


def test_exr_round_trip_is_exact_and_png_is_written(tmp_path, rng):
    img = (rng.random((7, 11, 3)) * 100).astype(np.float32)
    img[0, 0] = [0.0, 1e-30, 65504.5]
    fn = str(tmp_path / "a.exr")
    render.write_exr(fn, img)
    back = render.read_exr(fn)
    assert back.dtype == np.float32 and back.shape == img.shape
    np.testing.assert_array_equal(back, img)
    render.write_exr(fn, img.astype(np.float64) * 2)  # float64 is written as float32
    np.testing.assert_array_equal(render.read_exr(fn), img * 2)
    png = str(tmp_path / "a.png")
    img8 = render.tonemap(img, 0.01)
    render.write_png(png, img8)
    with Image.open(png) as im:
        assert im.mode == "RGB" and im.size == (11, 7)
        np.testing.assert_array_equal(np.asarray(im), img8)
    with pytest.raises(render.RenderError, match="no such"):
        render.read_exr(str(tmp_path / "missing.exr"))
    with pytest.raises(render.RenderError, match="OpenEXR"):
        render.read_exr(png)


# ----------------------------------------------------------------------------- the stage

def _bytes(fn):
    with open(fn, "rb") as f:
        return f.read()


def test_render_outputs_writes_deterministic_images(cornell_run):
    rs, part, el, cam, raster, L = _load(cornell_run)
    f1 = render.render_outputs(cornell_run, settings=settings_of())
    exr, png = _bytes(f1["image_exr"]), _bytes(f1["image_png"])
    f2 = render.render_outputs(cornell_run, settings=settings_of())
    assert _bytes(f2["image_exr"]) == exr and _bytes(f2["image_png"]) == png
    assert f1["exposure"] == f2["exposure"] and f1["exposure_auto"]  # yaml: exposure null
    assert (f1["width"], f1["height"]) == (cam.width, cam.height) == (16, 16)
    img = render.read_exr(f1["image_exr"])
    # the default: each of the 2 x 2 fine pixels (subpixel 2) the mean of 2 x 2 rays over its area
    assert (f1["sampling"], f1["area_samples"], f1["rays"]) == ("area", 2, 32 * 32 * 4)
    rays = render.sample_raster(part, el, cam, 2, 2, 1e-6)
    fine = render.pixel_radiance(part, el, cam, rays, L)
    # fine pixels whose rays see two planes or materials or values far apart (and their
    # neighbours): the mean of ceil(edge-samples 12 / 2)^2 = 36 rays over their area, then
    # more where the error estimate says so (pixels.refine)
    from radiosity.stages import pixels
    from radiosity.tracing.rays import RayCaster

    lum = pixels.seen_radiance(part, el, cam, L)
    plane = pixels.plane_ids(el)
    busy = pixels.busy_pixels(rays, part, plane, lum.sum(1))
    assert (busy >= pixels.edge_pixels(rays, part, plane)).all()
    rows, cols = np.nonzero(busy)
    assert 0 < len(rows) < 32 * 32
    assert (f1["edge_pixels"], f1["edge_rays"]) == (len(rows), 36 * len(rows))
    rc = RayCaster(el.verts, el.nverts, 1e-6)
    before = fine.copy()
    levels = pixels.refine(part, el, cam, 2, lum, fine, rays, 6, rc)
    assert levels[0] == (6, len(rows)) and [list(v) for v in levels[1:]] == f1["refined"]
    assert f1["refined_rays"] == sum(n * k * k for k, n in levels[1:])
    assert np.abs(fine - before).max() > 0  # they change the image
    want = render.downsample(fine, 2, "box")
    np.testing.assert_array_equal(img, want.astype(np.float32))
    # the seed's point samples: the ID raster of the fine pixels' centres
    fp = render.render_outputs(cornell_run, sampling="point", settings=settings_of())
    point = render.downsample(render.pixel_radiance(part, el, cam, raster["sub"], L), 2, "box")
    np.testing.assert_array_equal(render.read_exr(fp["image_exr"]), point.astype(np.float32))
    assert (fp["sampling"], fp["rays"]) == ("point", 0)
    with pytest.raises(render.RenderError, match="render.sampling must be one of area, point"):
        render.render_outputs(cornell_run, sampling="centre", settings=settings_of())
    f1 = render.render_outputs(cornell_run, settings=settings_of())
    np.testing.assert_allclose(f1["mean_radiance"], want.reshape(-1, 3).mean(0))
    with Image.open(f1["image_png"]) as im:
        np.testing.assert_array_equal(np.asarray(im), render.tonemap(want, f1["exposure"]))
    for key in ("mesh_glb", "mesh_ply", "viewer_html"):
        assert os.path.getsize(f1[key]) > 0
    report = json.load(open(os.path.join(cornell_run, "report.json")))
    assert report["render"]["exposure"] == f1["exposure"]
    # explicit parameters win over the config
    f3 = render.render_outputs(cornell_run, filter="gaussian", sigma=1.2, exposure=2.0,
                               settings=settings_of())
    got = (f3["filter"], f3["sigma"], f3["exposure"], f3["exposure_auto"])
    assert got == ("gaussian", 1.2, 2.0, False)
    assert _bytes(f3["image_exr"]) != exr
    with pytest.raises(render.RenderError, match="exposure"):
        render.render_outputs(cornell_run, exposure=-1.0, settings=settings_of())


def test_render_without_solution_says_what_to_run(client, tmp_path):
    path = write_scene(tmp_path, PANELS, PANELS_TOML, camera=PANELS_CAMERA)
    out = str(tmp_path / "run")
    preprocess(load_scene(path, settings=settings_of()), out, client, settings_of(),
               progress=False)
    with pytest.raises(Exception, match="solution"):
        render.render_outputs(out, settings=settings_of())


def test_mesh_glb_and_ply_load_back_with_flat_colours(cornell_run, tmp_path):
    import trimesh

    rs, part, el, cam, raster, L = _load(cornell_run)
    e = 0.8
    glb, ply = str(tmp_path / "m.glb"), str(tmp_path / "m.ply")
    info = render.export_mesh(glb, ply, part, L, e)
    ntri = int(np.sum(part.nverts.astype(int) - 2))
    assert info["triangles"] == info["faces"] == ntri
    tri_sub, tri_v = render.triangles(part)
    front = L[tri_sub, 0]

    g = trimesh.load(glb, force="mesh", process=False, skip_materials=True)
    assert len(g.faces) == ntri
    np.testing.assert_allclose(g.vertices.reshape(-1, 3, 3), tri_v, rtol=1e-6, atol=1e-3)
    # COLOR_0 is the linear exposed colour (glTF's colour space), one colour per face
    vc = g.visual.vertex_colors[:, :3].astype(int).reshape(-1, 3, 3)
    assert np.all(vc == vc[:, :1])
    np.testing.assert_allclose(vc[:, 0], np.clip(front * e, 0, 1) * 255, atol=1.0)
    np.testing.assert_allclose(g.vertex_attributes["_RADIANCE"][::3], front, rtol=1e-6)
    assert len(np.unique(vc[:, 0], axis=0)) >= 4  # red, green, white walls, light
    with open(glb, "rb") as f:
        raw = f.read()
    doc = json.loads(raw[20:20 + int.from_bytes(raw[12:16], "little")])
    prim = doc["meshes"][0]["primitives"][0]
    assert "COLOR_0" in prim["attributes"] and prim["material"] == 0
    assert "KHR_materials_unlit" in doc["materials"][0]["extensions"]

    p = trimesh.load(ply, process=False)
    assert len(p.faces) == ntri
    pc = p.visual.vertex_colors[:, :3].reshape(-1, 3, 3)
    np.testing.assert_array_equal(pc[:, 0], render.tonemap(front, e))
    face = p.metadata["_ply_raw"]["face"]["data"]
    np.testing.assert_allclose(face["radiance_g"], front[:, 1], rtol=1e-6)


def test_mesh_two_sided_elements_get_back_faces(panels_run, tmp_path):
    import trimesh

    rs, part, el, cam, raster, L = _load(panels_run)
    two = el.two_sided[part.orig]
    glb, ply = str(tmp_path / "m.glb"), str(tmp_path / "m.ply")
    info = render.export_mesh(glb, ply, part, L, 1.0, two_sided=two)
    ntri = int(np.sum(part.nverts.astype(int) - 2))
    nback = int(np.sum(part.nverts[two].astype(int) - 2))
    assert nback > 0 and info["faces"] == ntri + nback
    for fn in (glb, ply):
        m = trimesh.load(fn, force="mesh", process=False, skip_materials=True)
        assert len(m.faces) == ntri + nback
        back = m.vertices[3 * ntri:].reshape(-1, 3, 3)
        n = np.cross(back[:, 1] - back[:, 0], back[:, 2] - back[:, 0])
        assert np.all(n[:, 2] < 0)  # reversed: the back faces -z, towards the camera
        col = m.visual.vertex_colors[3 * ntri:, :3]
        assert np.all(col[:, 0] > col[:, 1])  # the red back material


# ----------------------------------------------------------------------------- viewer

def _strip_data(page: str) -> str:
    return re.sub(r'<script type="application/octet-stream"[^>]*>[^<]*</script>', "", page)


def test_viewer_page_is_self_contained(cornell_run, tmp_path):
    rs, part, el, cam, raster, L = _load(cornell_run)
    fn = str(tmp_path / "v.html")
    info = render.write_viewer(fn, part, L, 1.0, "Cornell <box>", camera=cam)
    page = open(fn, encoding="utf-8").read()
    code = _strip_data(page)
    assert "http" not in code.lower() and "src=" not in code and "href" not in code
    assert "Cornell &lt;box&gt;" in code and f"{len(part):,} elements" in code
    assert info["triangles"] == int(np.sum(part.nverts.astype(int) - 2)) and info["stride"] == 1
    # a mesh above the limit is thinned, and the page says so
    render.write_viewer(fn, part, L, 1.0, "big", max_triangles=100)
    page = open(fn, encoding="utf-8").read()
    assert "large mesh: showing every" in page


@pytest.mark.needs("chromium")
def test_viewer_draws_in_headless_chromium(cornell_run, tmp_path):
    figures = render.render_outputs(cornell_run, settings=settings_of())
    shot = tmp_path / "shot.png"
    profile = tmp_path / "profile"
    profile.mkdir()
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={profile}", "--use-gl=swiftshader",
           "--enable-unsafe-swiftshader", "--window-size=800,600", f"--screenshot={shot}",
           "--dump-dom", "--virtual-time-budget=5000", "file://" + figures["viewer_html"]]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=90)
    shutil.rmtree(profile, ignore_errors=True)
    m = re.search(r'<span id="status">([^<]*)</span>', r.stdout)
    assert m, f"no DOM from chromium (rc {r.returncode}): {r.stderr[-2000:]}"
    assert m.group(1) == f"ok {figures['triangles']} triangles", m.group(1)
    with Image.open(shot) as im:
        px = np.asarray(im.convert("RGB")).astype(int)
    assert px.shape[:2] == (600, 800)
    below = px[120:]  # under the caption
    background = np.array([30, 34, 39])  # the page's clear colour #1e2227
    drawn = np.abs(below - background).sum(-1) > 12
    assert drawn.mean() > 0.15, f"only {drawn.mean():.1%} of the canvas is drawn"
    colours = {tuple(c // 16) for c in below[drawn]}
    assert len(colours) >= 3  # white walls, red, green at least
    reds = below[..., 0] > below[..., 1] + 40  # the left wall
    greens = below[..., 1] > below[..., 0] + 20  # the right wall
    assert reds.sum() > 500 and greens.sum() > 500


def _viewer_shot(html: str, fragment: str, out, tmp_path) -> np.ndarray:
    """A headless Chromium screenshot (800 x 600) of a viewer page at view `fragment`."""
    profile = tmp_path / f"profile-{out.stem}"
    profile.mkdir()
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--disable-sync", f"--user-data-dir={profile}", "--use-gl=swiftshader",
           "--enable-unsafe-swiftshader", "--window-size=800,600", f"--screenshot={out}",
           "--dump-dom", "--virtual-time-budget=5000", f"file://{html}#{fragment}"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=90)
    shutil.rmtree(profile, ignore_errors=True)
    assert "ok " in r.stdout, f"the page did not draw (rc {r.returncode}): {r.stderr[-2000:]}"
    with Image.open(out) as im:
        return np.asarray(im.convert("RGB")).astype(int)


def _isolated_steps(px: np.ndarray) -> tuple[int, int]:
    """Blocks in a screenshot: neighbouring pixels (rows and columns, under the caption) that
    differ by 3 to 40 levels with no change (at most 1 level) on either side, as at the border
    of two flat-shaded blocks (a smooth gradient changes by 0-1 level a pixel; edges between
    surfaces are the same in both pages compared). Returns (steps, drawn pixels)."""
    b = px[120:]
    steps = 0
    for a in (b, b.transpose(1, 0, 2)):
        d = np.abs(np.diff(a, axis=1)).max(-1)
        mid, before, after = d[:, 1:-1], d[:, :-2], d[:, 2:]
        steps += int(((mid >= 3) & (mid <= 40) & (before <= 1) & (after <= 1)).sum())
    drawn = int((np.abs(b - np.array([30, 34, 39])).sum(-1) > 12).sum())
    return steps, drawn


@pytest.fixture(scope="module")
def solved_cornell(tmp_path_factory):
    """The Cornell box at 32^2 solved by the default (hierarchical) method, from its camera."""
    import radiosity

    out = tmp_path_factory.mktemp("solved") / "run"
    radiosity.render(scene_path("cornell-box"), out=str(out), resolution=32, method="hierarchical")
    return str(out)


@pytest.mark.needs("chromium")
@pytest.mark.parametrize("fragment", ["yaw=0&pitch=-60", "yaw=160&pitch=-20"])
def test_viewer_has_no_blocks_where_the_camera_did_not_look(solved_cornell, tmp_path, fragment):
    """The viewer from above (the blocks' tops, the floor behind them) and from behind (the
    blocks' back faces): surfaces the run's camera never saw, so their sub-elements are
    coarse. With the smooth vertex radiance (the page render_outputs writes) fewer than 1 % of
    the drawn pixels sit on a step between flat blocks, and at most a fifth of what the same
    page with flat colours per sub-element shows (about 5 % there)."""
    from radiosity.core.smooth import smooth_mesh

    rs, part, el, cam, raster, L = _load(solved_cornell)
    two = np.asarray(el.two_sided, bool)[part.orig]
    counts = {}
    for kind, smooth in (("smooth", smooth_mesh(part, el, L)), ("flat", None)):
        html = str(tmp_path / f"{kind}.html")
        render.write_viewer(html, part, L, None, "t", camera=cam, two_sided=two, smooth=smooth)
        counts[kind] = _isolated_steps(_viewer_shot(html, fragment, tmp_path / f"{kind}.png",
                                                    tmp_path))
    (smooth_steps, drawn), (flat_steps, _) = counts["smooth"], counts["flat"]
    assert drawn > 0.15 * 680 * 800, drawn
    assert smooth_steps < 0.01 * drawn, counts
    assert smooth_steps < 0.2 * flat_steps, counts


@pytest.mark.needs("chromium")
def test_viewer_lux_mode_draws_the_illuminance(cornell_run, tmp_path):
    """viewer.html's lux mode (key L, or #lux=1): the tables' illuminance per sub-element in
    false colour with a scale; the page still draws every triangle."""
    figures = render.render_outputs(cornell_run, settings=settings_of())
    page = open(figures["viewer_html"], encoding="utf-8").read()
    assert '"lux": true' in page and "L: illuminance (lx)" in page
    shots = {}
    for frag in ("", "lux=1"):
        out = tmp_path / f"shot{len(shots)}.png"
        profile = tmp_path / f"profile{len(shots)}"
        profile.mkdir()
        cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
               "--no-first-run", "--disable-background-networking", "--disable-component-update",
               "--disable-sync", f"--user-data-dir={profile}", "--use-gl=swiftshader",
               "--enable-unsafe-swiftshader", "--window-size=800,600", f"--screenshot={out}",
               "--dump-dom", "--virtual-time-budget=5000",
               f"file://{figures['viewer_html']}#{frag}"]
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=90)
        shutil.rmtree(profile, ignore_errors=True)
        assert f"ok {figures['triangles']} triangles" in r.stdout, r.stderr[-2000:]
        assert f'data-mode="{"lux" if frag else "radiance"}"' in r.stdout
        with Image.open(out) as im:
            shots[frag] = np.asarray(im.convert("RGB")).astype(int)[120:]
    # the false colours differ from the radiance colours over most of the drawn canvas
    assert (np.abs(shots["lux=1"] - shots[""]).sum(-1) > 30).mean() > 0.3
