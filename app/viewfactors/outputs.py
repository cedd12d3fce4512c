"""The view-factor stage's outputs: the closure test and row balancing of the assembled matrix
(the render's: scene/closure.py, core/balancing.py),
the checks and their warnings, the figures of report.json, and the files (the matrix into the
run store, viewfactors.npz, facets.csv, viewfactors.csv).
"""

from __future__ import annotations

import csv
import os
import warnings

import numpy as np

from radiosity.errors import RadiosityError
from radiosity.settings import ViewFactorSettings
from radiosity.viewfactors.facets import Facets

HIST_EDGES = (0.0, 0.25, 0.5, 0.75, 0.9, 0.99, 0.999, 1.001, 1.01, np.inf)


def row_histogram(rows: np.ndarray) -> dict:
    """Counts of row sums in the bins of HIST_EDGES, as {"[a, b)": count}."""
    h, _ = np.histogram(rows, bins=np.array(HIST_EDGES))
    names = [f"[{a:g}, {b:g})" for a, b in zip(HIST_EDGES[:-1], HIST_EDGES[1:])]
    return dict(zip(names, h.tolist()))


def _worst(fac: Facets, values: np.ndarray, idx: np.ndarray, k: int = 5) -> str:
    return "; ".join(f"{fac.describe(int(i))}: {values[i]:.6g}" for i in idx[:k])


def facet_closure(fac: Facets, ray_offset: float):
    """The render's closure test (scene/closure.detect_closure: rays per element side) on the
    facets as one-sided elements: per facet front, contact (covered by a touching surface), the
    fraction of its hemisphere that reaches geometry (target) and whether that is exactly 1 or
    0 (exact). Touching furniture, T-junctions and winding that does not match across an edge
    do not make a closed room open, as an edge-topology test would. ray_offset: rays.epsilon."""
    from radiosity.core.bundles import Elements
    from radiosity.scene.closure import detect_closure

    n = len(fac)
    el = Elements(verts=fac.verts, nverts=fac.nverts, normal=fac.normal, center=fac.center,
                  area=fac.area, reflectance=np.zeros((n, 2, 3)), emission=np.zeros((n, 2, 3)),
                  two_sided=np.zeros(n, bool), material=np.zeros(n, np.int32),
                  source=fac.source, face=fac.face, material_names=("facet",),
                  sources=tuple(os.path.basename(x) for x in fac.sources))
    return detect_closure(el, float(ray_offset))


def open_by_row(rows0: np.ndarray, accuracy: float) -> np.ndarray:
    """(n,) bool: rows that sum to less than 1 - max(10 x accuracy, 5e-3) before balancing.
    In an open scene such a facet sees the environment even where the closure's rays all met
    front faces: the closure casts the same 16 directions from every facet of one orientation,
    and all of them can miss a window of sky that the pairs' own factors account for (the
    lowest wall cells of a street canyon in benchmarks/bench_viewfactors.py's urban scene:
    rows 0.88, which auto balanced to 1). 10 x the accuracy: the warning's threshold for a
    balanced row (a row adds up about a hundred factors, each within the accuracy)."""
    return rows0 < 1.0 - max(10.0 * accuracy, 5e-3)


def open_scene_targets(rt, cl, rows0: np.ndarray, accuracy: float):
    """(targets, count) in a scene the closure `cl` found open: an open scene (or one with a
    cavity of wrongly wound faces) is still closed around the facets whose every ray met a
    front face, and those rows are balanced too, unless their own row says otherwise
    (open_by_row: `count` of them). rt: core.balancing.RowTargets; rows0 (n,) before
    balancing."""
    from radiosity.core.balancing import RowTargets

    lost0 = rt.balance & (cl.lost[:, 0] == 0) & (rt.target == 1)
    closed_rows = lost0 & ~open_by_row(rows0, accuracy)
    return RowTargets(rt.target, closed_rows, rt.dead, rt.sided), int((lost0 & ~closed_rows).sum())


def balance_matrix(F, rows, tol: float, max_iterations: int):
    """core.balancing.balance_rows on the CSR matrix F (n x n, A F symmetric) with the row
    targets `rows` (core.balancing.RowTargets: balanced rows to their target, the other live
    rows capped at 1, dead rows and columns 0). Returns (F' = D F D as a new CSR matrix, d (n,),
    passes, error, rows stopped at the scaling bound)."""
    import scipy.sparse as sp

    from radiosity.core.balancing import balance_rows

    sums = np.asarray(F.sum(axis=1)).ravel()[None, :]

    def apply(d):
        Fd = F @ d
        return Fd, Fd

    d, passes, err, stuck = balance_rows(apply, sums, rows.target, rows.balance, rows.dead,
                                         tol, max_iterations)
    r = np.repeat(np.arange(F.shape[0]), np.diff(F.indptr))
    out = sp.csr_matrix((F.data * (d[r] * d[F.indices]), F.indices.copy(), F.indptr.copy()),
                        shape=F.shape)
    out.eliminate_zeros()
    return out, d, passes, err, stuck


def finish(rs, out: str, fac: Facets, asm, vf: ViewFactorSettings, fmt: str,
           ray_offset: float = 1e-6) -> dict:
    """Closure test and row handling of the assembled matrix `asm` (master.Assembled), checks
    and warnings against vf.accuracy, outputs (fmt: npz | csv). vf.enclosure: auto balances
    the rows whose side the closure finds closed to 1 (in a closed scene every side it snapped
    to 1; in an open one, or one with a cavity of wrongly wound faces, the sides that lost no
    ray) and caps every other row at 1; on balances every row to 1 (rows below half of it capped); off leaves the
    rows as computed. Facets covered by a touching surface take no part in any mode. Returns
    the figures (with the final matrix under "_matrix")."""
    import scipy.sparse as sp

    from radiosity.core.balancing import RowTargets
    from radiosity.viewfactors.store import write_vf_matrix
    from radiosity.viewfactors.loops import reciprocity_residual

    mode, accuracy = vf.enclosure, float(vf.accuracy)
    F = asm.matrix
    n = F.shape[0]
    A = fac.area
    cl = facet_closure(fac, ray_offset)
    rt = RowTargets.of(cl, np.arange(n), np.zeros(n, bool))
    # a facet partly inside a solid (under a block whose bottom faces the wrong way) sees less
    # than its hemisphere, as a partly covered one: capped, not balanced; one wholly inside
    # sees nothing, as a covered one
    part = (cl.inside[:, 0] > 0) & (cl.inside[:, 0] < 1)
    buried = cl.inside[:, 0] >= 1
    rt = RowTargets(rt.target, rt.balance & ~part & ~buried, rt.dead | buried, rt.sided)
    contact = rt.dead
    if contact.any():  # as in the radiosity path: covered facets neither receive nor send
        keep = sp.diags(np.where(contact, 0.0, 1.0))
        F = sp.csr_matrix(keep @ F @ keep)
        F.eliminate_zeros()
    rows0 = np.asarray(F.sum(axis=1)).ravel()
    seen_open = 0
    if mode == "auto" and not cl.closed:
        rt, seen_open = open_scene_targets(rt, cl, rows0, accuracy)
    do_balance = mode == "on" or (mode == "auto" and bool((rt.balance & (rows0 > 0)).any()))
    if mode == "on":
        rt = RowTargets(np.ones(n), ~contact, contact, rt.sided)
    elif not do_balance:
        rt = RowTargets(rt.target, np.zeros(n, bool), contact, rt.sided)
    fig: dict = {"enclosure_mode": mode, "closed": cl.closed, "enclosure": cl.closed,
                 "not_enclosure_because": "" if cl.closed else cl.reason,
                 "closure": cl.to_dict(), "balanced": do_balance, "nonzeros": int(F.nnz),
                 "contact_facets": int(cl.contact[:, 0].sum()),
                 "inside_facets": int(buried.sum()),
                 "partly_covered_facets": int(cl.counts["partly_covered_sides"]),
                 "partly_inside_facets": int(part.sum()),
                 "rows_open_by_their_sum": seen_open,
                 "row_sum_min": float(rows0.min()), "row_sum_max": float(rows0.max()),
                 "row_sum_histogram": row_histogram(rows0),
                 "obstructed_over_unobstructed": asm.violations,
                 "cheap_kernel_row_bound_max": float(asm.cheap_bound.max(initial=0.0)),
                 "dropped_row_bound_max": float(asm.dropped_bound.max(initial=0.0))}
    if mode == "on" and not cl.closed:
        warnings.warn(f"--enclosure on: the facets do not form an enclosure ({cl.reason}); "
                      "their rows are balanced to 1 all the same")
    scale = np.ones(n)
    if mode != "off":
        if do_balance:
            dev = np.where(rt.balance, np.abs(rows0 - rt.target), 0.0)
            bad = np.argsort(-dev)
            if dev[bad[0]] > 10 * accuracy:
                warnings.warn(f"enclosure rows sum to their target +- {dev[bad[0]]:.3g} before "
                              f"balancing (more than 10 x the accuracy {accuracy:g}); worst rows: "
                              f"{_worst(fac, rows0, bad)}")
        F, scale, passes, err, stuck = balance_matrix(F, rt, float(vf.balance_tol),
                                                      int(vf.balance_max_iterations))
        converged = err <= float(vf.balance_tol)  # over the rows not stopped at the bound
        fig.update({"rows_balanced": int((rt.balance & (rows0 > 0)).sum()),
                    "balance_iterations": passes, "balance_converged": bool(converged),
                    "balance_residual": err, "rows_at_scaling_bound": stuck,
                    "balance_scale_min": float(scale[rows0 > 0].min(initial=1.0)),
                    "balance_scale_max": float(scale[rows0 > 0].max(initial=1.0))})
        if not converged:
            warnings.warn(f"balancing stopped after {passes} passes with rows within "
                          f"{err:.3g} of their targets")
        if stuck:
            warnings.warn(f"{stuck} rows stopped at the balancing's scaling bound (facets in a "
                          "thin gap whose rows cannot be balanced together): they keep that scale")
    rows = np.asarray(F.sum(axis=1)).ravel()
    diag = F.diagonal()
    fig.update({
        "row_sum_final_min": float(rows.min()), "row_sum_final_max": float(rows.max()),
        "row_sum_final_histogram": row_histogram(rows),
        "factor_min": float(F.data.min()) if F.nnz else 0.0,
        "factor_max": float(F.data.max()) if F.nnz else 0.0,
        "self_factors": int(np.count_nonzero(diag)),
        "reciprocity_residual_max": float(reciprocity_residual(F.indptr, F.indices.astype(np.int64),
                                                               F.data, A)),
        "rows_with_no_factor": int(np.count_nonzero(rows == 0)),
    })
    over = np.nonzero(rows > 1.0 + max(accuracy, 1e-12))[0]
    fig["rows_over_1"] = int(len(over))
    if len(over):
        worst = over[np.argsort(-rows[over])]
        warnings.warn(f"{len(over)} rows sum to more than 1 + {accuracy:g}: {_worst(fac, rows, worst)}")
    if fig["factor_min"] < 0 or fig["factor_max"] > 1:
        warnings.warn(f"factors outside [0, 1]: min {fig['factor_min']:.6g}, max {fig['factor_max']:.6g}")
    if asm.violations:
        warnings.warn(f"{asm.violations} pairs have an obstructed factor above the unobstructed one")
    # outputs
    write_vf_matrix(rs, F.indptr, F.indices, F.data, scale, {"balanced": do_balance})
    os.makedirs(out, exist_ok=True)
    sp.save_npz(os.path.join(out, "viewfactors.npz"), F, compressed=True)
    _write_facets_csv(os.path.join(out, "facets.csv"), fac, rows0, rows, cl)
    files = ["viewfactors.npz", "facets.csv"]
    if fmt == "csv":
        limit = int(vf.csv_max_nonzeros)
        if F.nnz > limit:
            raise RadiosityError(f"--format csv: {F.nnz} nonzeros is more than "
                                 f"radiosity.viewfactors.csv-max-nonzeros ({limit}); use npz")
        _write_matrix_csv(os.path.join(out, "viewfactors.csv"), F)
        files.append("viewfactors.csv")
    fig["files"] = files
    fig["_matrix"] = F
    return fig


def _write_facets_csv(fn: str, fac: Facets, rows0: np.ndarray, rows: np.ndarray, cl) -> None:
    """One line per facet: where it is, its row sum, its view to the environment (1 - row sum:
    the fraction of its power that reaches no facet), its row sum as computed (before any
    balancing or capping; contact facets' rows 0) and what the closure found of its front
    (contact, the fraction of its hemisphere that reaches geometry)."""
    with open(fn, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["facet", "source", "face", "area", "cx", "cy", "cz", "nx", "ny", "nz", "row_sum",
                    "environment", "row_sum_computed", "contact", "closure_target"])
        for i in range(len(fac)):
            w.writerow([i, os.path.basename(fac.sources[fac.source[i]]), int(fac.face[i]),
                        repr(float(fac.area[i])), *(repr(float(x)) for x in fac.center[i]),
                        *(repr(float(x)) for x in fac.normal[i]), repr(float(rows[i])),
                        repr(float(1.0 - rows[i])), repr(float(rows0[i])), int(cl.contact[i, 0]),
                        repr(float(cl.target[i, 0]))])


def _write_matrix_csv(fn: str, F) -> None:
    C = F.tocoo()
    with open(fn, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["i", "j", "F_ij"])
        for i, j, v in zip(C.row.tolist(), C.col.tolist(), C.data.tolist()):
            w.writerow([i, j, repr(v)])
