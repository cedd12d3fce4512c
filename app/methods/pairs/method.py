"""The pairs method behind the methods' seam (methods/base.py): the visibility stage, the
operator over the bit-packed matrix, and nothing after the solve (the sub-elements are the
unknowns: no final gather, no rounds)."""

from __future__ import annotations

import numpy as np

from radiosity.methods.base import Opened, TransportMethod
from radiosity.scene.emitters import AreaEmitters


def side_vectors(part, elements):
    """Le, rho (2, 3, m) float64 and area (m,) of the sub-elements, per side."""
    Le = AreaEmitters(elements).side_vectors(part.orig)
    rho = np.ascontiguousarray(np.transpose(elements.reflectance[part.orig], (1, 2, 0)))
    return Le, rho, part.area


def per_sub_element(L: np.ndarray) -> np.ndarray:
    """(2, C, m) -> (m, 2, C)."""
    return np.ascontiguousarray(np.transpose(L, (2, 0, 1)))


class PairsMethod(TransportMethod):
    name = "pairs"
    section = "visibility"
    store_groups = ("visibility", "nearfield")
    all_pairs = True
    refinement = None

    def check(self, rs, settings) -> None:
        """Settings that would fail the stage, failed before any cluster starts."""
        from radiosity.settings import sampling_of

        sampling_of(settings.solve)

    def check_scene(self, scene, settings) -> dict | None:
        """The stage's work grows as the facing pairs of originals: a scene whose pairs
        (estimated) exceed plan.max-facing-pairs is refused up front (the hierarchical method
        clusters such scenes, SPEC §9). Returns originals.check_budget's estimate."""
        from radiosity.scene.originals import check_budget, tree_of

        return check_budget(tree_of(scene.elements, int(settings.plan.leaf_size)),
                            int(settings.plan.max_facing_pairs), scene.path)

    def plan_lines(self, settings, sub_elements, originals, why) -> list[str]:
        m = int(sub_elements)
        return [f"visibility: one bit per facing pair of the {m} sub-elements (at most "
                f"{m * (m - 1) / 2:.2g} pairs, {m * (m - 1) / 16 / 2 ** 20:.2g} MiB)"]

    def build(self, run_dir, client, settings, *, resume=False, progress=True, occlusion=True,
              unit=None, on_done=None):
        from radiosity.methods.pairs.visibility import compute_visibility

        return compute_visibility(run_dir, client, settings, unit=unit, resume=resume,
                                  progress=progress, occlusion=occlusion, on_done=on_done)

    def built(self, rs) -> bool:
        from radiosity.methods.pairs.store import VisibilityStore

        return VisibilityStore(rs).token() is not None

    def require(self, rs) -> None:
        from radiosity.methods.pairs.store import VisibilityStore

        VisibilityStore(rs).require()

    def open(self, rs, client, settings, **options) -> Opened:
        from radiosity.methods.pairs.transport import open_operator

        op, part, el = open_operator(rs, client, settings.solve.kernel, settings)
        Le, rho, area = side_vectors(part, el)
        return Opened(op, Le, rho, area, part.orig, len(part), per_sub_element, originals=len(el))

    def gathers(self, settings) -> bool:
        return False

    def finish(self, opened: Opened, L: np.ndarray, rows: dict, settings) -> tuple[dict, dict]:
        from radiosity.settings import sampling_of

        op, inp = opened.op, opened.op.inp
        L3 = np.broadcast_to(L, (2, 3, L.shape[2])) if L.shape[1] == 1 else L
        figures = {
            "near_field": op.sparse["figures"] if op.sparse is not None else None,
            "partial_visibility": ({"pairs": int(inp.pcrc[:, 1].sum()),
                                    "rays_per_pair": sampling_of(settings.solve).rays_per_pair}
                                   if len(inp.pcrc) else None),
            "two_sided_sub_elements": int(inp.sided.sum()),
        }
        return {"radiance": per_sub_element(L3)}, figures

    def kept(self, rs) -> str | None:
        from radiosity.methods.pairs.store import VisibilityStore

        vs = VisibilityStore(rs)
        token = vs.token()
        if token is None:
            return None
        return f"{len(vs.finished(token))} of {len(vs.plan().tasks)} visibility tasks"

    def summary_row(self, report: dict) -> tuple[str, str]:
        vis = report["visibility"]
        return ("rays cast", f"{vis['rays']} ({vis['rays'] / max(1, vis['pairs_total']):.1%} of pairs)")

    def radiance_at(self, rs, settings, pts, porig, side, pixel, footprint):
        """Radiance (K, 3) leaving points on originals `porig`, side `side`: the stored radiance
        of the sub-element holding each point (the pairs method keeps no links to gather
        over), and the figures."""
        return self.open_views(rs, settings).radiance_at(pts, porig, side, pixel, footprint)

    def open_views(self, rs, settings):
        """The run's partition and solution opened once for many views (SubElementLookup)."""
        return SubElementLookup(rs.load_partition(), rs.read_arrays("solution")["radiance"])


class SubElementLookup:
    """A pairs run opened for views: the stored radiance of the sub-element holding a point."""

    def __init__(self, partition, radiance: np.ndarray):
        self.partition, self.radiance = partition, radiance

    def radiance_at(self, pts, porig, side, pixel, footprint):
        """Radiance (K, 3) leaving points `pts` (K, 3) on originals `porig`, side `side`, and
        the figures (pixel and footprint are not needed: there are no links to gather over)."""
        from radiosity.scene.subdivide import lookup

        sub = lookup(self.partition, pts, np.asarray(porig, np.int32))
        out = np.zeros((len(pts), 3))
        ok = sub >= 0
        out[ok] = self.radiance[sub[ok], np.asarray(side)[ok]]
        return out, {"points": int(len(pts)), "evaluations": 0, "lookup": "sub-element"}


PAIRS = PairsMethod()
