"""The seam between the pipeline and the transport methods: what a method is (`TransportMethod`),
what the solvers apply (`Operator`), what every Dask operator shares (`GroupExecutor`: pinned
groups, data lost with a worker sent again), the `METHODS` registry and the per-scene choice.
The pipeline, the stages and the CLI pick a method by name here and never compare names.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from radiosity.errors import RadiosityError
from radiosity.runtime.cluster import Scattered
from radiosity.runtime.runner import gather_retrying

# How a pair's form factor is scaled by the row normalisation (stages/solve.normalise_rows):
# CAP_MIN by min(cap_a, cap_b) (rows capped at 1; 1 = none), CAP_PRODUCT by cap_a * cap_b
# (symmetric balancing of a closed scene). Numba passes of every method read these.
CAP_MIN, CAP_PRODUCT = 0, 1


class Operator(Protocol):
    """What the solvers need: K applied to (2, C, M) vectors [side, channel, unknown]."""

    kernel: str
    passes: int
    terms: int

    def apply(self, L: np.ndarray, live: np.ndarray | None = None,
              use_need: bool = True) -> np.ndarray:
        """K L; `live` (M,) bool marks the unknowns whose L may be non-zero; with use_need, the
        rows of originals that do not gather stay 0."""

    def row_sums(self) -> np.ndarray:
        """sum_b K_ab for every unknown and side, (2, M) (one pass)."""

    def gs_sweep(self, L: np.ndarray, Le: np.ndarray, rho: np.ndarray) -> np.ndarray:
        """One block Gauss-Seidel sweep from L; returns the new L."""

    def configure(self, **arrays) -> None:
        """Replace input arrays (cap and cmode, sided, need, ...)."""


class GroupExecutor:
    """Task groups on a Dask cluster, each pinned to one worker (its cache stays warm across
    passes), resubmitted anywhere when it fails; a pass whose scattered data died with a worker
    scatters its inputs again and reruns. Operators of every method run their passes here."""

    def __init__(self, client, inputs, ngroups: int, retries: int):
        self.client = client
        self.inputs = inputs
        self.ngroups = ngroups
        self.retries = retries
        self._pin()
        self.shared = Scattered(client, inputs)

    def _pin(self) -> None:
        alive = sorted(self.client.scheduler_info()["workers"])
        self.workers = [alive[g % len(alive)] if alive else None for g in range(self.ngroups)]

    def replace_inputs(self, inputs) -> None:
        """New inputs for every later pass (one scatter)."""
        self.inputs = inputs
        self.shared = Scattered(self.client, inputs)

    def run(self, fn, args_of: Callable, vectors: tuple, name: str, count: int | None = None) -> list:
        """[fn(inputs, *args_of(i, *vector_futures)) for each group i], in group order.
        `vectors` are scattered once per pass (sent again when their only copy dies)."""
        from concurrent.futures import CancelledError

        count = self.ngroups if count is None else count
        for attempt in range(self.retries + 1):
            try:
                vf = self.client.scatter(list(vectors), broadcast=False, hash=False)

                def submit(i, again):
                    if again and any(f.status != "finished" for f in vf):
                        vf[:] = self.client.scatter(list(vectors), broadcast=False, hash=False)
                    w = self.workers[i % len(self.workers)] if self.workers else None
                    return self.client.submit(fn, self.shared.future(), *args_of(i, *vf), pure=False,
                                              workers=[w] if w else None,
                                              allow_other_workers=bool(w))

                return gather_retrying(self.client, submit, count, self.retries, name=name)
            except (CancelledError, OSError) as e:  # FutureCancelledError, CommClosedError
                if attempt == self.retries:
                    raise RadiosityError(f"a solver pass failed {attempt + 1} times: workers were "
                                         f"lost ({type(e).__name__}: {e})") from None
                self._pin()


@dataclass
class Opened:
    """A solved run's unknowns as a method opened them: the operator, Le and rho (2, 3, M) and
    area (M,) per unknown and side, the original element of each unknown (M,), and the number
    of sub-elements the solution is written for."""

    op: Operator
    Le: np.ndarray
    rho: np.ndarray
    area: np.ndarray
    orig: np.ndarray
    sub_elements: int
    to_sub: Callable[[np.ndarray], np.ndarray]  # (2, C, M) -> (m, 2, C) per sub-element
    # the method's own (node table, ...; "live" (M,) the part of each unknown outside solids:
    # the solve leaves those at 0 out of the transport and weighs the others' light by it), and
    # the solve's rows of F before any scaling
    # ("row_sums" (2, M): stages/solve.py puts them there for the method's finish)
    state: dict = field(default_factory=dict)


class TransportMethod(Protocol):
    """One transport method: its stage after preprocessing (visibility bits, links), its
    operator, and what it adds after the solve (a final gather, or nothing)."""

    name: str
    section: str  # the report.json section its build stage writes

    def build(self, run_dir: str, client, settings, *, resume: bool, progress: bool,
              occlusion: bool, unit: str | None = None, on_done=None): ...

    def built(self, rs) -> bool: ...

    def open(self, rs, client, settings, **options) -> Opened: ...

    def finish(self, opened: Opened, L: np.ndarray, rows: dict, settings) -> tuple[dict, dict]:
        """(arrays for solution/, extra SolveFigures fields) from the solved L (2, C, M)."""

    def radiance_at(self, rs, settings, pts: np.ndarray, porig: np.ndarray, side: np.ndarray,
                    pixel: np.ndarray, footprint: np.ndarray) -> tuple[np.ndarray, dict]:
        """Radiance (K, 3) leaving points `pts` on originals `porig` (-1: none) on side `side`
        (0 front, 1 back), seen through pixel `pixel` whose footprint there is `footprint`
        (m^2), from the stored solution: for views the run was not refined for."""

    def open_views(self, rs, settings):
        """The run opened once for many views (a walkthrough's frames): an object whose
        radiance_at(pts, porig, side, pixel, footprint) answers as radiance_at does."""

    def kept(self, rs) -> str | None:
        """What a rerun reuses of this method's stage ("14 of 18 link tasks"), or None."""

    def summary_row(self, report: dict) -> tuple[str, str]: ...


METHODS = {"pairs": "radiosity.methods.pairs.method:PAIRS",
           "hierarchical": "radiosity.methods.hierarchical.method:HIERARCHICAL"}


def get_method(name: str) -> TransportMethod:
    """The method registered as `name` (imported on first use)."""
    if name not in METHODS:
        raise RadiosityError(f"--method must be one of auto, {', '.join(METHODS)}, got {name!r}")
    module, attr = METHODS[name].split(":")
    return getattr(importlib.import_module(module), attr)


def method_of_run(rs) -> TransportMethod:
    """The method whose stage a run store holds; StoreError-like RadiosityError if none."""
    for name in METHODS:
        m = get_method(name)
        if m.built(rs):
            return m
    raise RadiosityError(f"{rs.run_dir} has no visibility matrix or links yet: run radiosity "
                         f"visibility {rs.run_dir}")


def choose_method(sub_elements: int, settings, originals: int = 1,
                  facing_pairs: float | None = None) -> tuple[str, str]:
    """(method, why) for a run of `sub_elements`: settings.visibility.method unless auto; auto
    takes hierarchical above visibility.hierarchical-above sub-elements (links grow at most like
    m, pairs like m^2; docs/src/measurements/hierarchical.md), the seed's pairs below, where both cost the same
    and pairs is the exact all-pairs limit. A sampled kernel (nxm, mc) is the pairs method's
    (links sample their own rays), and so are scenes of many originals with few sub-elements
    each (visibility.hierarchical-min-per-original), unless their facing pairs (`facing_pairs`,
    counted or estimated) exceed plan.max-facing-pairs, which the pairs method refuses."""
    vis = settings.visibility
    method = vis.method
    if method != "auto":
        get_method(method)
        return method, f"{method}: stated (method: {method})"
    budget = float(settings.plan.max_facing_pairs)
    if facing_pairs is not None and facing_pairs > budget:
        return "hierarchical", (f"hierarchical: auto, about {facing_pairs:.3g} facing pairs of "
                                f"originals > plan.max-facing-pairs {budget:g} (clustered)")
    kernel = settings.solve.kernel
    if kernel not in ("point", "disc", "point-nf", "disc-nf"):
        return "pairs", f"pairs: auto, the {kernel} kernel samples the pairs' own rays"
    clustered, _ = settings.hierarchy.clustered(originals)
    if clustered:
        return "hierarchical", (f"hierarchical: auto, {originals} originals, clustered "
                                f"(hierarchy.clusters-above {settings.hierarchy.clusters_above})")
    per = float(vis.hierarchical_min_per_original)
    if sub_elements < per * originals:
        return "pairs", (f"pairs: auto, {sub_elements} sub-elements on {originals} originals "
                         f"(under {per:g} each: no trees for links to coarsen)")
    above = int(vis.hierarchical_above)
    if sub_elements > above:
        return "hierarchical", (f"hierarchical: auto, {sub_elements} sub-elements > {above} "
                                "(links grow at most like m, pairs like m^2)")
    return "pairs", f"pairs: auto, {sub_elements} sub-elements <= {above} (all pairs cost no more)"
