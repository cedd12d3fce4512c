"""Direct light at points (scene/direct.py, issue 50): H1 at N points of a scene, its speed
against Embree's on the same shadow rays, and its error against a many-ray reference.

    python benchmarks/bench_direct.py [--points 20000] [--ref-points 400] [--scenes a,b]
                                      [--samples 16 --refine 4]

Scenes: the Cornell box (scenes/cornell-box), modern-hall (benchmarks/real/modern-hall: 168
emitting elements in 13 lights) and a terrain of scenes_generated.terrain (--terrain triangles,
one 2 x 2 light). Points: uniform by area over the elements that reflect, on a side that
reflects (its normal), numbered for their sample offsets. For each scene:
- points/s and shadow rays/s of DirectLight.irradiance (default settings, numba warm), and the
  share of the (point, light) pairs that the shaft test proved clear (no ray);
- Embree alone on the same rays (RayCaster.occluded_pairs replayed on the recorded batches):
  rays/s, and the share of the time spent outside Embree;
- error against samples=1024, refine=1 on the first --ref-points points: the mean absolute
  luminance error over the mean luminance, and the 99th percentile of the per-point error
  relative to the point's own unoccluded H1;
- the same for the first version of the module (git revision --first, the per-element loop
  with `samples` rays to every emitting element a point sees) on the first --first-points
  points, in the same run.
Writes benchmarks/results/direct.json and prints a table.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import HERE, ROOT, table, write  # noqa: E402

LUMA = np.array([0.2126, 0.7152, 0.0722])
SCENES = {"cornell-box": os.path.join(ROOT, "scenes", "cornell-box", "scene.toml"),
          "modern-hall": os.path.join(HERE, "real", "modern-hall", "scene.toml")}


def points_of(el, n: int, seed: int = 0):
    """n points uniform by area over the elements that reflect, with the normal of a side that
    reflects and their element: (P (n, 3), N (n, 3), E (n,))."""
    rng = np.random.default_rng(seed)
    refl = el.reflectance.max(axis=2)                             # (m, 2)
    w = el.area * (refl.max(axis=1) > 0)
    e = rng.choice(len(w), n, p=w / w.sum())
    back = (refl[e, 1] > 0) & ((refl[e, 0] <= 0) | (rng.random(n) < 0.5))
    V = el.verts[e]
    u, v = rng.random((2, n, 1))
    tri = el.nverts[e] == 3
    fold = u + v > 1
    u, v = np.where(fold, 1 - u, u), np.where(fold, 1 - v, v)
    c = np.where(tri[:, None], V[:, 2], V[:, 3])
    P = np.where(tri[:, None], V[:, 0] + u * (V[:, 1] - V[:, 0]) + v * (V[:, 2] - V[:, 0]),
                 V[:, 0] + u * (V[:, 1] - V[:, 0]) + v * (c - V[:, 0]))
    N = el.normal[e] * np.where(back, -1.0, 1.0)[:, None]
    return P, N, e


def first_version(rev: str, folder: str):
    """scene/direct.py as of git revision rev, as a module (written into folder: numba caches
    next to the file)."""
    import importlib.util
    import subprocess

    src = subprocess.run(["git", "show", f"{rev}:app/scene/direct.py"], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout
    fn = os.path.join(folder, "direct_first.py")
    with open(fn, "w") as f:
        f.write(src)
    spec = importlib.util.spec_from_file_location("direct_first", fn)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def errors(got, ref, h0) -> tuple[float, float]:
    """(mean absolute luminance error over the mean, p99 of |error| / unoccluded)."""
    lit = h0 > 0
    rel = np.abs(got - ref)[lit] / h0[lit]
    return (float(np.abs(got - ref).mean() / max(ref.mean(), 1e-300)),
            float(np.percentile(rel, 99)) if lit.any() else 0.0)


def measure(name: str, path: str, n: int, n_ref: int, first=None, n_first: int = 2000,
            samples: int = 16, refine: int = 4) -> dict:
    from radiosity.scene.direct import DirectLight
    from radiosity.scene.load import load_scene
    from radiosity.settings import options

    st = options()
    t = time.perf_counter()
    el = load_scene(path, settings=st).elements
    t_load = time.perf_counter() - t
    P, N, E = points_of(el, n)
    dl = DirectLight(el, st.rays.offset, samples=samples, refine=refine)
    dl.irradiance(P[:64], N[:64], E[:64])                          # compile, build the caster
    caster = dl.caster
    calls = []
    inner = caster.occluded_pairs

    def recorded(*a, **k):
        calls.append(a)
        return inner(*a, **k)

    caster.occluded_pairs = recorded
    dl.rays = dl.pairs = dl.cleared = 0
    t = time.perf_counter()
    H = dl.irradiance(P, N, E)
    t_all = time.perf_counter() - t
    caster.occluded_pairs = inner
    t = time.perf_counter()
    for a in calls:
        inner(*a)
    t_embree = time.perf_counter() - t
    ref_dl = DirectLight(el, st.rays.offset, samples=1024, refine=1)
    Pr, Nr, Er = P[:n_ref], N[:n_ref], E[:n_ref]
    ref = ref_dl.irradiance(Pr, Nr, Er) @ LUMA
    got = H[:n_ref] @ LUMA
    h0 = dl.unoccluded(Pr, Nr) @ LUMA
    mean_error, p99_error = errors(got, ref, h0)
    row = {"scene": name, "elements": len(el.area), "emitting": len(dl.ids), "lights": dl.lights,
           "points": n, "load_s": round(t_load, 2), "seconds": round(t_all, 3),
           "points_per_s": n / t_all, "rays": dl.rays, "rays_per_point": dl.rays / n,
           "rays_per_s": dl.rays / t_all, "shaft_clear": dl.cleared / max(dl.pairs, 1),
           "embree_rays_per_s": dl.rays / max(t_embree, 1e-9),
           "outside_embree": 1.0 - t_embree / t_all, "mean_error": mean_error,
           "p99_error": p99_error, "ref_points": n_ref}
    if first is not None:
        old = first.DirectLight(el, st.rays.offset)
        old.irradiance(P[:64], N[:64], E[:64])
        k = min(n_first, n)
        t = time.perf_counter()
        Ho = old.irradiance(P[:k], N[:k], E[:k])
        row["first_points_per_s"] = k / (time.perf_counter() - t)
        row["first_mean_error"], row["first_p99_error"] = errors(Ho[:n_ref] @ LUMA, ref, h0)
        row["speedup"] = row["points_per_s"] / row["first_points_per_s"]
    return row


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=20000)
    ap.add_argument("--ref-points", type=int, default=400)
    ap.add_argument("--terrain", type=int, default=20000, help="the terrain's triangles")
    ap.add_argument("--scenes", default="cornell-box,modern-hall,terrain")
    ap.add_argument("--first", default="2f68088", help="the first version's git revision ('': none)")
    ap.add_argument("--first-points", type=int, default=2000)
    ap.add_argument("--samples", type=int, default=16, help="DirectLight's samples")
    ap.add_argument("--refine", type=int, default=4, help="DirectLight's refine")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        from scenes_generated import terrain

        scenes = dict(SCENES, terrain=terrain(tmp, a.terrain))
        for name in a.scenes.split(","):
            first = first_version(a.first, tmp) if a.first else None
            rows.append(measure(name, scenes[name], a.points, a.ref_points, first, a.first_points,
                                a.samples, a.refine))
            print(rows[-1], flush=True)
    extra = {"points": a.points, "terrain_triangles": a.terrain, "first": a.first,
             "samples": a.samples, "refine": a.refine}
    fn = write("direct" if (a.samples, a.refine) == (16, 4) else
               f"direct-s{a.samples}-r{a.refine}", rows, extra)
    print(table(rows, ["scene", "emitting", "lights", "points", "seconds", "points_per_s",
                       "rays_per_point", "shaft_clear", "rays_per_s", "embree_rays_per_s", "outside_embree",
                       "mean_error", "p99_error", "first_points_per_s", "speedup",
                       "first_mean_error", "first_p99_error"]))
    print("wrote", fn)


if __name__ == "__main__":
    main()
