"""Clustering above the originals (SPEC §9) on scenes of many small triangles, as whole
`radiosity plan` and `radiosity render` processes: a terrain lit by a rectangular light (10^4,
10^5, 10^6 triangles), a room with a finely tessellated sphere, the Cornell box with every face
cut into triangles beside the 32-original box (the same picture). Per scene: load, plan, cluster
links, element links, rays, time per stage, peak memory of the driver and the workers, and the
image against a reference image (the plain box for the tessellated one; the same scene with
clusters off where that fits) and, for both boxes and the room, against a Mitsuba 3 reference
(--reference-spp; its noise on a 4 x 4-pixel cell stated as ref_cell_noise, the median
per-pixel relative standard error / 4). Writes benchmarks/results/clusters.json.

    python benchmarks/bench_clusters.py                      # 10^4 terrain, tessellated Cornell
    (time_vs_plain: the median ratio of --repeats renders of each box one after the other)
    python benchmarks/bench_clusters.py --terrain 10000,100000,1000000 --room 50000
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from common import ROOT, table, write

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import scenes_generated as gen  # noqa: E402


def _run(args: list, env: dict | None = None) -> tuple[float, str]:
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "radiosity.cli", *args], cwd=ROOT, capture_output=True,
                       text=True, env={**os.environ, **(env or {})})
    if r.returncode not in (0, 3):
        raise RuntimeError(f"radiosity {' '.join(args)} failed:\n{r.stdout}\n{r.stderr}")
    return time.perf_counter() - t, r.stdout


def _cells(img: np.ndarray, k: int = 32) -> np.ndarray:
    h, w = img.shape[:2]
    return img[:h - h % k, :w - w % k].reshape(k, h // k, k, w // k, 3).mean((1, 3)).sum(-1)


def compare(a_exr: str, b_exr: str) -> dict:
    """Image b against a: mean ratio and the mean |relative error| of 32 x 32 block cells."""
    from radiosity.stages.image import read_exr

    a, b = read_exr(a_exr), read_exr(b_exr)
    A, B = _cells(a), _cells(b)
    m = A > 0
    return {"mean_ratio": float(b.mean() / a.mean()),
            "cell_error": float(np.abs(B[m] / A[m] - 1).mean())}


def _against(ref: str, exr: str) -> dict:
    """compare() against the Mitsuba reference in folder ref, keys ref_*."""
    return {f"ref_{k}": v for k, v in compare(os.path.join(ref, "reference.exr"), exr).items()}


def render(scene: str, out: str, env: dict | None = None) -> dict:
    t_plan, _ = _run(["plan", scene], env)
    wall, _ = _run(["render", scene, "--out", out, "--no-preview", "--force"], env)
    rep = json.load(open(os.path.join(out, "report.json")))
    lk, st = rep.get("links", {}), rep["render"]["stages"]
    cl = lk.get("clusters") or {}
    peak = st.get("peak_rss_mb", {})
    return {"originals": rep["preprocess"]["original_elements"], "method": rep["plan"]["method"],
            "plan_s": round(t_plan, 1), "render_s": round(wall, 1),
            "links_s": round(st["visibility_s"], 1), "solve_s": round(st["solve_s"], 1),
            "cluster_links": lk.get("cluster_links", 0), "cluster_s": cl.get("time_s", 0.0),
            "element_pairs": lk.get("pairs", 0), "links": lk.get("links", 0),
            "rays": lk.get("rays", 0) + cl.get("rays", 0),
            "driver_mib": peak.get("master"), "worker_mib": max((peak.get("workers") or {0: 0}).values())}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--terrain", default="10000", help="terrain triangle counts")
    ap.add_argument("--room", default="", help="sphere triangle counts of the furnished room")
    ap.add_argument("--cornell", default="200,2000", help="triangles per face of the Cornell box")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--reference-spp", type=int, default=2048,
                    help="Mitsuba reference of the Cornell box (0: none): both boxes against it")
    ap.add_argument("--off-below", type=int, default=20000,
                    help="also render with clusters off below this many triangles (the reference)")
    ap.add_argument("--repeats", type=int, default=3,
                    help="renders of the plain and each tessellated box, one after the other, "
                         "for time_vs_plain (the median of the pairs' ratios)")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in [int(x) for x in a.terrain.split(",") if x]:
            sc = gen.terrain(os.path.join(tmp, f"terrain{n}"), n, a.resolution)
            row = {"scene": f"terrain {n}", **render(sc, os.path.join(tmp, f"t{n}"))}
            if n < a.off_below:
                ref = os.path.join(tmp, f"t{n}-off")
                r0 = render(sc, ref, {"DASK_RADIOSITY__HIERARCHY__CLUSTERS": "off"})
                row.update(off_render_s=r0["render_s"],
                           **compare(f"{ref}/image.exr", os.path.join(tmp, f"t{n}", "image.exr")))
            rows.append(row)
        for n in [int(x) for x in a.room.split(",") if x]:
            sc = gen.room_with_sphere(os.path.join(tmp, f"room{n}"), n, a.resolution)
            row = {"scene": f"room, sphere {n}", **render(sc, os.path.join(tmp, f"r{n}"))}
            if a.reference_spp > 0:  # against Mitsuba, as the boxes
                ref_r = os.path.join(tmp, f"reference-room{n}")
                _run(["reference", sc, "--out", ref_r, "--resolution", str(a.resolution),
                      "--spp", str(a.reference_spp)])
                noise = json.load(open(os.path.join(ref_r, "reference.json")))["rel_stderr_median"]
                row.update(_against(ref_r, os.path.join(tmp, f"r{n}", "image.exr")),
                           ref_cell_noise=round(noise / 4, 4))
            rows.append(row)
        plain = os.path.join(tmp, "cornell")
        src = os.path.join(ROOT, "scenes", "cornell-box", "scene.toml")
        base = {"scene": "cornell-box (32 originals)",
                **render(src, plain)} if a.cornell else None
        ref = None
        if base and a.reference_spp > 0:  # ground truth for both boxes (the same picture)
            ref = os.path.join(tmp, "reference")
            _run(["reference", src, "--out", ref, "--resolution", str(a.resolution), "--spp",
                  str(a.reference_spp)])
            noise = json.load(open(os.path.join(ref, "reference.json")))["rel_stderr_median"]
            base.update(_against(ref, f"{plain}/image.exr"), ref_cell_noise=round(noise / 4, 4))
        if base:
            rows.append(base)
        for k in [int(x) for x in a.cornell.split(",") if x]:
            sc = gen.tessellated_cornell(os.path.join(tmp, f"ct{k}"), k, a.resolution)
            out = os.path.join(tmp, f"c{k}")
            rows.append({"scene": f"cornell-box, {k} triangles a face", **render(sc, out),
                         **compare(f"{plain}/image.exr", f"{out}/image.exr"),
                         **(_against(ref, f"{out}/image.exr") if ref else {}),
                         "time_vs_plain": None})
            # the ratio from renders one after the other (the machine's speed drifts): the
            # median of the pairs' ratios, every pair's times kept
            pairs = [(_run(["render", src, "--out", plain, "--no-preview", "--force"])[0],
                      _run(["render", sc, "--out", out, "--no-preview", "--force"])[0])
                     for _ in range(max(1, a.repeats))]
            rows[-1].update(time_vs_plain=round(float(np.median([t / p for p, t in pairs])), 2),
                            pairs_s=[[round(p, 1), round(t, 1)] for p, t in pairs])
    cols = ["scene", "originals", "method", "plan_s", "render_s", "links_s", "cluster_s",
            "cluster_links", "element_pairs", "links", "rays", "driver_mib", "worker_mib",
            "mean_ratio", "cell_error", "ref_mean_ratio", "ref_cell_error", "ref_cell_noise",
            "off_render_s", "time_vs_plain"]
    print(table(rows, cols))
    print("wrote", write("clusters", rows, {"resolution": a.resolution}))


if __name__ == "__main__":
    main()
