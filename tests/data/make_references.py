"""Regenerate the stored coarse references of tests/test_cli.py: the image of each built-in
scene without an exact answer, rendered exactly as the test renders it (`radiosity render SCENE
--resolution 16 --tol 1e-6` with the other defaults, on a LocalCluster of 2 single-threaded worker processes).

    PYTHONPATH=$PWD/.shim python tests/data/make_references.py [scene ...]

Writes tests/data/render16-<scene>.npy (the linear image.exr as float32, (16, 16, 3)) and
tests/data/references.json (how each was made: command, git commit, date, figures). Rerun it
when a change to the engine changes these images on purpose, and say why in the commit.
"""

from __future__ import annotations

import datetime
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
SCENES = ["cornell-box", "three-rectangles", "construction-in-wood", "room-2400"]
RESOLUTION = 16


def main(names):
    from distributed import Client, LocalCluster
    from click.testing import CliRunner

    from radiosity.cli.commands import main as cli
    from radiosity.stages.image import read_exr

    meta_fn = os.path.join(HERE, "references.json")
    meta = json.load(open(meta_fn)) if os.path.exists(meta_fn) else {}
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=40) as cluster, Client(cluster) as c:
        for name in names:
            with tempfile.TemporaryDirectory() as d:
                scene = os.path.join("scenes", name, "scene.toml")
                args = ["render", os.path.join(ROOT, scene), "--out", d,
                        "--resolution", str(RESOLUTION), "--tol", "1e-6",
                        "--scheduler", c.scheduler.address]
                r = CliRunner().invoke(cli, args)
                if r.exit_code != 0:
                    sys.exit(f"{name}: render failed:\n{r.output}")
                img = read_exr(os.path.join(d, "image.exr")).astype(np.float32)
                rep = json.load(open(os.path.join(d, "report.json")))
            np.save(os.path.join(HERE, f"render{RESOLUTION}-{name}.npy"), img)
            dirty = subprocess.run(["git", "status", "--porcelain", "app"], cwd=ROOT,
                                   capture_output=True, text=True).stdout.strip()
            meta[name] = {"command": f"radiosity render {scene} --resolution {RESOLUTION}",
                          "commit": commit + (" + uncommitted changes to app/" if dirty else ""), "date": datetime.date.today().isoformat(),
                          "sub_elements": rep["preprocess"]["sub_elements"],
                          "kernel": rep["solve"]["kernel"], "solver": rep["solve"]["solver"],
                          "final_residual": rep["solve"]["final_residual"],
                          "mean": float(img.mean())}
            print(f"{name}: {img.shape}, mean {img.mean():.6g}, {meta[name]['sub_elements']} sub-elements")
    with open(meta_fn, "w") as f:
        json.dump(meta, f, indent=2, sort_keys=True)
        f.write("\n")


if __name__ == "__main__":
    main(sys.argv[1:] or SCENES)
