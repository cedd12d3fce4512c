"""Rays a link: the link tasks of a rendered run re-made in this process, in one thread, with
the boxes' shafts alone (`hull_shafts` off, the code before) and with the polygons' tight shafts
(the default), in the same run on the same pairs.

Per scene and way: kept links, links that waited for rays, rays cast, rays a kept link, links
proven visible / blocked without a ray (by the boxes' shafts, by the tight shafts), the tasks'
time (one thread: refinement, shafts and rays; the faster of --repeat alternating rounds), rays/s over that time, and the answer: the
largest relative change of an original's row sum sum_q F_pq v_pq between the two ways (the
same links bar those proven instead of measured). The run directory is made by `radiosity
render` (the default settings) unless --run names one already rendered; a run stopped after
its preprocess (a large clustered scene, whose cluster layer alone takes many minutes here)
gives near pairs of originals instead of its link plan (near_pairs).

    python benchmarks/bench_linkrays.py [--scene cornell-box:64] [--scene PATH:RES ...]
                                        [--run DIR ...] [--max-pairs 20000] [--repeat 2] [--hull 0,1,16]

Writes benchmarks/results/linkrays.json and prints the table.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from common import ROOT, table, write
from radiosity.settings import options as settings_of

SCENES = {"cornell-box": os.path.join(ROOT, "scenes", "cornell-box", "scene.toml"),
          "modern-hall": os.path.join(ROOT, "benchmarks", "real", "modern-hall", "scene.toml")}


def render(scene: str, res: int, out: str) -> str:
    """`radiosity render` of the scene into out (the run whose link plan is re-made)."""
    subprocess.run([sys.executable, "-m", "radiosity.cli", "render", scene, "-o", out,
                    "--resolution", str(res), "--force", "--no-preview"], check=True,
                   stdout=subprocess.DEVNULL)
    return out


def inputs(run_dir: str, max_pairs: int):
    """LinkInputs as the link stage made them for the run (its settings' defaults), at most
    max_pairs of its plan's pairs (evenly strided), their total and a ray caster."""
    from radiosity.methods.hierarchical.links.master import LinkInputs
    from radiosity.methods.hierarchical.params import resolve_params
    from radiosity.runtime.store import RunStore
    from radiosity.scene.splittrees import seen_originals, tree_nodes
    from radiosity.tracing.rays import RayCaster

    s = settings_of()
    rs = RunStore(run_dir)
    part, el = rs.load_partition(), rs.load_elements()
    raster = rs.read_arrays("raster")
    prm, weight = resolve_params(el, s, True, pixels=raster["orig"].size)
    hit = None
    if s.hierarchy.split_hidden:
        sub = raster["sub"]
        hit = np.zeros(len(part), bool)
        hit[sub[sub >= 0]] = True
    seen = seen_originals(raster["orig"], len(el))
    inp = LinkInputs(tree_nodes(part, el), part, el, seen, prm, weight, "bench",
                     float(s.rays.offset), hit)
    if "links" in rs.root:  # strided in the store: a large plan is gigabytes
        stored = rs.root["links"]["pairs"]
        total = stored.shape[0]
        pairs = stored[::max(1, -(-total // max_pairs))]
    else:  # no link plan yet (a run stopped after its preprocess): near pairs instead
        pairs = near_pairs(el)
        total = len(pairs)
        pairs = pairs[::max(1, -(-total // max_pairs))]
    pairs = np.ascontiguousarray(pairs, np.int64)
    return inp, pairs, total, RayCaster(el.verts, el.nverts, float(s.rays.offset)), len(el)


def near_pairs(el, originals: int = 2000, near: int = 8, seed: int = 0) -> np.ndarray:
    """Pairs I < J of each of `originals` random originals with its `near` nearest (by
    centroid) that face it both ways: a stand-in for the pairs a clustered scene's cluster
    layer hands to the element level, which are mostly near ones."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    c, nrm, two = el.center, el.normal, np.asarray(el.two_sided, bool)
    pick = rng.choice(len(el), min(originals, len(el)), replace=False)
    _, nb = cKDTree(c).query(c[pick], near + 1)
    i, j = np.repeat(pick, near + 1), nb.ravel()
    d = c[j] - c[i]
    fi = np.einsum("kc,kc->k", nrm[i], d)
    fj = -np.einsum("kc,kc->k", nrm[j], d)
    ok = (i != j) & ((fi > 0) | two[i]) & ((fj > 0) | two[j])
    p = np.sort(np.stack([i[ok], j[ok]], 1), axis=1)
    return np.unique(p, axis=0).astype(np.int64)


def one_way(inp, pairs, caster, n: int, hull: int, chunk: int = 4096) -> dict:
    """The pairs' links with the tight shafts' setting `hull` (LinkParams.hull_shafts: 0 off,
    1 lists only, more: the tree walk's budget): counters, time, row sums."""
    from radiosity.methods.hierarchical.links.master import COUNTERS, refine_pairs

    inp.params = dataclasses.replace(inp.params, hull_shafts=hull)
    counts = np.zeros(len(COUNTERS), np.int64)
    rows = np.zeros(n)
    t, c0 = time.perf_counter(), time.thread_time()
    for a in range(0, len(pairs), chunk):  # tasks of `chunk` pairs, as a stripe
        links, _, c = refine_pairs(inp, pairs[a:a + chunk], caster)
        counts += c
        np.add.at(rows, links["po"], links["fpq"] * links["v"])
        np.add.at(rows, links["qo"], links["fqp"] * links["v"])
    dt, cpu = time.perf_counter() - t, time.thread_time() - c0
    c = dict(zip(COUNTERS, counts.tolist()))
    return {"links": c["links"], "ray_links": c["ray_links"], "rays": c["rays"],
            "rays_per_link": c["rays"] / max(1, c["links"]),
            "shaft_visible": c["shaft_visible"], "shaft_blocked": c["shaft_blocked"],
            "hull_visible": c["hull_visible"], "hull_blocked": c["hull_blocked"],
            "time_s": round(dt, 3), "cpu_s": round(cpu, 3),
            "rays_per_s": c["rays"] / cpu if cpu > 0 else 0.0,
            "rows": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", action="append", default=None,
                    help="NAME-or-PATH:RESOLUTION (default cornell-box:64 and modern-hall:32)")
    ap.add_argument("--run", action="append", default=[],
                    help="an already rendered run directory for the scene of the same place")
    ap.add_argument("--max-pairs", type=int, default=20000,
                    help="at most this many of the plan's pairs, evenly strided")
    ap.add_argument("--repeat", type=int, default=2, help="rounds of all ways, alternating")
    ap.add_argument("--hull", type=lambda t: [int(x) for x in t.split(",")], default=[0, 1, 16],
                    help="LinkParams.hull_shafts values to compare, the first the baseline "
                         "(0: the boxes' shafts alone, the code before; 1: the tight shafts "
                         "on candidate lists; N: and the tree walk of N nodes; default 0,1,16)")
    a = ap.parse_args()
    scenes = a.scene or ["cornell-box:64", "modern-hall:32"]
    tmp = tempfile.mkdtemp(prefix="linkrays-")
    out, rows = [], []
    for i, spec in enumerate(scenes):
        name, res = spec.rsplit(":", 1)
        path = SCENES.get(name, name)
        t = time.perf_counter()
        run = a.run[i] if i < len(a.run) else render(path, int(res), os.path.join(tmp, f"r{i}"))
        t_render = time.perf_counter() - t
        inp, sub, total, caster, n = inputs(run, a.max_pairs)
        one_way(inp, sub[:8], caster, n, 16)  # compiled and warm before timing
        ways = {}
        for _ in range(a.repeat):  # alternating, the faster of each (a shared machine)
            for hull in a.hull:
                w = one_way(inp, sub, caster, n, hull)
                if hull not in ways or w["cpu_s"] < ways[hull]["cpu_s"]:
                    ways[hull] = w
        r0 = ways[a.hull[0]]["rows"]
        for w in ways.values():
            r1 = w.pop("rows")
            w["row_sum_change"] = float(np.max(np.abs(r1 - r0) / np.maximum(np.abs(r0), 1e-12),
                                               initial=0.0))
        rec = {"scene": name, "resolution": int(res), "pairs": int(total),
               "pairs_used": int(len(sub)), "render_s": round(t_render, 1) if i >= len(a.run)
               else None, "ways": {str(k): v for k, v in ways.items()}}
        out.append(rec)
        for way, w in ways.items():
            rows.append({"scene": name, "res": int(res), "pairs": f"{len(sub)}/{total}",
                         "hull_shafts": way, "links": w["links"], "ray links": w["ray_links"],
                         "rays": w["rays"], "rays/link": round(w["rays_per_link"], 3),
                         "box vis/blk": f"{w['shaft_visible']}/{w['shaft_blocked']}",
                         "tight vis/blk": f"{w['hull_visible']}/{w['hull_blocked']}",
                         "CPU s": w["cpu_s"], "wall s": w["time_s"],
                         "Mrays/s": round(w["rays_per_s"] / 1e6, 3),
                         "row change": f"{w['row_sum_change']:.1e}"})
    write("linkrays", out)
    print(table(rows, list(rows[0])))

if __name__ == "__main__":
    main()
