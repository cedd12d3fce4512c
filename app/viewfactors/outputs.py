"""The view-factor stage's outputs: the enclosure test and balancing of the assembled matrix,
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


def covered_fraction(fac: Facets, epsilon: float, points: int = 64) -> np.ndarray:
    """(n,) the fraction of each facet's front covered by a touching surface (scene/contact.py,
    `points` stratified sample points per facet)."""
    from types import SimpleNamespace

    from radiosity.core.kernels import Sampling, sample_points
    from radiosity.scene.contact import contact_points

    el = SimpleNamespace(verts=fac.verts, nverts=fac.nverts, normal=fac.normal,
                         two_sided=np.zeros(len(fac), bool))
    pts, _ = sample_points(fac.verts, fac.nverts, Sampling("nxm", points))
    return contact_points(el, pts, epsilon)[:, :, 0].mean(axis=1)


def finish(rs, out: str, fac: Facets, asm, vf: ViewFactorSettings, fmt: str,
           epsilon: float = 1e-6) -> dict:
    """Enclosure test (vf.enclosure: auto | on | off) and balancing of the assembled matrix
    `asm` (master.Assembled), checks and warnings against vf.accuracy, outputs (fmt: npz |
    csv). Returns the figures (with the final matrix under "_matrix")."""
    import scipy.sparse as sp

    from radiosity.scene.contact import COVERED
    from radiosity.viewfactors.enclosure import balance, mesh_closure
    from radiosity.viewfactors.store import write_vf_matrix
    from radiosity.viewfactors.loops import reciprocity_residual

    mode, accuracy = vf.enclosure, float(vf.accuracy)
    F = asm.matrix
    n = F.shape[0]
    A = fac.area
    # facets covered by a touching surface take no part, as in the radiosity path; facets
    # partly covered see less than their hemisphere: not balanced to 1, only capped
    cover = covered_fraction(fac, epsilon)
    contact = cover >= COVERED
    if contact.any():
        keep = sp.diags(np.where(contact, 0.0, 1.0))
        F = sp.csr_matrix(keep @ F @ keep)
        F.eliminate_zeros()
    rows0 = np.asarray(F.sum(axis=1)).ravel()
    cl = mesh_closure(fac.verts, fac.nverts)
    do_balance = mode == "on" or (mode == "auto" and cl.enclosure)
    fig: dict = {"enclosure_mode": mode, "closed": cl.closed, "normals_inward": cl.inward,
                 "enclosure": cl.enclosure, "not_enclosure_because": cl.reason,
                 "balanced": do_balance, "nonzeros": int(F.nnz),
                 "contact_facets": int(contact.sum()),
                 "partly_covered_facets": int(((cover > 0) & ~contact).sum()),
                 "row_sum_min": float(rows0.min()), "row_sum_max": float(rows0.max()),
                 "row_sum_histogram": row_histogram(rows0),
                 "obstructed_over_unobstructed": asm.violations,
                 "cheap_kernel_row_bound_max": float(asm.cheap_bound.max(initial=0.0)),
                 "dropped_row_bound_max": float(asm.dropped_bound.max(initial=0.0))}
    if mode == "on" and not cl.enclosure:
        warnings.warn(f"--enclosure on: the facets do not form an enclosure ({cl.reason}); "
                      "their rows are balanced to 1 all the same")
    scale = np.ones(n)
    if do_balance:
        dev = np.where(cover == 0, np.abs(rows0 - 1.0), 0.0)
        bad = np.argsort(-dev)
        if dev[bad[0]] > 10 * accuracy:
            warnings.warn(f"enclosure rows sum to 1 +- {dev[bad[0]]:.3g} before balancing "
                          f"(more than 10 x the accuracy {accuracy:g}); worst rows: "
                          f"{_worst(fac, rows0, bad)}")
        F, bal = balance(F, tol=float(vf.balance_tol),
                         max_iterations=int(vf.balance_max_iterations), exact=cover == 0)
        scale = bal.scale
        fig.update({"balance_iterations": bal.iterations, "balance_converged": bal.converged,
                    "balance_scale_min": float(scale.min()), "balance_scale_max": float(scale.max())})
        if not bal.converged:
            warnings.warn(f"balancing stopped after {bal.iterations} iterations with rows "
                          f"1 +- {bal.residual_after:.3g}")
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
    _write_facets_csv(os.path.join(out, "facets.csv"), fac, rows)
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


def _write_facets_csv(fn: str, fac: Facets, rows: np.ndarray) -> None:
    with open(fn, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["facet", "source", "face", "area", "cx", "cy", "cz", "nx", "ny", "nz", "row_sum"])
        for i in range(len(fac)):
            w.writerow([i, os.path.basename(fac.sources[fac.source[i]]), int(fac.face[i]),
                        repr(float(fac.area[i])), *(repr(float(x)) for x in fac.center[i]),
                        *(repr(float(x)) for x in fac.normal[i]), repr(float(rows[i]))])


def _write_matrix_csv(fn: str, F) -> None:
    C = F.tocoo()
    with open(fn, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["i", "j", "F_ij"])
        for i, j, v in zip(C.row.tolist(), C.col.tolist(), C.data.tolist()):
            w.writerow([i, j, repr(v)])
