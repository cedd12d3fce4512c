"""What accuracy costs in time: `radiosity study accuracy` sweeps the settings and times them
(`accuracy`: each camera resolution x sub-pixel factor x kernel x solver tolerance, run, timed
and measured against a reference, see its docstring). `seed`, the seed's experiments, lives in
validation.seed_experiments (re-exported here).

Outputs in OUT: results.csv, results.md (Markdown table) and accuracy.png (log-log error against
time, the Pareto front marked: the settings no other setting beats in both).
"""

from __future__ import annotations

import csv
import itertools
import os
import time
import warnings

import numpy as np

from radiosity.errors import RadiosityError
from radiosity.core.kernels import MC, NXM, get_kernel, kernel_id
from radiosity.core.solvers import choose_solver
from radiosity.settings import Settings, sampling_of
from radiosity.validation.seed_experiments import seed

__all__ = ["COLUMNS", "PATH_TRACER", "HIER", "pareto", "resample", "image_error",
           "sampled_radiance", "kernel_setting", "overridden", "form_factor_of_run", "accuracy",
           "against_mitsuba", "write_results", "plot", "seed"]

COLUMNS = ["resolution", "subpixel", "kernel", "direct", "solver", "tol", "sub_elements", "passes", "time_preprocess_s",
           "time_visibility_s", "time_solve_s", "time_image_s", "time_total_s", "error", "pareto",
           "spp", "error_surface", "noise_floor"]
PATH_TRACER = "path tracer"


def pareto(times, errors) -> np.ndarray:
    """(k,) bool: not dominated (no other point is at least as fast and as accurate, and better
    in one)."""
    t, e = np.asarray(times, float), np.asarray(errors, float)
    out = np.ones(len(t), bool)
    for i in range(len(t)):
        better = (t <= t[i]) & (e <= e[i]) & ((t < t[i]) | (e < e[i]))
        out[i] = not better.any()
    return out


def resample(img: np.ndarray, h: int, w: int) -> np.ndarray:
    """Box-filter (integer factor) or nearest-sample an (H, W, 3) image to (h, w, 3)."""
    H, W = img.shape[:2]
    if H % h == 0 and W % w == 0:
        return img.reshape(h, H // h, w, W // w, -1).mean(axis=(1, 3))
    rows = ((np.arange(h) + 0.5) * H / h).astype(int)
    cols = ((np.arange(w) + 0.5) * W / w).astype(int)
    return img[rows][:, cols]


def image_error(img: np.ndarray, ref: np.ndarray) -> float:
    """Relative RMS difference, both on the coarser of the two grids."""
    h, w = min(img.shape[0], ref.shape[0]), min(img.shape[1], ref.shape[1])
    a, b = resample(img, h, w), resample(ref, h, w)
    return float(np.sqrt(np.mean((a - b) ** 2)) / max(np.sqrt(np.mean(b ** 2)), 1e-300))


def sampled_radiance(part, L: np.ndarray, orig: np.ndarray, points: np.ndarray, camera) -> np.ndarray:
    """Radiance L (m, 2, 3) of partition `part` at hit points (k, 3) on the originals `orig` (k,),
    on the side facing the camera: (k, 3)."""
    from radiosity.scene.subdivide import lookup

    sub = lookup(part, points, orig)
    out = np.zeros((len(orig), 3))
    ok = sub >= 0
    s = sub[ok]
    side = (np.einsum("ij,ij->i", part.normal[s], camera.center - part.center[s]) <= 0).astype(int)
    out[ok] = L[s, side]
    return out


HIER = "hier"  # a sweep label hier:EPSILON:RAYS[:DIRECT] is --method hierarchical with those settings
DIRECT_MODES = ("auto", "points", "links")


def kernel_setting(spec: str, settings: Settings):
    """A kernel of a sweep: "point", or a sampled kernel with its sample count, "nxm:16"
    (points per element) or "mc:64" (sample pairs), or the hierarchical method with its
    epsilon, link rays and optionally where the emitters' light is taken (direct.mode, SPEC
    §10: the old way "links" beside the new "points"), "hier:1e-3:16" or "hier:1e-3:16:points"
    (kernel: hierarchy.kernel of `settings`). Returns (kernel, dask.config overrides
    {"radiosity.section.key": value}; `overridden` makes them a Settings)."""
    name, _, n = spec.partition(":")
    if name == HIER:
        eps, _, k = n.partition(":")
        k, _, mode = k.partition(":")
        try:
            eps, k = float(eps), int(k)
        except ValueError:
            raise RadiosityError(f"setting {spec!r}: the hierarchical method is "
                                 "hier:EPSILON:RAYS[:DIRECT], e.g. hier:1e-3:16 or "
                                 "hier:1e-3:16:points") from None
        if not (eps >= 0 and k >= 1 and int(round(k ** 0.5)) ** 2 == k):
            raise RadiosityError(f"setting {spec!r}: epsilon >= 0 and a square number of link rays")
        if mode and mode not in DIRECT_MODES:
            raise RadiosityError(f"setting {spec!r}: the direct light's mode must be one of "
                                 f"{', '.join(DIRECT_MODES)}")
        return settings.hierarchy.kernel, {
            "radiosity.visibility.method": "hierarchical", "radiosity.hierarchy.epsilon": eps,
            "radiosity.hierarchy.link-rays": k, **({"radiosity.direct.mode": mode} if mode else {})}
    kid = kernel_id(name)
    if not n:
        return name, {}
    if kid not in (NXM, MC) or not n.isdigit():
        raise RadiosityError(f"kernel {spec!r}: only nxm:N and mc:k take a sample count (an integer)")
    return name, {"radiosity.solve." + ("nxm-points" if kid == NXM else "mc-samples"): int(n)}


def overridden(settings: Settings, overrides: dict) -> Settings:
    """`settings` with kernel_setting's dask.config overrides ({"radiosity.solve.nxm-points": 16})
    applied."""
    return settings.replace({k.removeprefix("radiosity."): v for k, v in overrides.items()})


def _visibility_key(spec: str, settings: Settings) -> str:
    """Which visibility matrix (or link set) `spec` needs ("" for one ray between centres)."""
    if spec.startswith(HIER + ":"):
        return spec
    kernel, overrides = kernel_setting(spec, settings)
    smp = sampling_of(overridden(settings, overrides).solve, kernel)
    return "" if smp is None else str(smp.to_dict())


def form_factor_of_run(run_dir: str, client, kernel: str, frm: str, to: str,
                       settings: Settings) -> float:
    """F from material `frm` to material `to` as the run's operator computes it (front sides),
    with `kernel`; settings: the operator's."""
    from radiosity.methods.base import method_of_run
    from radiosity.stages.solve import normalise_rows
    from radiosity.runtime.store import RunStore

    rs = RunStore(run_dir)
    opened = method_of_run(rs).open(rs, client, settings.replace({"solve.kernel": kernel}))
    op, orig, area = opened.op, opened.orig, opened.area
    _, scaling = normalise_rows(op)
    if scaling:
        op.configure(**scaling)
    el = rs.load_elements()
    names = np.array(el.material_names)[el.material[orig]]
    x = np.zeros((2, 1, len(orig)))
    x[0, 0, names == to] = 1.0
    y = op.apply(x, use_need=False)
    a = names == frm
    return float((area[a] * y[0, 0, a]).sum() / area[a].sum())


def accuracy(scene_path: str, out: str, client, resolutions, subpixels, kernels, tols,
             reference: str | None = None, solver: str | None = None, echo=print,
             reference_spp: int | None = None, path_tracer_spp=None, *,
             settings: Settings) -> list[dict]:
    """Run the sweep; write results.csv, results.md and accuracy.png into `out` (with
    `reference="auto"` also surfaces.csv and the Mitsuba reference(s) in out/reference/).

    For each camera resolution x sub-pixel factor x kernel x solver tolerance, the stages are
    run and timed (_sweep_run) and the error is measured against a reference:

    - validation scenes (a `[validation]` table in the scene TOML): `form_factor` is the exact
      form factor between two materials (Howell's catalogue), compared with the one the run's
      operator gives (sum of A_a F_ab over the pairs, divided by the area of `from`); `radiance`
      is the exact radiance everywhere (furnace scenes: Le / (1 - rho));
    - otherwise the finest setting: every run's radiance is sampled where the finest setting's
      camera rays hit (the two-level lookup into each run's own partition), so runs of different
      resolutions are compared at the same points, without aliasing; the relative RMS difference;
    - or a reference image the user gives (EXR): the relative RMS difference of the images, the
      finer one box-filtered to the coarser grid;
    - or, with `reference="auto"`, ground truth path-traced by Mitsuba 3 (validation.reference)
      at the finest resolution (box-filtered to the coarser ones that divide it, rendered again
      at the others), made once and reused: the mean absolute relative error per pixel over the
      pixels wholly inside one original element (compare.interior), the mean per-surface error,
      and the reference's own noise level. The path tracer itself joins the sweep at several
      sample counts (its error against the higher-spp reference, its time), so the Pareto front
      shows where each method wins.

    solver: solve.solver (None: that of `settings`, the run's settings.Settings).
    """
    from radiosity.methods.base import all_pairs_method
    from radiosity.stages.preprocess import preprocess
    from radiosity.stages.image import read_exr
    from radiosity.scene.load import load_scene

    s = settings.replace({"solve.solver": solver})
    os.makedirs(out, exist_ok=True)
    val = load_scene(scene_path, settings=s).validation
    if reference == "auto" and val:
        raise RadiosityError(f"{scene_path}: the scene has a [validation] table, whose exact answer is "
                             "the study's reference; --reference auto is for scenes without one")
    rows = []
    images = {}
    # warm-up (numba kernels load from cache, Embree and workers start): not timed
    warm = os.path.join(out, "runs", "warm-up")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        preprocess(load_scene(scene_path, resolution=min(resolutions), settings=s), warm, client,
                   s, progress=False)
    all_pairs_method().build(warm, client, s, progress=False)
    for res, k in sorted(itertools.product(resolutions, subpixels)):
        run = os.path.join(out, "runs", f"r{res}-k{k}")
        rows += _sweep_run(scene_path, run, client, res, k, kernels, tols, reference, images,
                           echo, s)
    if images and reference == "auto":  # against Mitsuba; the path tracer joins the sweep
        rows += against_mitsuba(scene_path, out, rows, images, resolutions, reference_spp,
                                path_tracer_spp, echo, settings=s)
    elif images and reference:  # against the user's EXR
        ref = read_exr(reference)
        for r in rows:
            r["error"] = image_error(images[(r["resolution"], r["subpixel"], r["kernel"], r["tol"])], ref)
    elif images:  # against the finest setting, at its camera rays' hit points
        _against_finest(scene_path, rows, images, echo, s)
    # against Mitsuba, images of one size compete (radiosity at every K and the path tracer at
    # that resolution): a per-pixel error of a 16 x 16 image says nothing of a 64 x 64 one
    group = [r["resolution"] if reference == "auto" else 0 for r in rows]
    front = np.zeros(len(rows), bool)
    for g in set(group):
        idx = np.array([i for i, r in enumerate(rows) if group[i] == g and r["error"] > 0], int)
        if len(idx):
            front[idx] = pareto([rows[i]["time_total_s"] for i in idx], [rows[i]["error"] for i in idx])
    for r, p in zip(rows, front):
        r["pareto"] = bool(p)
    write_results(out, rows, os.path.basename(os.path.dirname(os.path.abspath(scene_path))))
    return rows


def _row_settings(label: str, settings: Settings):
    """(kernel, the row's settings, its method) of a sweep label: hier:EPSILON:RAYS states its
    method in the overrides (kernel_setting); a kernel is solved by the method that takes every
    pair as it is (methods/base.all_pairs_method)."""
    from radiosity.methods.base import all_pairs_method, stated_method

    kernel, overrides = kernel_setting(label, settings)
    # this row's settings: the sample count of nxm:N / mc:k, hier:EPSILON:RAYS's own, the kernel
    row = overridden(settings, {**overrides, "radiosity.solve.kernel": kernel})
    stated = "radiosity.visibility.method" in overrides
    return kernel, row, stated_method(row) if stated else all_pairs_method()


def _sweep_run(scene_path: str, run: str, client, res: int, k: int, kernels, tols, reference,
               images: dict, echo, s: Settings) -> list[dict]:
    """The rows of one camera resolution x sub-pixel factor (accuracy): the scene preprocessed
    into `run` once, each sampling's visibility matrix (or link set) made once, every kernel
    solved at every tolerance, timed, and its error measured where the scene has an exact
    answer; the others keep their image (a user's reference) or solution (the finest setting)
    in `images` for accuracy to measure."""
    from radiosity.pipeline import direct_choice
    from radiosity.stages.preprocess import preprocess
    from radiosity.stages.image import read_exr, render_outputs
    from radiosity.scene.load import load_scene
    from radiosity.stages.solve import run_solve
    from radiosity.runtime.store import RunStore

    sc = load_scene(scene_path, resolution=res, settings=s)
    val = sc.validation
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pre = preprocess(sc, run, client, s.replace({"subdivide.subpixel": k}), progress=False)
    t_pre = time.perf_counter() - t
    t_vis = {}  # per sampling: one-ray kernels share one matrix, nxm / mc cast their own
    current = "none yet"
    rows = []
    # one matrix per sampling, each made once
    specs = sorted(kernels, key=lambda spec: _visibility_key(spec, s))
    for label, tol in itertools.product(specs, tols):
        kernel, row, method = _row_settings(label, s)
        key = _visibility_key(label, s)
        if key != current:
            t = time.perf_counter()
            method.build(run, client, row, progress=False)
            t_vis[key] = time.perf_counter() - t
            current = key
        t = time.perf_counter()
        passes = 0
        # cg needs a reciprocal kernel: the others are solved by Gauss-Seidel
        solve_with = row.solve.solver
        if solve_with == "cg" and not get_kernel(kernel).reciprocal:
            solve_with = "auto"
        solve_with = choose_solver(solve_with, kernel)
        if "form_factor" in val and not method.all_pairs:
            raise RadiosityError(f"{scene_path}: a form-factor validation scene compares the form "
                                 f"factors of every pair; sweep the {method.name} method on a "
                                 "scene with a radiance answer or an image reference")
        if "form_factor" in val:
            f = form_factor_of_run(run, client, kernel, val["from"], val["to"], settings=row)
            err = abs(f / val["form_factor"] - 1.0)
            t_solve, t_img = time.perf_counter() - t, 0.0
        else:
            fig = run_solve(run, client, row.replace({"solve.solver": solve_with, "solve.tol": tol}),
                            progress=False, method=method.name)
            passes = fig.iterations
            t_solve = time.perf_counter() - t
            t = time.perf_counter()
            render_outputs(run, exposure="auto", settings=row)
            t_img = time.perf_counter() - t
            rs = RunStore(run)
            if "radiance" in val:
                part = rs.load_partition()
                L = rs.read_arrays("solution")["radiance"][:, 0, :]
                err = float((part.area[:, None] * np.abs(L / val["radiance"] - 1)).sum()
                            / (3 * part.area.sum()))
            else:  # keep the image (user's reference) or the solution (finest setting)
                images[(res, k, label, tol)] = (read_exr(os.path.join(run, "image.exr")) if reference
                                                else (run, rs.read_arrays("solution")["radiance"]))
                err = np.nan
        rows.append({"resolution": res, "subpixel": k, "kernel": label,
                     "direct": direct_choice(method.name, sc.elements, row)[0],
                     "solver": solve_with if "form_factor" not in val else "-", "tol": tol,
                     "sub_elements": pre["sub_elements"], "passes": passes,
                     "time_preprocess_s": t_pre, "time_visibility_s": t_vis[key],
                     "time_solve_s": t_solve, "time_image_s": t_img,
                     "time_total_s": t_pre + t_vis[key] + t_solve + t_img, "error": err})
        echo(f"  {res}x{res} K={k} {label} tol={tol:g}: "
             f"{'error at the end' if np.isnan(err) else f'error {err:.3g}'}, "
             f"{rows[-1]['time_total_s']:.2f} s")
    return rows


def _against_finest(scene_path: str, rows: list[dict], images: dict, echo, s: Settings) -> None:
    """Every row's error (in place) against the finest setting's radiance, sampled at its camera
    rays' hit points (images[(res, K, kernel, tol)]: (run, solution radiance))."""
    from radiosity.runtime.store import RunStore
    from radiosity.scene.load import load_scene
    from radiosity.tracing.rays import RayCaster, raster_band

    key = max(images, key=lambda q: (q[0] * q[1], -q[3], q[2] == "point-nf", q[2] == "point"))
    echo(f"  reference: the finest setting {key[0]}x{key[0]} K={key[1]} {key[2]} tol={key[3]:g}")
    fine = load_scene(scene_path, resolution=key[0], settings=s)
    rc = RayCaster(fine.elements.verts, fine.elements.nverts, float(s.rays.offset))
    h = fine.camera.height * key[1]
    orig, pts = raster_band(rc, fine.elements.normal, fine.elements.center, fine.camera, key[1],
                            slice(0, h))
    hit = orig >= 0
    orig, pts = orig[hit], pts[hit]

    def sample(q):
        run, L = images[q]
        return sampled_radiance(RunStore(run).load_partition(), L, orig, pts, fine.camera)

    ref = sample(key)
    norm = max(float(np.sqrt(np.mean(ref ** 2))), 1e-300)
    for r in rows:
        q = (r["resolution"], r["subpixel"], r["kernel"], r["tol"])
        r["error"] = float(np.sqrt(np.mean((sample(q) - ref) ** 2)) / norm)


def against_mitsuba(scene_path: str, out: str, rows: list[dict], images: dict, resolutions,
                    spp: int | None = None, path_tracer_spp=None, echo=print, *,
                    settings: Settings) -> list[dict]:
    """Measure every row's image (images[(res, K, kernel, tol)], (res, res, 3)) against Mitsuba
    ground truth, in place: `error` (mean absolute relative error over the pixels wholly inside
    one element), `error_surface` (mean over the elements seen of their mean's relative error),
    `noise_floor` (what an exact image would show against this reference). Renders the path
    tracer at `path_tracer_spp` (default: 1, 4, 16, ... up to spp / 16) at every resolution of
    the sweep and returns its rows; writes surfaces.csv (per element, per setting). spp None:
    reference.study-spp of `settings`."""
    from radiosity.validation.compare import box_down, box_down_stderr, element_raster, errors, interior, noise_floor, surface_errors
    from radiosity.validation.reference import path_tracer_runs, reference_at
    from radiosity.scene.load import load_scene

    s = settings.replace({"reference.study-spp": spp})
    spp = int(s.reference.study_spp)
    passes = int(s.reference.passes)
    finest = max(resolutions)
    fine_scene = load_scene(scene_path, resolution=finest, settings=s)
    refs = {finest: reference_at(fine_scene, os.path.join(out, "reference", f"r{finest}"), spp, passes, echo,
                                 settings=s)[:2]}
    truth = {}
    for res in sorted(set(resolutions)):
        sc = load_scene(scene_path, resolution=res, settings=s)
        if res not in refs:
            h, w = sc.camera.height, sc.camera.width
            m, se = refs[finest]
            if m.shape[0] % h == 0 and m.shape[1] % w == 0:  # a box-filtered pixel is the exact mean
                refs[res] = box_down(m, h, w), box_down_stderr(se, h, w)
            else:
                refs[res] = reference_at(sc, os.path.join(out, "reference", f"r{res}"), spp, passes, echo,
                                         settings=s)[:2]
        raster = element_raster(sc)
        mask = interior(raster)
        truth[res] = (*refs[res], raster, mask, noise_floor(refs[res][0], refs[res][1], mask))
    el = fine_scene.elements
    surfaces = []

    def measure(row, img):
        ref, se, raster, mask, floor = truth[row["resolution"]]
        row["error"] = errors(img, ref, mask)["mare"]
        per = surface_errors(img, ref, raster, mask, se)
        row["error_surface"] = float(np.mean([d["error"] for d in per.values()])) if per else float("nan")
        row["noise_floor"] = floor
        for e, d in per.items():
            surfaces.append({"resolution": row["resolution"], "subpixel": row["subpixel"],
                             "kernel": row["kernel"], "tol": row["tol"], "spp": row["spp"], "element": e,
                             "material": el.material_names[el.material[e]], "pixels": d["pixels"],
                             "error": d["error"], "reference_stderr": d["stderr"]})

    for r in rows:
        r["spp"] = 0
        measure(r, images[(r["resolution"], r["subpixel"], r["kernel"], r["tol"])])
        echo(f"  {r['resolution']}x{r['resolution']} K={r['subpixel']} {r['kernel']} tol={r['tol']:g}: "
             f"error {r['error']:.3g} (per surface {r['error_surface']:.3g}), {r['time_total_s']:.2f} s")
    if path_tracer_spp is None:
        path_tracer_spp = [4 ** i for i in range(12) if 4 ** i <= max(1, spp // 16)]
    pt = []
    for res in sorted(set(resolutions)):  # at every resolution, so equal images are compared
        for run in path_tracer_runs(load_scene(scene_path, resolution=res, settings=s),
                                    path_tracer_spp, echo=lambda *a: None, settings=s):
            r = {"resolution": res, "subpixel": 1, "kernel": PATH_TRACER, "solver": f"mitsuba {run['variant']}",
                 "tol": float("nan"), "sub_elements": 0, "passes": 0, "time_preprocess_s": 0.0,
                 "time_visibility_s": 0.0, "time_solve_s": run["time_s"], "time_image_s": 0.0,
                 "time_total_s": run["time_s"], "spp": run["spp"]}
            measure(r, run["image"])
            pt.append(r)
            echo(f"  path tracer {res}x{res} {run['spp']} spp: error {r['error']:.3g} (per surface "
                 f"{r['error_surface']:.3g}), {run['time_s']:.2f} s")
    with open(os.path.join(out, "surfaces.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(surfaces[0]) if surfaces else ["resolution"])
        w.writeheader()
        w.writerows(surfaces)
    return pt


def write_results(out: str, rows: list[dict], title: str) -> None:
    with open(os.path.join(out, "results.csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, "") for k in COLUMNS})
    mitsuba = any("noise_floor" in r for r in rows)
    with open(os.path.join(out, "results.md"), "w") as f:
        f.write("| resolution | K | kernel | direct light | solver | tol | sub-elements | passes | "
                "total s | error | " + ("surface error | " if mitsuba else "") + "Pareto |\n")
        f.write("|---:|---:|---|---|---|---:|---:|---:|---:|---:|" + ("---:|" if mitsuba else "")
                + ":---:|\n")
        for r in rows:
            pt = r["kernel"] == PATH_TRACER
            f.write(f"| {r['resolution']} | {r['subpixel']} | "
                    f"{r['kernel'] + (', ' + str(r['spp']) + ' spp' if pt else '')} | "
                    f"{r.get('direct', '-')} | {r['solver']} | "
                    f"{'-' if pt else format(r['tol'], 'g')} | {r['sub_elements'] if not pt else '-'} | "
                    f"{r['passes'] if not pt else '-'} | {r['time_total_s']:.2f} | {r['error']:.3g} | "
                    + (f"{r.get('error_surface', float('nan')):.3g} | " if mitsuba else "")
                    + f"{'*' if r['pareto'] else ''} |\n")
        if mitsuba:
            floors = sorted({(r["resolution"], r["noise_floor"]) for r in rows})
            f.write("\nerror: mean absolute relative error over the pixels wholly inside one element, "
                    "against Mitsuba 3; surface error: the mean over the elements of their mean's "
                    "relative error. The reference's own noise (the error an exact image would show): "
                    + ", ".join(f"{res}x{res}: {fl:.3g}" for res, fl in floors) + ".\n")
    plot(os.path.join(out, "accuracy.png"), rows, title)


def plot(path: str, rows: list[dict], title: str) -> None:
    """Log-log error against total time, one marker per kernel, the path tracer as one line per
    resolution (labels: samples per pixel), the reference's noise level per resolution as dashed lines, the
    Pareto front (over every method; per resolution when the path tracer is there) as step
    lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.2, 4.8), dpi=110)
    markers = itertools.cycle("osD^v<>")
    for kernel in sorted({r["kernel"] for r in rows} - {PATH_TRACER}):
        rr = [r for r in rows if r["kernel"] == kernel and r["error"] > 0]
        ax.scatter([r["time_total_s"] for r in rr], [r["error"] for r in rr], marker=next(markers),
                   label=kernel, zorder=3)
        for r in rr:
            ax.annotate(f"{r['resolution']}" + (f"·{r['subpixel']}" if r["subpixel"] > 1 else ""),
                        (r["time_total_s"], r["error"]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
    pts = [r for r in rows if r["kernel"] == PATH_TRACER and r["error"] > 0]
    shades = matplotlib.colormaps["Purples"]
    res_pt = sorted({r["resolution"] for r in pts})
    for i, res in enumerate(res_pt):
        pt = sorted([r for r in pts if r["resolution"] == res], key=lambda r: r["spp"])
        colour = shades(0.45 + 0.5 * (i + 1) / len(res_pt))
        ax.plot([r["time_total_s"] for r in pt], [r["error"] for r in pt], "-x", color=colour, lw=1.2,
                label=f"path tracer {res}² ({pt[0]['solver']})", zorder=3)
        for r in pt:
            ax.annotate(f"{r['spp']}", (r["time_total_s"], r["error"]), fontsize=6, xytext=(2, -8),
                        textcoords="offset points", color=colour)
    floors = sorted({(r["resolution"], r["noise_floor"]) for r in rows
                     if np.isfinite(r.get("noise_floor", np.nan))})
    for i, (res, fl) in enumerate(floors):
        ax.axhline(fl, color="0.35", ls=(0, (4, 3)), lw=0.9, zorder=1,
                   label="reference noise (per resolution)" if i == 0 else None)
        ax.annotate(f"{res}²", (1.0, fl), xycoords=("axes fraction", "data"), fontsize=7,
                    xytext=(-16, 2), textcoords="offset points", color="0.35")
    groups = sorted({r["resolution"] for r in rows}) if pts else [None]  # see accuracy()
    for i, g in enumerate(groups):
        front = sorted([r for r in rows if r.get("pareto") and g in (None, r["resolution"])],
                       key=lambda r: r["time_total_s"])
        if front:
            ax.step([r["time_total_s"] for r in front], [r["error"] for r in front], where="post",
                    color="k", lw=1 if g in (None, groups[-1]) else 0.7, alpha=0.6 if g in (None, groups[-1]) else 0.3,
                    label=("Pareto front" if g is None else "Pareto front per resolution") if i == 0 else None,
                    zorder=2)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time, all stages (s)")
    ax.set_ylabel("mean abs. relative error per pixel" if floors else "relative error")
    ax.set_title(f"{title}: what accuracy costs (labels: resolution·K" + (", spp" if pts else "") + ")" +
                 (" against Mitsuba 3" if floors else ""), fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
