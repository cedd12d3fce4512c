"""Are the built-in scenes' images, tables and link counts the same to the bit as before a change?

Renders every scene under scenes/ (whole `radiosity render` commands, small resolutions, each
method where it applies) and the view factors of one mesh, then hashes what a user gets: the
image's pixels, the PNG, the light tables, the mesh exports, the stored solution and the counts
of report.json (sub-elements, links, rays, passes, residual). Refactors must leave every hash as
it was.

    python benchmarks/identical.py --write benchmarks/results/identical.json   # before
    python benchmarks/identical.py --check benchmarks/results/identical.json   # after

Prints one line a case (same / DIFFERENT and which files) and exits 1 when any differs.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESOLUTION = "32"
FILES = ("image.exr", "image.png", "elements.csv", "surfaces.csv", "materials.csv", "mesh.ply")
COUNTS = (("preprocess", "sub_elements"), ("links", "links"), ("links", "rays"),
          ("links", "cluster_links"), ("visibility", "ones"), ("solve", "iterations"),
          ("solve", "final_residual"), ("render", "mean_radiance"), ("plan", "method"))


def cases() -> list[tuple[str, list[str]]]:
    """(name, extra render arguments) for every built-in scene, and both methods on two."""
    out = []
    for toml in sorted(ROOT.glob("scenes/*/scene.toml")):
        out.append((toml.parent.name, [str(toml)]))
    for scene in ("cornell-box", "three-rectangles"):
        for method in ("pairs", "hierarchical"):
            out.append((f"{scene}/{method}",
                        [str(ROOT / "scenes" / scene / "scene.toml"), "--method", method]))
    return out


def _hash_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def _store_hashes(store: Path) -> dict:
    import zarr

    out = {}
    root = zarr.open_group(str(store), mode="r")
    for group in ("solution",):
        if group in root:
            for name, arr in root[group].arrays():
                out[f"{group}/{name}"] = _hash_bytes(np.ascontiguousarray(arr[...]).tobytes())
    return out


def fingerprint(run: Path) -> dict:
    """Hashes of a run's user-facing outputs and its counts."""
    out = {}
    for name in FILES:
        if (run / name).exists():
            out[name] = _hash_bytes((run / name).read_bytes())
    if (run / "store.zarr").exists():
        out.update(_store_hashes(run / "store.zarr"))
    report = json.loads((run / "report.json").read_text())
    for section, key in COUNTS:
        if key in report.get(section, {}):
            out[f"{section}.{key}"] = report[section][key]
    return out


def run_case(args: list[str], out: Path) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "radiosity.cli", "render", *args, "--out", str(out),
                           "--resolution", RESOLUTION], capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"render {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return time.perf_counter() - t0


def viewfactors_case(out: Path) -> dict:
    mesh = ROOT / "scenes" / "furnished-room" / "furnished-room.obj"
    proc = subprocess.run([sys.executable, "-m", "radiosity.cli", "viewfactors", str(mesh),
                           "--out", str(out)], capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"viewfactors failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    return {p.name: _hash_bytes(p.read_bytes()) for p in sorted(out.iterdir())
            if p.is_file() and p.suffix in (".npz", ".csv")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", type=Path, help="record the hashes here")
    ap.add_argument("--check", type=Path, help="compare with hashes recorded here")
    ap.add_argument("--only", help="comma-separated case names")
    a = ap.parse_args(argv)
    want = json.loads(a.check.read_text()) if a.check else {}
    only = set(a.only.split(",")) if a.only else None
    got, differ = {}, []
    with tempfile.TemporaryDirectory() as tmp:
        todo = cases() + [("viewfactors/furnished-room", None)]
        for name, args in todo:
            if only and name not in only:
                continue
            out = Path(tmp) / name.replace("/", "-")
            t0 = time.perf_counter()
            got[name] = viewfactors_case(out) if args is None else (run_case(args, out) and
                                                                    fingerprint(out))
            dt = time.perf_counter() - t0
            if a.check:
                ref = want.get(name)
                bad = sorted(k for k in set(ref or {}) | set(got[name])
                             if (ref or {}).get(k) != got[name].get(k))
                if ref is None or bad:
                    differ.append(name)
                print(f"{name:40s} {dt:6.1f} s  " + ("same" if ref and not bad else
                      f"DIFFERENT: {', '.join(bad) if ref else 'not recorded'}"), flush=True)
            else:
                print(f"{name:40s} {dt:6.1f} s  {len(got[name])} hashes", flush=True)
    if a.write:
        a.write.parent.mkdir(parents=True, exist_ok=True)
        a.write.write_text(json.dumps(got, indent=1, sort_keys=True) + "\n")
    if differ:
        print(f"{len(differ)} case(s) differ: {', '.join(differ)}")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
