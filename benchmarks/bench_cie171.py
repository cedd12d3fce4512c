"""CIE 171:2006-style analytic cases on calculation grids (issue 52): every point of every grid
of scenes/cie171/ against its exact answer (validation/cie171.py), as lighting vendors publish
them (reference, computed, % deviation), with no options (the scene's own camera, the
defaults):

    python benchmarks/bench_cie171.py [--cases area-source,obstruction] [--markdown FILE]
        [--method hierarchical --name cie171-hierarchical]

Writes benchmarks/results/cie171.json and prints one table per grid and a summary (worst and
mean |deviation| per case; for the closed rooms the mean reflected illuminance over the six
faces against the energy balance).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import ROOT, table, write  # noqa: E402

import radiosity  # noqa: E402
from radiosity.validation import cie171  # noqa: E402


def run_case(case: str, tmp: str, **options) -> dict:
    t0 = time.perf_counter()
    r = radiosity.render(cie171.scene_dir(ROOT, case), os.path.join(tmp, case), **options)
    wall = time.perf_counter() - t0
    out = {"case": case, "time_s": round(wall, 2), "grids": {},
           "method": r.report["plan"]["method"], "direct": r.report["plan"]["direct"],
           "receiver": r.report["plan"].get("receiver")}
    if case.startswith("interreflection"):
        rho = int(case.rsplit("-", 1)[1]) / 100
        ind = np.concatenate([g["indirect_lux"] for g in r.grids.values()])
        ref = cie171.closed_room_mean_indirect(rho)
        out["mean_indirect_lux"] = float(ind.mean())
        out["reference_lux"] = ref
        out["deviation_pct"] = 100 * (float(ind.mean()) / ref - 1)
        return out
    for name, g in r.grids.items():
        P = np.column_stack([g["x"], g["y"], g["z"]])
        N = np.column_stack([g["nx"], g["ny"], g["nz"]])
        ref = cie171.reference(case, name, P, N)
        got = g["illuminance_lux"]
        dev = np.where(ref > 0, 100 * (got / np.where(ref > 0, ref, 1) - 1), np.nan)
        out["grids"][name] = {"points": P.tolist(), "reference": ref.tolist(),
                              "computed": got.tolist(), "deviation_pct": dev.tolist(),
                              "zero_reference_abs_lux": float(np.abs(got[ref <= 0]).max())
                              if (ref <= 0).any() else 0.0}
    return out


def markdown(res: list) -> str:
    lines = []
    for c in res:
        if "grids" not in c or not c["grids"]:
            continue
        for name, g in c["grids"].items():
            lines += [f"### {c['case']}: grid `{name}`", "",
                      "| x | y | z | reference (lx) | computed (lx) | deviation |",
                      "|---:|---:|---:|---:|---:|---:|"]
            for p, ref, got, d in zip(g["points"], g["reference"], g["computed"],
                                      g["deviation_pct"]):
                ds = "-" if d is None or not np.isfinite(d) else f"{d:+.2f} %"
                lines.append(f"| {p[0]:g} | {p[1]:g} | {p[2]:g} | {ref:.2f} | {got:.2f} | {ds} |")
            lines.append("")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cases", default=",".join(cie171.CASES))
    ap.add_argument("--markdown", default=None, help="Write the per-point tables here.")
    ap.add_argument("--method", default=None, help="pairs | hierarchical (default: auto).")
    ap.add_argument("--name", default="cie171", help="Results file name (benchmarks/results/).")
    a = ap.parse_args()
    res = []
    with tempfile.TemporaryDirectory(prefix="cie171-") as tmp:
        for case in a.cases.split(","):
            res.append(run_case(case, tmp, **({"method": a.method} if a.method else {})))
            c = res[-1]
            print(f"{case}: {c['time_s']} s, method {c['method']}, direct {c['direct']}, "
                  f"receiver {c['receiver']}")
    rows = []
    for c in res:
        if "deviation_pct" in c:
            rows.append({"case": c["case"], "points": "6 faces", "worst_pct": "",
                         "mean_pct": round(c["deviation_pct"], 3), "time_s": c["time_s"]})
            continue
        d = np.concatenate([np.asarray(g["deviation_pct"], float) for g in c["grids"].values()])
        d = d[np.isfinite(d)]
        rows.append({"case": c["case"], "points": len(d),
                     "worst_pct": round(float(np.abs(d).max()), 3),
                     "mean_pct": round(float(np.abs(d).mean()), 3), "time_s": c["time_s"]})
    print(table(rows, ["case", "points", "worst_pct", "mean_pct", "time_s"]))
    with open("/proc/loadavg") as f:
        load = f.read().split()[:3]
    print("load average", " ".join(load))
    print("wrote", write(a.name, rows, {"cases": res, "loadavg": load}))
    if a.markdown:
        with open(a.markdown, "w") as f:
            f.write(markdown(res))


if __name__ == "__main__":
    main()
