"""Near-field correction: accurate form factors for pairs of sub-elements that are close.

Design notes and measurements: docs/src/design/methods-pairs-nearfield.md.
"""

from __future__ import annotations

import time

import numpy as np

from radiosity.core.arrays import unique
from radiosity.core.exact import pair_form_factors_exact
from radiosity.core.geometry import COS_TOL  # facing means what it means to the visibility stage
from radiosity.core.kernels import pair_form_factors
from radiosity.methods.pairs.passes import CAP_MIN
from radiosity.runtime.store import RunStore
from radiosity.methods.pairs.store import VisibilityStore


def near_pairs(center: np.ndarray, area: np.ndarray, orig: np.ndarray, factor: float):
    """Pairs (a, b), a < b, of sub-elements of different originals with
    |c_a - c_b| < factor * max(sqrt(A_a), sqrt(A_b)). Returns ia, ib (k,) int64."""
    from scipy.spatial import cKDTree

    size = np.sqrt(area)
    tree = cKDTree(center)
    lists = tree.query_ball_point(center, factor * size)
    ia = np.repeat(np.arange(len(center)), [len(x) for x in lists])
    ib = np.concatenate([np.asarray(x, np.int64) for x in lists]) if len(lists) else np.zeros(0, np.int64)
    a, b = np.minimum(ia, ib), np.maximum(ia, ib)
    keep = (a != b) & (orig[a] != orig[b])
    key = unique(a[keep] * len(center) + b[keep])
    return key // len(center), key % len(center)


def corrections(rs, kernel: str, factor: float) -> dict:
    """The sparse near-field corrections of a run (computed once, kept in the store).

    Returns arrays ia, ib (k,) int64; sa, sb (k,) int8 the facing sides; dab, dba (k,) float64:
    exact - kernel for F_ab and F_ba (0 where the pair's bit is 0); and figures."""
    vs = VisibilityStore(rs)
    token = f"{vs.token()}-{kernel}-{factor}"
    if rs.has("nearfield") and rs.group_attrs("nearfield").get("token") == token:
        arr = rs.read_arrays("nearfield")
        return {**arr, "figures": rs.group_attrs("nearfield")["figures"]}
    t0 = time.perf_counter()
    part = rs.load_partition()
    el = rs.load_elements()
    ia, ib = near_pairs(part.center, part.area, part.orig, factor)
    d = part.center[ib] - part.center[ia]
    length = np.linalg.norm(d, axis=1)
    ca = np.einsum("ij,ij->i", part.normal[ia], d)
    cb = -np.einsum("ij,ij->i", part.normal[ib], d)
    ts = el.two_sided[part.orig]
    t = COS_TOL * length
    face = ((ca > t) | (ts[ia] & (ca < -t))) & ((cb > t) | (ts[ib] & (cb < -t)))
    ia, ib, ca, cb = ia[face], ib[face], ca[face], cb[face]
    vis = vs.pair_bits(part.offsets, ia, ib) if len(ia) else np.zeros(0, bool)
    ia, ib, ca, cb = ia[vis], ib[vis], ca[vis], cb[vis]
    fe = pair_form_factors_exact(part.verts[ia], part.nverts[ia], part.verts[ib], part.nverts[ib])
    fe_ba = fe * part.area[ia] / part.area[ib]
    fk_ab, fk_ba = pair_form_factors(kernel, part.center[ia], part.normal[ia], part.area[ia],
                                     part.center[ib], part.normal[ib], part.area[ib])
    arr = {"ia": ia, "ib": ib, "sa": (ca <= 0).astype(np.int8), "sb": (cb <= 0).astype(np.int8),
           "dab": fe - fk_ab, "dba": fe_ba - fk_ba}
    figures = {"pairs": int(len(ia)), "factor": factor, "time_s": round(time.perf_counter() - t0, 4),
               "max_kernel_over_exact": float((fk_ab / np.maximum(fe, 1e-300)).max(initial=0.0))}
    try:  # keep them for the next solve of this run (the caller may hold a read-only handle)
        RunStore(rs.run_dir, "r+").write_arrays("nearfield", arr, {"token": token, "figures": figures})
    except Exception:
        pass
    return {**arr, "figures": figures}


def apply(near: dict, L: np.ndarray, y: np.ndarray, cap: np.ndarray, cmode: int,
          need_sub=None) -> int:
    """y += (F_exact - F_kernel) L over the near pairs, scaled like the tiles (cap, cmode as in
    passes.py); rows that do not gather (need_sub False) are left alone. Returns the number of
    pair terms."""
    ia, ib, sa, sb = near["ia"], near["ib"], near["sa"], near["sb"]
    if len(ia) == 0:
        return 0
    w = np.minimum(cap[ia], cap[ib]) if cmode == CAP_MIN else cap[ia] * cap[ib]
    ra = (w * near["dab"])[None, :] * L[sb, :, ib].T     # (C, k)
    rb = (w * near["dba"])[None, :] * L[sa, :, ia].T
    ga = np.ones(len(ia), bool) if need_sub is None else need_sub[ia]
    gb = np.ones(len(ia), bool) if need_sub is None else need_sub[ib]
    for c in range(L.shape[1]):
        np.add.at(y[:, c, :], (sa[ga], ia[ga]), ra[c, ga])
        np.add.at(y[:, c, :], (sb[gb], ib[gb]), rb[c, gb])
    return 2 * len(ia)
