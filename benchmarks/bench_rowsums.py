"""Row sums of F in a closed scene: the furnace cube, where every row must sum to exactly 1.
Per camera resolution and kernel (point, disc, point-nf): max |row sum - 1| over the
sub-elements (front sides), and for point-nf the near-field pairs (unordered pairs a < b, each
stored once) per sub-element. The
partition is the camera's alone (radiosity.subdivide.unseen: keep, as the docs' table was
measured: unseen faces whole), and rows are not balanced or capped (what the kernel gives).

    python benchmarks/bench_rowsums.py [--res 8,16,32,64] [--unseen keep|refine]

docs/src/measurements/kernels.md: the furnace row-sum table ("Measured on the furnace cube, max |row sum - 1|") and the
near-field pairs per sub-element come from this script.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
import warnings

import dask.config
import numpy as np

from common import ROOT, table, write

from radiosity.runtime.cluster import open_client
from radiosity.methods.pairs.transport import open_operator
from radiosity.stages.preprocess import preprocess
from radiosity.scene.load import load_scene
from radiosity.runtime.store import RunStore
from radiosity.methods.pairs.visibility import compute_visibility
from radiosity.settings import options as settings_of

CUBE = os.path.join(ROOT, "scenes", "furnace-cube", "scene.toml")
KERNELS = ("point", "disc", "point-nf")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--res", default="8,16,32,64")
    ap.add_argument("--unseen", default="keep", choices=("keep", "refine"))
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    rows = []
    with open_client(args.workers, quiet=True, settings=settings_of().cluster) as client, \
            dask.config.set({"radiosity.subdivide.unseen": args.unseen}):
        for res in (int(r) for r in args.res.split(",")):
            with tempfile.TemporaryDirectory() as d:
                preprocess(load_scene(CUBE, resolution=res, settings=settings_of()), d, client,
                           settings_of(), progress=False)
                compute_visibility(d, client, settings_of(), progress=False)
                rs = RunStore(d)
                row = {"resolution": res, "sub_elements": len(rs.load_partition())}
                for kernel in KERNELS:
                    t = time.perf_counter()
                    op, part, _ = open_operator(rs, client, kernel, settings_of())
                    sums = op.row_sums()[0]
                    row[f"{kernel}_max_dev"] = float(np.abs(sums - 1).max())
                    row[f"{kernel}_s"] = round(time.perf_counter() - t, 2)
                    if op.sparse is not None:
                        pairs = int(op.sparse["figures"]["pairs"])
                        row["near_pairs"] = pairs  # unordered pairs (a, b), a < b
                        row["near_pairs_per_sub_element"] = pairs / len(part)
                rows.append(row)
                print(f"  {res}^2: {row}", flush=True)
    print(table(rows, ["resolution", "sub_elements", *(f"{k}_max_dev" for k in KERNELS), "near_pairs",
                       "near_pairs_per_sub_element"]))
    print("wrote", write("rowsums", rows, {"scene": "furnace-cube", "unseen": args.unseen,
                                            "workers": args.workers}))


if __name__ == "__main__":
    main()
