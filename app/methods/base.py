"""The seam between the pipeline and the transport methods: what a method is and can do
(`TransportMethod`, an abstract base that tests/methods/test_protocol.py checks every method
against; `Refinement`, its rounds), what the solvers apply (`Operator`), what the solve gets
(`Opened`), the `METHODS` registry and the per-scene choice. Code outside methods/ picks a
method here (by a setting's value, by the run it holds, or by a capability such as
`all_pairs`) and never compares names nor imports a method's modules (tests/test_layers.py).
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from radiosity.errors import RadiosityError
from radiosity.runtime.store import register_method_groups

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


@dataclass
class Opened:
    """A solved run's unknowns as a method opened them: the operator, Le and rho (2, 3, M) and
    area (M,) per unknown and side, the original element of each unknown (M,), and the number
    of sub-elements the solution is written for. What the solve reads besides: `originals`, the
    scene's original elements (the gathering count when all gather); `live` (M,) float, the
    part of each unknown outside solids, or None (the solve leaves those at 0 out of the
    transport and weighs the others' light by it). The solve sets `row_sums` (2, M), the rows
    of F before any scaling, for the method's finish (hierarchical: views/rounds.py), and
    `row_targets`, the closure's core.balancing.RowTargets (or None)."""

    op: Operator
    Le: np.ndarray
    rho: np.ndarray
    area: np.ndarray
    orig: np.ndarray
    sub_elements: int
    to_sub: Callable[[np.ndarray], np.ndarray]  # (2, C, M) -> (m, 2, C) per sub-element
    originals: int = 0
    live: np.ndarray | None = None
    row_sums: np.ndarray | None = None
    row_targets: object | None = None
    state: dict = field(default_factory=dict)  # the method's own (its node table, ...)


class Refinement(ABC):
    """A method's rounds of refinement by the solved radiance, after a first solve
    (stages/rounds.py runs them: solve, refine, solve from the last answer, ...)."""

    @abstractmethod
    def count(self, settings) -> int | None:
        """The rounds the settings ask for (0: none), None where decide() says after the first
        solve; bad values are a RadiosityError."""

    @abstractmethod
    def decide(self, rs, settings, radiance: np.ndarray) -> tuple[int, str]:
        """(rounds, why) from the first solve's radiance (m, 2, C) per sub-element."""

    @abstractmethod
    def previous(self, rs) -> dict:
        """The run's last solution, read once for a round and the warm start after it."""

    @abstractmethod
    def warm_start(self, prev: dict) -> Callable:
        """x0 for run_solve from `prev` (previous()): a function Opened -> (2, C, M)."""

    @abstractmethod
    def start(self, run_dir: str, settings, unit, occlusion: bool):
        """The rounds of one run: an object with refine(client, prev, progress) -> the round's
        figures ({"tasks": 0}: nothing refined), and `figures`, `factor`, `change` for the
        report's "rounds" section."""


class TransportMethod(ABC):
    """One transport method: its stage after preprocessing (visibility bits, links), its
    operator, and what it adds after the solve (a final gather, rounds, or nothing). Every
    caller outside methods/ goes through these members; tests/methods/test_protocol.py checks
    each METHODS entry against them."""

    name: str            # its METHODS key
    section: str         # the report.json section its build stage writes
    store_groups: tuple  # its groups of the run store, written by its stage (runtime/store.py)
    all_pairs: bool      # every pair of unknowns as it is: the preview's and the kernels' method
    refinement: Refinement | None = None  # rounds by the solved radiance, or None

    @abstractmethod
    def check(self, rs, settings) -> None:
        """Settings that would fail the stage on this run, failed before any cluster starts."""

    @abstractmethod
    def check_scene(self, scene, settings) -> dict | None:
        """A scene the stage would refuse, refused before any cluster starts (a RadiosityError
        naming the scene and the option); returns the estimates it made, or None."""

    def direct(self, elements, settings) -> tuple[str, str]:
        """(mode, why): where this method takes the emitters' light (radiosity.direct.mode,
        SPEC §10): "links" (as all other light, the seed's way) unless it overrides this; a
        scene with luminaires (point sources, which links cannot carry) is refused."""
        from radiosity.scene.emitters import point_emitters

        lums = point_emitters(elements)
        if lums.any():
            raise RadiosityError(f"the {self.name} method cannot carry the scene's "
                                 f"{lums.describe()} (point sources): use --method hierarchical "
                                 "(or auto)")
        return "links", f"links: the {self.name} method carries all light through its pairs"

    @abstractmethod
    def plan_lines(self, settings, sub_elements: int, originals: int, why: str) -> list[str]:
        """What `radiosity plan` says of this method's stage for a scene of this size (after
        the line "method: WHY")."""

    @abstractmethod
    def build(self, run_dir: str, client, settings, *, resume: bool = False,
              progress: bool = True, occlusion: bool = True, unit: str | None = None,
              on_done=None):
        """Run the method's stage on a preprocessed run; returns its figures."""

    @abstractmethod
    def built(self, rs) -> bool:
        """Whether the run store holds this method's stage."""

    @abstractmethod
    def require(self, rs) -> None:
        """A StoreError saying what to run where the run's stage is missing or incomplete."""

    @abstractmethod
    def open(self, rs, client, settings, **options) -> Opened:
        """The run's unknowns and operator for the solve (options: where, the hierarchical
        method's driver or cluster choice)."""

    @abstractmethod
    def gathers(self, settings) -> bool:
        """Whether finish() runs a final gather under these settings (a stage of its own)."""

    @abstractmethod
    def finish(self, opened: Opened, L: np.ndarray, rows: dict, settings) -> tuple[dict, dict]:
        """(arrays for solution/, extra SolveFigures fields) from the solved L (2, C, M)."""

    @abstractmethod
    def radiance_at(self, rs, settings, pts: np.ndarray, porig: np.ndarray, side: np.ndarray,
                    pixel: np.ndarray, footprint: np.ndarray) -> tuple[np.ndarray, dict]:
        """Radiance (K, 3) leaving points `pts` on originals `porig` (-1: none) on side `side`
        (0 front, 1 back), seen through pixel `pixel` whose footprint there is `footprint`
        (m^2), from the stored solution: for views the run was not refined for."""

    @abstractmethod
    def open_views(self, rs, settings):
        """The run opened once for many views (a walkthrough's frames): an object whose
        radiance_at(pts, porig, side, pixel, footprint) answers as radiance_at does."""

    @abstractmethod
    def kept(self, rs) -> str | None:
        """What a rerun reuses of this method's stage ("14 of 18 link tasks"), or None."""

    @abstractmethod
    def summary_row(self, report: dict) -> tuple[str, str]:
        """The render summary's row of this method's stage, from report.json."""


#: name -> "module:attribute" of its TransportMethod; a new method is one folder and one line
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


def stated_method(settings) -> TransportMethod | None:
    """The method visibility.method states, None for auto (chosen later, by the scene)."""
    method = settings.visibility.method
    return None if method == "auto" else get_method(method)


def all_pairs_method() -> TransportMethod:
    """The registered method that takes every pair of unknowns as it is (no refinement): the
    preview on the original elements, and the accuracy study's kernels, solve with it."""
    return next(m for m in map(get_method, METHODS) if m.all_pairs)


def store_groups() -> tuple[str, ...]:
    """Every registered method's groups of the run store, in registry order."""
    return tuple(g for name in METHODS for g in get_method(name).store_groups)


register_method_groups(store_groups)  # the run store's drop_after deletes them after a raster


def choose_method(sub_elements: int, settings, originals: int = 1,
                  facing_pairs: float | None = None, point_sources: int = 0) -> tuple[str, str]:
    """(method, why) for a run of `sub_elements`: settings.visibility.method unless auto; auto
    takes hierarchical above visibility.hierarchical-above sub-elements (links grow at most like
    m, pairs like m^2; docs/src/measurements/hierarchical.md), the seed's pairs below, where both cost the same
    and pairs is the exact all-pairs limit. A sampled kernel (nxm, mc) is the pairs method's
    (links sample their own rays), and so are scenes of many originals with few sub-elements
    each (visibility.hierarchical-min-per-original), unless their facing pairs (`facing_pairs`,
    counted or estimated) exceed plan.max-facing-pairs, which the pairs method refuses.
    `point_sources` (the scene's luminaires): hierarchical, whose direct light at points
    carries them (the pairs method cannot)."""
    vis = settings.visibility
    method = vis.method
    if method != "auto":
        get_method(method)
        return method, f"{method}: stated (method: {method})"
    if point_sources:
        return "hierarchical", (f"hierarchical: auto, {point_sources} luminaire(s): point "
                                "sources are lit at points (direct.mode points)")
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
