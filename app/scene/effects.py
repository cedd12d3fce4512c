"""Simulate only the effects a scene calls for: decide, before any ray is cast, what to skip.

Design notes and measurements: docs/src/design/scene-effects.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from radiosity.scene.originals import (LEAF, TOL, FacingPairsError, behind_any,
                                       pairs_within_budget, tree_of)
from radiosity.core.bundles import Elements
from radiosity.scene.emitters import AreaEmitters
from radiosity.scene.luminaires import luminaires_of


@dataclass(frozen=True)
class EffectsPlan:
    """What the run will simulate. Arrays are per original element (n,).

    occlusion, interreflection, colour : bool — the effect is simulated
    two_sided : (n,) bool — elements solved with two sides
    gather : (n,) bool — elements that take part in the iteration (gather light)
    passes_bound : int — Jacobi passes to the tolerance, known up front (0: no solve)
    reasons : dict effect -> one line saying why it is on or off
    estimates : dict of figures (pairs, rays, pair terms and channels saved)
    """

    occlusion: bool
    interreflection: bool
    colour: bool
    two_sided: np.ndarray
    gather: np.ndarray
    passes_bound: int
    reasons: dict = field(default_factory=dict)
    estimates: dict = field(default_factory=dict)
    full: bool = False

    def to_dict(self) -> dict:
        return {"full": self.full, "occlusion": self.occlusion,
                "interreflection": self.interreflection, "colour": self.colour,
                "two_sided_elements": int(self.two_sided.sum()),
                "gathering_elements": int(self.gather.sum()), "elements": int(len(self.gather)),
                "passes_bound": self.passes_bound, "reasons": dict(self.reasons),
                "estimates": dict(self.estimates)}

    @property
    def channels(self) -> int:
        return 3 if self.colour else 1


def _behind(elements: Elements) -> np.ndarray:
    """(n, n) bool: does any vertex of J lie strictly behind the plane of I? Dense: for tests
    of originals.behind_any (which plan_effects uses), small scenes only."""
    v = elements.verts
    d = np.einsum("ic,jkc->ijk", elements.normal, v) - \
        np.einsum("ic,ic->i", elements.normal, elements.center)[:, None, None]
    scale = float(np.linalg.norm(v.reshape(-1, 3).max(0) - v.reshape(-1, 3).min(0)))
    return (d < -TOL * scale).any(axis=2)


def _reachable(bi: np.ndarray, bj: np.ndarray, emitter: np.ndarray,
               reflects: np.ndarray) -> np.ndarray:
    """Elements light can reach: BFS from the emitters over the pairs (bi, bj) that face each
    other (a sparse graph, O(pairs)); light travels on from an element only if it reflects."""
    from scipy.sparse import csr_matrix

    n = len(emitter)
    adj = csr_matrix((np.ones(2 * len(bi), np.float32),
                      (np.concatenate([bi, bj]), np.concatenate([bj, bi]))), shape=(n, n))
    seen = emitter.copy()
    frontier = emitter.copy()
    while frontier.any():
        nxt = (adj @ frontier.astype(np.float32) > 0) & ~seen
        seen |= nxt
        frontier = nxt & reflects
    return seen


def plan_effects(elements: Elements, tol: float = 1e-6, full: bool = False,
                 sizes: np.ndarray | None = None, max_pairs: int | None = None,
                 leaf: int = LEAF, where: str = "the scene") -> EffectsPlan:
    """The effects plan of a scene. `sizes` (n,): expected sub-elements per original, for the
    estimates (1 each if not given). `full` forces every effect on (the reference run).

    Nothing n x n: the pairs that face each other and whatever lies behind each element come
    from the hierarchy over the originals (originals.py), at most `max_pairs` pairs; beyond
    that (a mesh of many small triangles, which the hierarchical method clusters) the pairs are
    not listed: their number is estimated and every element gathers (no dead-row search)."""
    n = len(elements)
    rho = elements.reflectance          # (n, 2, 3)
    emitters = AreaEmitters(elements)
    ts = elements.two_sided
    s = np.ones(n) if sizes is None else np.asarray(sizes, float)
    tree = tree_of(elements, leaf)
    try:
        bi, bj, _ = pairs_within_budget(tree, max_pairs, where)
    except FacingPairsError as e:
        bi = bj = None
        over = e.estimate
    # the rows of the (n, n) "behind" relation, or-ed: is any element behind another (nothing
    # can block otherwise), and which two-sided elements are seen from their back
    blocker_possible = bool(behind_any(tree, first=True).any())
    back_any = behind_any(tree, wanted=ts)
    reasons = {}
    est = {}
    if bi is None:  # too many to list: estimated (sizes taken as their mean)
        n_pairs = over
        pairs = n_pairs * float(s.mean()) ** 2 if n else 0.0
        est["facing_original_pairs_estimate"] = n_pairs
    else:
        pairs = float((s[bi] * s[bj]).sum())
        est["facing_original_pairs"] = int(len(bi))
    est["facing_block_pairs"] = pairs

    # occlusion: if every element is in front of (or on) every other's plane, the elements
    # bound a convex region and a segment between two of them stays inside it: nothing blocks
    occlusion = full or blocker_possible
    if not blocker_possible:
        reasons["occlusion"] = ("off: every element lies in front of every other (a convex "
                                "enclosure): no segment between two elements can be blocked")
        est["rays_saved_at_most"] = pairs
    else:
        reasons["occlusion"] = "on: some elements lie behind others; blocks are classified by shafts"

    reflect = rho.max(axis=(1, 2)) > 0
    interreflection = full or bool(reflect.any())
    rho_max = float(rho.max(initial=0.0))
    if not reflect.any():
        reasons["interreflection"] = "off: reflectance is 0 everywhere, only direct emission (L = Le)"
        passes = 0
        est["pair_terms_saved_per_pass"] = 2 * pairs
    else:
        passes = int(math.ceil(math.log(tol) / math.log(rho_max))) if rho_max > 0 else 1
        reasons["interreflection"] = (f"on: largest reflectance {rho_max:.3g}; Jacobi needs at most "
                                      f"{passes} passes to reach {tol:g} (CG far fewer)")

    lums = luminaires_of(elements)   # [[luminaire]] point sources
    grey = bool(np.all(rho == rho[..., :1]) and emitters.grey()
                and all(np.all(lum.colour == lum.colour[0]) for lum in lums.items))
    colour = full or not grey
    reasons["colour"] = ("off: every material is grey: one channel is solved and broadcast"
                         if not colour else "on: some material has colour" if not grey else
                         "on (--full)")
    if not colour:
        est["channels"] = 1

    # two-sided elements whose back sees nothing are one-sided in effect
    back_used = back_any
    eff_two = ts & (back_used | full)
    dropped = int((ts & ~eff_two).sum())
    reasons["two_sided"] = (f"{int(eff_two.sum())} of {int(ts.sum())} two-sided elements are reached "
                            f"from both sides" + (f"; {dropped} solved as one-sided" if dropped else ""))

    emitter = emitters.emitting()
    # luminaires light elements directly (not through pairs): every element may be reached
    reach = _reachable(bi, bj, emitter, reflect) if bi is not None and not lums \
        else np.ones(n, bool)
    gather = np.ones(n, bool) if full else (reflect & reach)
    # three disjoint kinds that add up to the rows dropped: ~(reflect & reach)
    dead_emit = int((emitter & ~reflect).sum())
    dead_black = int((~emitter & ~reflect).sum())
    dead_dark = int((reflect & ~reach).sum())
    reasons["dead_rows"] = (f"{int((~gather).sum())} of {n} elements drop out of the iteration "
                            f"({dead_emit} emitters that reflect nothing, {dead_black} other "
                            f"elements that reflect nothing, {dead_dark} that no light can reach)"
                            + ("" if bi is not None else "; pairs too many to list: reach not "
                               "searched") if not full else "off (--full)")
    dead = ~gather
    if bi is not None:
        est["pair_terms_saved_per_pass"] = est.get("pair_terms_saved_per_pass", 0.0) + float(
            ((s[bi] * s[bj]) * (dead[bi].astype(float) + dead[bj])).sum())
    else:
        est.setdefault("pair_terms_saved_per_pass", 0.0)
    return EffectsPlan(occlusion=occlusion, interreflection=interreflection, colour=colour,
                       two_sided=eff_two, gather=gather, passes_bound=passes, reasons=reasons,
                       estimates=est, full=full)


def describe(plan: EffectsPlan, unseen: int | None = None, sub_elements: int | None = None,
             closure=None) -> str:
    """The plan as the `radiosity plan` command prints it (closure: a closure.Closure)."""
    lines = ["effect             on/off  why"]
    rows = [("occlusion", plan.occlusion), ("interreflection", plan.interreflection),
            ("colour", plan.colour)]
    for name, on in rows:
        lines.append(f"{name:<18} {'on' if on else 'OFF':<7} {plan.reasons[name].split(': ', 1)[-1]}")
    lines.append(f"{'two-sided':<18} {'':<7} {plan.reasons['two_sided']}")
    lines.append(f"{'dead rows':<18} {'':<7} {plan.reasons['dead_rows']}")
    if closure is not None:
        lines.append(f"{'closure':<18} {'on' if closure.closed else 'OFF':<7} "
                     f"{closure.reason.split(': ', 1)[-1]}")
    if unseen is not None:
        lines.append(f"{'subdivision':<18} {'':<7} only where the camera sees: {unseen} elements "
                     "stay unsplit" + (f", about {sub_elements} sub-elements" if sub_elements else ""))
    e = plan.estimates
    lines.append("")
    if "facing_original_pairs" in e:
        from radiosity.scene.originals import BYTES_PER_PAIR

        lines.append(f"pairs of facing original elements: {e['facing_original_pairs']} (visibility "
                     f"plan about {e['facing_original_pairs'] * BYTES_PER_PAIR / 2 ** 20:.3g} MiB)")
    lines.append(f"estimated pairs of facing sub-elements: {e['facing_block_pairs']:.3g}")
    if "rays_saved_at_most" in e:
        lines.append(f"rays saved: up to {e['rays_saved_at_most']:.3g} (no visibility test at all)")
    lines.append(f"pair terms saved per pass: {e['pair_terms_saved_per_pass']:.3g}"
                 + (f"; channels solved: {plan.channels} of 3" if not plan.colour else ""))
    if plan.interreflection:
        lines.append(f"passes to tolerance (Jacobi bound): {plan.passes_bound}")
    return "\n".join(lines)
