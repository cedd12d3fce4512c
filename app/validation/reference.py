"""Ground truth from Mitsuba 3: the scene the project loads, path-traced by Mitsuba's `path`
integrator (unbiased; SPEC §1 units: radiance in W sr^-1 m^-2, linear RGB).

The conversion (`mitsuba_scene`) starts from the project's own loaded Scene, so the two renderers
see the same elements, materials, emission, sides and camera. The standard error comes from K
independent passes (different sampler seeds): per pixel, std over passes (ddof 1) / sqrt(K).
"""

from __future__ import annotations

import glob
import json
import math
import os
import re
import time

import numpy as np

from radiosity.errors import RadiosityError
from radiosity.core.bundles import Camera, Scene
from radiosity.scene.emitters import AreaEmitters
from radiosity.settings import Settings

INSTALL = "pip install -e '.[reference]'"
#: drjit's LLVM backend needs this major version or newer (older ones crash in its kernels).
MIN_LLVM = 16
TWOSIDED_EMITTER = "radiosity_twosided_area"


class ReferenceError(RadiosityError):
    """Mitsuba missing, a variant that cannot run, or a scene Mitsuba cannot represent."""


# ----------------------------------------------------------------------------- Mitsuba itself

_LLVM_GLOBS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib",
               "/usr/local/lib", "/usr/lib/llvm-*/lib", "/opt/homebrew/opt/llvm/lib",
               "/usr/local/opt/llvm/lib")


def find_libllvm(min_major: int = MIN_LLVM) -> str | None:
    """The newest libLLVM shared library of major version >= min_major in the usual places
    (Debian's libllvm19: /usr/lib/<arch>/libLLVM.so.19.1), or None."""
    best = None
    for d in _LLVM_GLOBS:
        for path in glob.glob(os.path.join(d, "libLLVM*")):
            m = re.fullmatch(r"libLLVM(?:\.so\.|-)(\d+)(?:[.\w-]*)", os.path.basename(path)) or \
                re.fullmatch(r"libLLVM\.(\d+)\.dylib", os.path.basename(path))
            if m and int(m.group(1)) >= min_major and os.path.isfile(path):
                key = (int(m.group(1)), path)
                best = key if best is None or key > best else best
    return None if best is None else best[1]


_LOADED: dict = {}


def load_mitsuba(variant: str = "auto", echo=None):
    """Import Mitsuba 3 and select its variant (reference.variant): `auto` takes llvm_ad_rgb
    when drjit's LLVM backend has libLLVM >= 16 (DRJIT_LIBLLVM_PATH is set to the newest one found when it is unset), otherwise scalar_rgb,
    said in one line through `echo`.

    Returns (mitsuba module, variant name).
    """
    if variant not in ("auto", "llvm_ad_rgb", "scalar_rgb"):
        raise ReferenceError(f"reference.variant {variant!r}: use auto, llvm_ad_rgb or scalar_rgb")
    if _LOADED.get("asked") == variant:
        return _LOADED["mi"], _LOADED["variant"]
    if variant != "scalar_rgb" and not os.environ.get("DRJIT_LIBLLVM_PATH"):
        lib = find_libllvm()
        if lib:
            os.environ["DRJIT_LIBLLVM_PATH"] = lib
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError:
        raise ReferenceError(f"Mitsuba 3 is not installed: {INSTALL}") from None
    chosen = "scalar_rgb"
    if variant != "scalar_rgb":
        why = None
        try:
            mi.set_variant("llvm_ad_rgb")
            major = int(dr.detail.llvm_version()[0])
            if major < MIN_LLVM:
                why = f"libLLVM {major} is too old (drjit needs {MIN_LLVM} or newer)"
            else:
                chosen = "llvm_ad_rgb"
        except (ImportError, AttributeError, RuntimeError) as e:
            why = f"drjit's LLVM backend did not start ({str(e).splitlines()[0][:80]})"
        if why and variant == "llvm_ad_rgb":
            raise ReferenceError(f"Mitsuba variant llvm_ad_rgb: {why}; install libllvm19 "
                                 "(apt-get install libllvm19) or set DRJIT_LIBLLVM_PATH")
        if why and echo:
            echo(f"Mitsuba: {why}; using scalar_rgb (slower; apt-get install libllvm19 "
                 "or set DRJIT_LIBLLVM_PATH for llvm_ad_rgb)")
    mi.set_variant(chosen)
    mi.set_log_level(mi.LogLevel.Warn)
    _register_twosided_emitter(mi, dr)
    _LOADED.update(asked=variant, mi=mi, variant=chosen)
    return mi, chosen


def mitsuba_version() -> str:
    import mitsuba as mi

    return mi.__version__


def _register_twosided_emitter(mi, dr) -> None:
    """`radiosity_twosided_area`: Mitsuba's `area` emitter on both sides of a shape, radiance
    `front` where the shape's normal points and `back` on the other side (Mitsuba's `area` is
    front-only). Direction sampling is the shape's own (uniform by area, converted to solid angle
    with |cos|), on either side."""

    class TwoSidedArea(mi.Emitter):
        def __init__(self, props):
            mi.Emitter.__init__(self, props)
            self.front = mi.Color3f(*[props[f"front_{c}"] for c in "rgb"])
            self.back = mi.Color3f(*[props[f"back_{c}"] for c in "rgb"])
            self.m_flags = mi.EmitterFlags.Surface

        def _side(self, cos_out):
            """Radiance leaving along a direction with cosine cos_out to the normal."""
            return dr.select(cos_out > 0, self.front, dr.select(cos_out < 0, self.back, mi.Color3f(0)))

        def eval(self, si, active=True):
            return dr.select(active, self._side(mi.Frame3f.cos_theta(si.wi)), mi.Color3f(0))

        def sample_direction(self, it, sample, active=True):
            ds = self.get_shape().sample_direction(it, sample, active)
            cos_out = -dr.dot(ds.d, ds.n)  # light travels from the shape towards `it`
            active &= (cos_out != 0) & (ds.pdf != 0)
            ds.emitter = mi.EmitterPtr(self)
            spec = self._side(cos_out) / dr.select(active, ds.pdf, 1.0)
            return ds, dr.select(active, spec, mi.Color3f(0))

        def pdf_direction(self, it, ds, active=True):
            active &= dr.dot(ds.d, ds.n) != 0
            return dr.select(active, self.get_shape().pdf_direction(it, ds, active), 0.0)

        def eval_direction(self, it, ds, active=True):
            return dr.select(active, self._side(-dr.dot(ds.d, ds.n)), mi.Color3f(0))

        def sample_position(self, time_, sample, active=True):
            ps = self.get_shape().sample_position(time_, sample, active)
            return ps, dr.select(active, mi.Float(1.0), 0.0)

        def pdf_position(self, ps, active=True):
            return self.get_shape().pdf_position(ps, active)

        def sample_ray(self, time_, sample1, sample2, sample3, active=True):
            raise NotImplementedError("radiosity_twosided_area: light tracing is not supported")

        def sample_wavelengths(self, si, sample, active=True):
            return mi.Wavelength(0), self._side(mi.Frame3f.cos_theta(si.wi))

        def bbox(self):
            return self.get_shape().bbox()

        def traverse(self, callback):
            pass

        def to_string(self):
            return f"TwoSidedArea[front={self.front}, back={self.back}]"

    mi.register_emitter(TWOSIDED_EMITTER, lambda props: TwoSidedArea(props))


# ----------------------------------------------------------------------------- the conversion

def path_depth(scene: Scene, truncation: float) -> tuple[int, float]:
    """(D, rho_max): the path integrator's max_depth D, the smallest with rho_max^D <= truncation
    (at least 1: paths of one segment see the emitters), and the scene's largest reflectance.
    truncation: reference.truncation."""
    truncation = float(truncation)
    rho = float(np.max(scene.elements.reflectance))
    if rho <= 0.0:
        return 1, rho
    return max(1, math.ceil(math.log(truncation) / math.log(rho) - 1e-12)), rho


def to_world(camera: Camera) -> np.ndarray:
    """(4, 4) float64 camera-to-world matrix for Mitsuba's perspective sensor: columns -x, y, z
    (Mitsuba's camera space has +x to the image's left, +y up, +z the viewing direction) and
    the centre. Built from the basis itself, not look_at, so no handedness is guessed."""
    m = np.eye(4)
    m[:3, 0] = -np.asarray(camera.x, float)
    m[:3, 1] = np.asarray(camera.y, float)
    m[:3, 2] = np.asarray(camera.z, float)
    m[:3, 3] = np.asarray(camera.center, float)
    return m


def _check_square_pixels(camera: Camera) -> None:
    a, b = camera.half_w / camera.half_h, camera.width / camera.height
    if abs(a / b - 1.0) > 1e-9:
        raise ReferenceError(
            f"the camera's pixels are not square (half_w/half_h = {a:.6g}, width/height = {b:.6g}): "
            "Mitsuba's perspective camera needs square pixels; give a resolution of that aspect")


def _clip_range(scene: Scene) -> tuple[float, float]:
    """Near and far clip distances: near 1e-6 of the scene's extent (the engine has none), far
    beyond every vertex."""
    v = scene.elements.verts.reshape(-1, 3)
    lo, hi = v.min(axis=0), v.max(axis=0)
    diag = float(np.linalg.norm(hi - lo)) or 1.0
    far = float(np.max(np.linalg.norm(v - scene.camera.center, axis=1)))
    return 1e-6 * diag, 2.0 * far + diag


def sensor_dict(scene: Scene, spp: int = 1) -> dict:
    """Mitsuba `perspective` sensor that casts the engine's pixel rays: its `to_world` has the
    columns (-x, y, z, centre) of the engine's basis (Mitsuba's camera looks along +z with +x to
    the left of the image) and its horizontal field of view is 2 atan(half_w / focal); a `box`
    pixel filter, so each pixel is the exact average of the radiance over its area (the engine's
    pixel convention: row 0 at the top, `bundles.Camera`). Square pixels only (half_w / half_h =
    width / height)."""
    import mitsuba as mi

    cam = scene.camera
    _check_square_pixels(cam)
    near, far = _clip_range(scene)
    return {
        "type": "perspective",
        "fov_axis": "x",
        "fov": math.degrees(2.0 * math.atan(cam.half_w / cam.focal)),
        "near_clip": near,
        "far_clip": far,
        "to_world": mi.ScalarTransform4f(to_world(cam).tolist()),
        "film": {"type": "hdrfilm", "width": int(cam.width), "height": int(cam.height),
                 "rfilter": {"type": "box"}, "pixel_format": "rgb", "sample_border": False},
        "sampler": {"type": "independent", "sample_count": int(spp)},
    }


def _rgb(v) -> dict:
    return {"type": "rgb", "value": [float(x) for x in v]}


def shape_groups(scene: Scene, meters=(), per_element: bool = False) -> list[np.ndarray]:
    """The original elements of each Mitsuba shape that `mitsuba_scene` makes, in its order:
    one shape per material (elements of one material that differ in side, reflectance or
    emission, as a scene's effects may make them, get a shape each), and an element that
    carries a meter alone (its sensor belongs to its shape). `per_element`: one shape each.

    Returns a list of (k,) int64 arrays, every element in exactly one."""
    el = scene.elements
    n = len(el)
    if per_element:
        return [np.array([i], np.int64) for i in range(n)]
    meters = np.array(sorted({int(i) for i in meters}), np.int64)
    key = np.concatenate([el.material.astype(np.float64)[:, None],
                          el.two_sided.astype(np.float64)[:, None],
                          el.reflectance.reshape(n, -1), el.emission.reshape(n, -1)], axis=1)
    if len(meters):  # a meter's element: a key of its own
        alone = np.zeros((n, 1))
        alone[meters, 0] = 1.0 + np.arange(len(meters))
        key = np.concatenate([key, alone], axis=1)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inv = inv.ravel()
    order = np.argsort(first, kind="stable")  # shapes in the order their first element comes
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    idx = np.argsort(rank[inv], kind="stable")
    bounds = np.cumsum(np.bincount(rank[inv], minlength=len(order)))[:-1]
    return np.split(idx.astype(np.int64), bounds)


def luminaire_dicts(scene: Scene) -> dict:
    """Mitsuba `point` emitters of the scene's isotropic luminaires ([[luminaire]] tables:
    intensity W sr^-1 = cd x colour / 683, as the engine takes them). Mitsuba 3 has no
    goniometric or cosine point light: a Lambertian or IES luminaire is one ReferenceError
    naming it (its reference would silently miss light)."""
    from radiosity.scene.luminaires import luminaires_of

    out = {}
    lums = luminaires_of(scene.elements)
    for k, lum in enumerate(lums.items):
        if lum.distribution != "isotropic":
            raise ReferenceError(
                f"{scene.path}: [[luminaire]] {lum.name!r} is "
                f"{'an IES table' if lum.photometry is not None else 'Lambertian'}: the Mitsuba "
                "reference converts isotropic luminaires only (Mitsuba 3 has no goniometric "
                "point light)")
        I = lums.intensity_w(k, np.array([[0.0, 0.0, -1.0]]))[0]
        out[f"luminaire{k:04d}"] = {"type": "point", "position": [float(x) for x in lum.position],
                                    "intensity": _rgb(I)}
    return out


def _mesh_arrays(el, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float32 and faces (F, 3) uint32 of the elements `idx`: a triangle as
    (v0 v1 v2), a quad as (v0 v1 v2), (v0 v2 v3), so the winding, hence the front normal, is
    the engine's."""
    nv = el.nverts[idx].astype(np.int64)
    base = np.concatenate([[0], np.cumsum(nv)[:-1]])
    take = np.arange(4)[None, :] < nv[:, None]
    verts = el.verts[idx][take]
    tri = np.stack([base, base + 1, base + 2], axis=1)
    quad = nv == 4
    faces = np.concatenate([tri, np.stack([base[quad], base[quad] + 2, base[quad] + 3], axis=1)])
    return (np.ascontiguousarray(verts, np.float32),
            np.ascontiguousarray(faces, np.uint32))


def mitsuba_scene(scene: Scene, depth: int, spp: int = 1, meters=(), mi=None,
                  per_element: bool = False):
    """The loaded scene as a Mitsuba scene. `meters`: element indices that carry an
    `irradiancemeter` sensor (one pixel) besides the camera. Returns (mitsuba Scene,
    {element index: meter sensor}). The conversion:

    - one Mitsuba mesh per material (`shape_groups`; `per_element`: one per original element,
      46 s instead of 3 s for a 32-spp pass on 200 000 triangles), a quad as two triangles
      (v0 v1 v2), (v0 v2 v3) (the winding, hence the front normal, is the engine's), loaded
      with `optimize=False` so that shapes are never merged; which elements a pixel sees comes
      from the engine's own rays (compare.element_raster), not from Mitsuba's shapes;
    - one-sided elements: a `diffuse` BSDF and an `area` emitter, both front-only in Mitsuba,
      which makes the back black, as the engine treats it; two-sided elements: a `twosided` BSDF
      (front, back) and, where the back emits, `radiosity_twosided_area`, which emits the front
      radiance on the front and the back radiance on the back;
    - the camera: `sensor_dict`;
    - the `path` integrator with max_depth = rr_depth = `depth` (no Russian roulette): paths of
      at most D segments, so the light that bounces D times or more is dropped. With rho_max the
      largest reflectance in the scene (any element, side, channel) that tail is
      (rho F)^D L <= rho_max^D max(L) (rows of F sum to at most 1); `path_depth` gives the
      smallest D with rho_max^D <= `reference.truncation` (1e-6): the truncation error is below
      1e-6 of the largest radiance in the scene.
    """
    if mi is None:
        mi, _ = load_mitsuba()
    el = scene.elements
    Le = AreaEmitters(el).radiance()  # (n, 2, 3): the area emitters Mitsuba gets
    bsdfs: dict = {}

    def bsdf(i):
        two = bool(el.two_sided[i])
        key = (two, tuple(el.reflectance[i, 0]), tuple(el.reflectance[i, 1]) if two else ())
        if key not in bsdfs:
            front = {"type": "diffuse", "reflectance": _rgb(el.reflectance[i, 0])}
            if two:  # twosided takes its nested BSDFs in order: front, then back
                d = {"type": "twosided", "bsdf_0_front": front,
                     "bsdf_1_back": {"type": "diffuse", "reflectance": _rgb(el.reflectance[i, 1])}}
            else:
                d = front
            bsdfs[key] = mi.load_dict(d)
        return bsdfs[key]

    meters = {int(i) for i in meters}
    sensors = {}
    d = {"type": "scene",
         "integrator": {"type": "path", "max_depth": int(depth), "rr_depth": int(depth),
                        "hide_emitters": False},
         "sensor": sensor_dict(scene, spp)}
    for j, idx in enumerate(shape_groups(scene, meters, per_element)):
        i = int(idx[0])  # every element of a shape has this one's material
        props = mi.Properties()
        props["bsdf"] = bsdf(i)
        front, back = Le[i]
        if el.two_sided[i] and np.any(back > 0):
            props["emitter"] = mi.load_dict(
                {"type": TWOSIDED_EMITTER, **{f"front_{c}": float(front[k]) for k, c in enumerate("rgb")},
                 **{f"back_{c}": float(back[k]) for k, c in enumerate("rgb")}})
        elif np.any(front > 0):
            props["emitter"] = mi.load_dict({"type": "area", "radiance": _rgb(front)})
        if i in meters:
            sensors[i] = mi.load_dict({
                "type": "irradiancemeter",
                "film": {"type": "hdrfilm", "width": 1, "height": 1, "rfilter": {"type": "box"},
                         "pixel_format": "rgb"},
                "sampler": {"type": "independent", "sample_count": int(spp)}})
            props["sensor"] = sensors[i]
        verts, faces = _mesh_arrays(el, idx)
        mesh = mi.Mesh(f"shape{j}", len(verts), len(faces), props, False, False)
        p = mi.traverse(mesh)
        p["vertex_positions"] = type(p["vertex_positions"])(verts.ravel())
        p["faces"] = type(p["faces"])(faces.ravel())
        p.update()
        d[f"shape{j:07d}"] = mesh
    d.update(luminaire_dicts(scene))
    try:
        return mi.load_dict(d, optimize=False), sensors
    except RuntimeError as e:  # Mitsuba's own message, on one line
        raise ReferenceError(f"{scene.path}: Mitsuba cannot load the converted scene: "
                             f"{' '.join(str(e).split())[:300]}") from None


# ----------------------------------------------------------------------------- rendering

def _chunks(spp: int, pixels: int, max_samples: int) -> list[int]:
    """Split `spp` samples per pixel into equal render calls of at most `max_samples` samples
    in flight (equal sizes: one compiled kernel)."""
    for n in range(1, spp + 1):
        if spp % n == 0 and (spp // n) * pixels <= max_samples:
            return [spp // n] * n
    return [1] * spp


def render_passes(mi, msc, spp: int, passes: int, seed: int = 0, sensor=None, echo=None,
                  *, max_samples: int):
    """K = `passes` independent estimates of `spp // passes` samples per pixel each.

    Returns (mean (H, W, 3) float64, stderr (H, W, 3) float64 (std over passes / sqrt K, zero
    when K = 1), seconds per pass (K,) list). max_samples: reference.max-samples-per-call."""
    max_samples = int(max_samples)
    per = spp // passes
    s = sensor if sensor is not None else msc.sensors()[0]
    size = s.film().size()
    chunks = _chunks(per, int(size[0]) * int(size[1]), max_samples)
    imgs, times = [], []
    call = 0
    for k in range(passes):
        t = time.perf_counter()
        acc = 0.0
        for c in chunks:
            img = mi.render(msc, sensor=s, spp=c, seed=(int(seed) * 1_000_003 + call) & 0xFFFFFFFF)
            acc = acc + np.asarray(img, np.float64) * c
            call += 1
        imgs.append(acc / per)
        times.append(time.perf_counter() - t)
        if echo:
            echo(f"  pass {k + 1}/{passes}: {per} spp, {times[-1]:.2f} s")
    a = np.stack(imgs)
    mean = a.mean(axis=0)
    se = a.std(axis=0, ddof=1) / math.sqrt(passes) if passes > 1 else np.zeros_like(mean)
    return mean, se, times


def relative_stderr(mean: np.ndarray, stderr: np.ndarray) -> tuple[float, float]:
    """Median and 99th percentile of stderr / mean over the (pixel, channel) entries with a
    positive mean; (nan, nan) when there are none."""
    ok = mean > 0
    if not ok.any():
        return float("nan"), float("nan")
    r = stderr[ok] / mean[ok]
    return float(np.median(r)), float(np.percentile(r, 99))


def _spp_per_pass(spp: int, passes: int) -> int:
    if passes < 2:
        raise ReferenceError(f"--passes must be at least 2 (a standard error needs two), got {passes}")
    if spp < passes:
        raise ReferenceError(f"--spp {spp} is fewer than --passes {passes}: each pass needs a sample")
    return -(-spp // passes)


def make_reference(scene: Scene, out: str, spp: int | None = None, passes: int | None = None,
                   seed: int | None = None, variant: str | None = None, echo=print, *,
                   settings: Settings) -> dict:
    """Render `scene` with Mitsuba into `out`: reference.exr (mean radiance), reference-stderr.exr
    (per-pixel standard error) and reference.json (the figures, returned). `spp` is the total
    per pixel, split into `passes` passes (rounded up to a multiple of it). None: the
    reference.* value of `settings`."""
    from radiosity.stages.image import write_exr

    s = settings.replace({"reference.spp": spp, "reference.passes": passes,
                          "reference.seed": seed, "reference.variant": variant})
    ref = s.reference
    spp = int(ref.spp)
    passes = int(ref.passes)
    seed = int(ref.seed)
    per = _spp_per_pass(spp, passes)
    mi, var = load_mitsuba(s.reference.variant, echo=echo)
    depth, rho = path_depth(scene, ref.truncation)
    os.makedirs(out, exist_ok=True)
    t0 = time.perf_counter()
    msc, _ = mitsuba_scene(scene, depth, mi=mi)
    t_load = time.perf_counter() - t0
    shapes = len(msc.shapes())
    echo(f"Mitsuba {mitsuba_version()} ({var}): {shapes} shapes ({len(scene.elements)} elements), "
         f"path depth {depth} "
         f"(max reflectance {rho:.3g}), {per * passes} spp in {passes} passes, "
         f"{scene.camera.width}x{scene.camera.height}")
    mean, se, times = render_passes(mi, msc, per * passes, passes, seed=seed, echo=echo,
                                    max_samples=ref.max_samples_per_call)
    total = time.perf_counter() - t0
    write_exr(os.path.join(out, "reference.exr"), mean)
    write_exr(os.path.join(out, "reference-stderr.exr"), se)
    med, p99 = relative_stderr(mean, se)
    truncation = float(ref.truncation)
    fig = {"scene": scene.path, "width": scene.camera.width, "height": scene.camera.height,
           "spp": per * passes, "passes": passes, "spp_per_pass": per, "seed": seed,
           "time_s": total, "time_load_s": t_load, "time_passes_s": times, "shapes": shapes,
           "rel_stderr_median": med, "rel_stderr_p99": p99,
           "mitsuba_version": mitsuba_version(), "variant": var, "max_depth": depth,
           "max_reflectance": rho, "truncation": truncation,
           "truncation_bound": rho ** depth if rho > 0 else 0.0,
           "camera": scene.camera.to_dict()}
    with open(os.path.join(out, "reference.json"), "w") as f:
        json.dump(fig, f, indent=1)
    return fig


def reusable(out: str, scene: Scene, spp: int, passes: int) -> dict | None:
    """The figures of an existing reference in `out` made of this scene file at this camera with
    at least `spp` samples and these passes, newer than the scene and its meshes, or None."""
    fn = os.path.join(out, "reference.json")
    if not (os.path.isfile(fn) and os.path.isfile(os.path.join(out, "reference.exr"))
            and os.path.isfile(os.path.join(out, "reference-stderr.exr"))):
        return None
    try:
        with open(fn) as f:
            fig = json.load(f)
    except (OSError, ValueError):
        return None
    same_cam = fig.get("camera") == json.loads(json.dumps(scene.camera.to_dict()))
    if (fig.get("scene") == scene.path and same_cam and fig.get("spp", 0) >= spp
            and fig.get("passes") == passes and fig.get("variant") is not None
            and all(os.path.getmtime(fn) >= os.path.getmtime(src)
                    for src in (scene.path, *scene.elements.sources) if os.path.isfile(src))):
        return fig
    return None


def form_factor(scene: Scene, frm: str, to: str, spp: int, passes: int, seed: int = 0,
                variant: str | None = None, echo=None, *,
                settings: Settings) -> tuple[float, float]:
    """The form factor from material `frm` to material `to` measured by Mitsuba: irradiance
    meters on the `to` elements, the emitters being `frm` (Le must be grey and uniform on them,
    and nothing else may emit or reflect). F_frm->to = sum_j A_j E_j / (pi Le A_frm).

    Returns (F, its standard error over the passes)."""
    s = settings.replace({"reference.variant": variant})
    mi, _ = load_mitsuba(s.reference.variant, echo=echo)
    el = scene.elements
    names = np.array(el.material_names)[el.material]
    src, dst = np.nonzero(names == frm)[0], np.nonzero(names == to)[0]
    Le = AreaEmitters(el).radiance()
    le = Le[src, 0]
    others = np.ones(len(el), bool)
    others[src] = False
    if (not len(src) or not len(dst) or np.ptp(le) > 0 or le.min() <= 0
            or np.any(Le[others] > 0) or np.any(el.reflectance > 0)):
        raise ReferenceError(f"{scene.path}: a form factor needs emitters {frm!r} of one grey radiance, "
                             f"receivers {to!r}, no other emitter and no reflection")
    depth, _ = path_depth(scene, s.reference.truncation)
    msc, meters = mitsuba_scene(scene, depth, meters=dst, mi=mi)
    per = _spp_per_pass(spp, passes)
    power, var = 0.0, 0.0
    for j, sensor in meters.items():  # independent renders: their variances add
        mean, se, _ = render_passes(mi, msc, per * passes, passes, seed=seed + 7919 * (j + 1),
                                    sensor=sensor, max_samples=s.reference.max_samples_per_call)
        power += el.area[j] * float(mean.mean())
        var += (el.area[j] * float(se.mean())) ** 2
    norm = math.pi * float(le[0, 0]) * float(el.area[src].sum())
    return power / norm, math.sqrt(var) / norm


# ----------------------------------------------------------------------------- for the accuracy study

def reference_at(scene: Scene, out: str, spp: int, passes: int, echo=print, *,
                 settings: Settings):
    """Make, or reuse when `out` holds one of this scene and camera with at least `spp` samples
    in `passes` passes, a reference in `out` (the other reference.* values from `settings`).
    Returns (mean (H, W, 3), stderr, figures)."""
    from radiosity.stages.image import read_exr

    fig = reusable(out, scene, spp, passes)
    if fig is None:
        fig = make_reference(scene, out, spp=spp, passes=passes, echo=echo, settings=settings)
    else:
        echo(f"  reusing the reference in {out} ({fig['spp']} spp, {fig['variant']})")
    return (read_exr(os.path.join(out, "reference.exr")).astype(np.float64),
            read_exr(os.path.join(out, "reference-stderr.exr")).astype(np.float64), fig)


def path_tracer_runs(scene: Scene, spps, seed: int = 12345, repeat: int = 2, echo=print, *,
                     settings: Settings) -> list[dict]:
    """The path tracer as a method of the study: for each sample count, a render of the scene's
    camera, timed (the conversion and scene build, measured once after a warm-up, plus the best
    of `repeat` renders; the kernel compilation is left out as the engine's numba warm-up is).
    The image kept is the first render's (its seed, not the timing, decides it).
    Returns [{"spp", "time_s", "image" (H, W, 3) float64}]."""
    s = settings
    max_samples = s.reference.max_samples_per_call
    mi, var = load_mitsuba(s.reference.variant, echo=echo)
    depth, _ = path_depth(scene, s.reference.truncation)
    msc, _ = mitsuba_scene(scene, depth, mi=mi)
    render_passes(mi, msc, 2, 2, seed=seed, max_samples=max_samples)  # warm-up: compiles the kernel
    t = time.perf_counter()
    msc, _ = mitsuba_scene(scene, depth, mi=mi)
    t_build = time.perf_counter() - t
    runs = []
    for k, spp in enumerate(spps):
        best, image = math.inf, None
        for rep in range(repeat):  # best of `repeat`: the machine's other work only slows
            t = time.perf_counter()
            img, _, _ = render_passes(mi, msc, int(spp), 1, seed=seed + 1 + 2 * k + rep,
                                      max_samples=max_samples)
            best = min(best, time.perf_counter() - t)
            if rep == 0:
                image = img
        runs.append({"spp": int(spp), "time_s": t_build + best, "image": image, "variant": var})
        echo(f"  path tracer {scene.camera.width}x{scene.camera.height} {spp} spp: "
             f"{runs[-1]['time_s']:.2f} s")
    return runs
