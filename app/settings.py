"""Settings: every tunable of radiosity.yaml as frozen objects, resolved once where the user gives
them (the CLI, the Python API) and passed down; code below that boundary reads attributes of
these objects, never dask.config.

`resolve({"solve.tol": 1e-4})` reads each radiosity.* section of dask.config once, applies the
overrides (a flag's value; None means "not given") and checks their names and types. The YAML
(radiosity.yaml) documents every key and why its default was chosen.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

from radiosity import config
from radiosity.errors import RadiosityError


@dataclass(frozen=True)
class _Section:
    """One radiosity.<SECTION>.* table; field names are the YAML keys with '_' for '-'."""

    SECTION: ClassVar[str] = ""
    #: field -> YAML key where the two differ (a user-facing key kept for users' configurations
    #: while the code says what the value is)
    KEYS: ClassVar[dict] = {}

    @classmethod
    def key_of(cls, field: str) -> str:
        """The YAML key of `field`."""
        return cls.KEYS.get(field, field.replace("_", "-"))

    @classmethod
    def field_of(cls, key: str) -> str:
        """The field of YAML key `key` (or of the field's own name)."""
        name = key.replace("-", "_")
        return next((f for f, k in cls.KEYS.items() if k == key or k == name), name)

    @classmethod
    def from_dict(cls, values: dict) -> "_Section":
        kw = {}
        for f in dataclasses.fields(cls):
            key = cls.key_of(f.name)
            # environment variables (DASK_RADIOSITY__PLAN__LEAF_SIZE) arrive as leaf_size
            name = key if key in values else f.name
            if name not in values:
                raise RadiosityError(f"radiosity.{cls.SECTION}.{key} is not set (radiosity.yaml "
                                     "holds every key: reinstall the package?)")
            kw[f.name] = _coerce(values[name], f.type, f"radiosity.{cls.SECTION}.{key}")
        return cls(**kw)

    def to_dict(self) -> dict:
        return {self.key_of(f.name): getattr(self, f.name) for f in dataclasses.fields(self)}


def _coerce(value, kind: str, where: str):
    """int and float keys as numbers (environment variables and YAML give '1e7' or 3 for
    either); null (None) stays None, "not set" (the YAML says what each key's null means); the
    other kinds as given."""
    if value is None:
        return None
    try:
        if kind == "int" and not isinstance(value, bool):
            return int(float(value))
        if kind == "float" and not isinstance(value, bool):
            return float(value)
    except (TypeError, ValueError):
        raise RadiosityError(f"{where} must be a number, got {value!r}") from None
    return value


@dataclass(frozen=True)
class SceneSettings(_Section):
    """radiosity.scene.*"""

    SECTION: ClassVar[str] = "scene"
    planarity_tolerance: float
    merge_tolerance: float
    min_relative_area: float


@dataclass(frozen=True)
class RaySettings(_Section):
    """radiosity.rays.*: `offset`, how far a ray starts off the surface it leaves (YAML key
    `epsilon`, kept for users' configurations; epsilon in code is the links' threshold)."""

    SECTION: ClassVar[str] = "rays"
    KEYS: ClassVar[dict] = {"offset": "epsilon"}
    offset: float


@dataclass(frozen=True)
class SubdivideSettings(_Section):
    """radiosity.subdivide.*"""

    SECTION: ClassVar[str] = "subdivide"
    subpixel: int
    max_depth: int
    variant: str
    unseen: str
    unseen_factor: float
    unseen_budget: float
    hidden: str
    hidden_factor: float
    hidden_rays: int
    subscenes: int
    rays_per_task: int


@dataclass(frozen=True)
class PlanSettings(_Section):
    """radiosity.plan.*"""

    SECTION: ClassVar[str] = "plan"
    max_facing_pairs: float
    leaf_size: int


@dataclass(frozen=True)
class VisibilitySettings(_Section):
    """radiosity.visibility.*"""

    SECTION: ClassVar[str] = "visibility"
    task_unit: str
    stripe_threshold: int
    window_per_worker: int
    max_task_bits: int
    min_task_bits: int
    retries: int
    method: str
    hierarchical_above: int
    hierarchical_min_per_original: int


@dataclass(frozen=True)
class SolveSettings(_Section):
    """radiosity.solve.*"""

    SECTION: ClassVar[str] = "solve"
    solver: str
    kernel: str
    nxm_points: int
    mc_samples: int
    mc_seed: int
    tol: float
    max_iterations: int
    closure: str | bool
    normalise_rows: str | bool
    near_field_factor: float
    shoot_fraction: float
    cache_bytes: int


@dataclass(frozen=True)
class HierarchySettings(_Section):
    """radiosity.hierarchy.*"""

    SECTION: ClassVar[str] = "hierarchy"
    kernel: str
    epsilon: float | str
    epsilon_base: float
    epsilon_resolution: int
    link_rays: int
    weight: str
    oracle: str
    far_kernel: str
    final_gather: str
    final_gather_levels: int
    near_gauss_gap: float
    kernel_weighted_rays: bool
    inside_solids: bool
    shadow_factor: float
    min_node_size: float
    split_hidden: bool
    rounds: int | str
    rounds_auto_ratio: float
    rounds_auto_share: float
    rounds_epsilon: float
    rounds_change: float
    rounds_rays: int
    rounds_row_excess: float
    task_unit: str
    max_task_cost: int
    driver_solve_links: int
    clusters: str
    clusters_above: int
    clusters_epsilon: float
    unseen_importance: float
    receiver: str

    def clustered(self, originals: int) -> tuple[bool, str]:
        """(on, why): clusters above the originals (clusters: auto | on | off; auto above
        clusters-above originals, where pairs of originals stop being affordable)."""
        mode = {True: "on", False: "off"}.get(self.clusters, self.clusters)
        if mode not in ("auto", "on", "off"):
            raise RadiosityError(f"radiosity.hierarchy.clusters must be auto, on or off, got {mode!r}")
        if mode != "auto":
            return mode == "on", f"{mode}: stated (clusters: {mode})"
        above = int(self.clusters_above)
        if originals > above:
            return True, f"on: auto, {originals} originals > {above}"
        return False, f"off: auto, {originals} originals <= {above}"


@dataclass(frozen=True)
class DirectSettings(_Section):
    """radiosity.direct.*: where the light straight from emitters is computed (SPEC §10): at
    points (`points`: pixels, gather points, the leaves' stratified points; links carry only the
    light after its first bounce), through the links as any other light (`links`, the seed's
    way), or per scene (`auto`: methods/hierarchical/params.choose_direct)."""

    SECTION: ClassVar[str] = "direct"
    mode: str
    samples: int
    leaf_points: int
    auto_share: float
    oracle: str
    smooth_floor: float


@dataclass(frozen=True)
class ImageSettings(_Section):
    """radiosity.render.*"""

    SECTION: ClassVar[str] = "render"
    sampling: str
    area_samples: int
    edge_samples: int
    filter: str
    sigma: float
    exposure: float | None


@dataclass(frozen=True)
class ClusterSettings(_Section):
    """radiosity.cluster.*"""

    SECTION: ClassVar[str] = "cluster"
    kind: str
    workers: int
    threads_per_worker: int
    host: str
    dashboard_address: str
    tls: bool | str
    adaptive: bool | str
    worker_timeout: int
    processes: bool | str
    in_process_samples: int
    malloc_trim_threshold: int
    malloc_mmap_threshold: int
    direct_scatter: str


@dataclass(frozen=True)
class ReferenceSettings(_Section):
    """radiosity.reference.*"""

    SECTION: ClassVar[str] = "reference"
    variant: str
    spp: int
    passes: int
    study_spp: int
    seed: int
    truncation: float
    max_samples_per_call: int


@dataclass(frozen=True)
class ViewFactorSettings(_Section):
    """radiosity.viewfactors.*"""

    SECTION: ClassVar[str] = "viewfactors"
    accuracy: float
    cheap_share: float
    max_points_per_side: int
    seed: int
    cutoff: float
    leaf_size: int
    task_pairs: int
    tasks_per_worker: int
    batch_pairs: int
    ray_batch: int
    window_per_worker: int
    retries: int
    enclosure: str
    balance_tol: float
    balance_max_iterations: int
    csv_max_nonzeros: int

@dataclass(frozen=True)
class HeatSettings(_Section):
    """radiosity.heat.* (radiosity heat: viewfactors/heat.py, core/netradiation.py)"""

    SECTION: ClassVar[str] = "heat"
    tol: float
    max_iterations: int
    conductances: str
    conductance_max_facets: int
    conductance_cutoff: float
    conductance_block_mb: int
    conductance_dense_facets: int
    esatan_max_conductors: int


SECTIONS = {c.SECTION: c for c in (SceneSettings, RaySettings, SubdivideSettings, PlanSettings,
                                   VisibilitySettings, SolveSettings, HierarchySettings,
                                   DirectSettings, ImageSettings, ClusterSettings, ReferenceSettings,
                                   ViewFactorSettings)}
SECTIONS[HeatSettings.SECTION] = HeatSettings


@dataclass(frozen=True)
class Settings:
    """Every section, frozen: `settings.solve.tol`, `settings.hierarchy.epsilon`, ..."""

    scene: SceneSettings
    rays: RaySettings
    subdivide: SubdivideSettings
    plan: PlanSettings
    visibility: VisibilitySettings
    solve: SolveSettings
    hierarchy: HierarchySettings
    direct: DirectSettings
    render: ImageSettings
    cluster: ClusterSettings
    reference: ReferenceSettings
    viewfactors: ViewFactorSettings
    heat: HeatSettings

    def replace(self, overrides: dict | None = None) -> "Settings":
        """A copy with `{"section.key": value}` applied (None values are skipped: not given)."""
        by_section: dict = {}
        for key, value in (overrides or {}).items():
            if value is None:
                continue
            section, _, name = key.partition(".")
            cls = SECTIONS.get(section)
            field = cls.field_of(name) if cls is not None else name
            if cls is None or field not in {f.name for f in dataclasses.fields(cls)}:
                raise RadiosityError(f"unknown setting radiosity.{key}: see radiosity.yaml for "
                                     "the keys")
            kind = next(f.type for f in dataclasses.fields(cls) if f.name == field)
            by_section.setdefault(section, {})[field] = _coerce(value, kind, f"radiosity.{key}")
        if not by_section:
            return self
        return dataclasses.replace(self, **{s: dataclasses.replace(getattr(self, s), **kw)
                                            for s, kw in by_section.items()})

    def to_dict(self) -> dict:
        return {s: getattr(self, s).to_dict() for s in SECTIONS}


def resolve(overrides: dict | None = None, base: Settings | None = None) -> Settings:
    """The settings of a run: `base` (or dask.config's radiosity.*, read here once) with
    `overrides` ({"solve.tol": 1e-4, ...}; None values are not given) applied, checked
    (check: the same one-line RadiosityError for the CLI's flags and the API's keywords)."""
    if base is None:
        base = Settings(**{s: cls.from_dict(config.section(s)) for s, cls in SECTIONS.items()})
    return check(base.replace(overrides))


# ----------------------------------------------------------------------------- options

#: The options a user gives by name, the same on the CLI (--max-iterations) and in the Python
#: API (max_iterations=): keyword -> the setting(s) it overrides. `unit` is both methods' task
#: unit (--task-unit).
OPTIONS = {
    "subpixel": ("subdivide.subpixel",), "variant": ("subdivide.variant",),
    "subscenes": ("subdivide.subscenes",),
    "solver": ("solve.solver",), "kernel": ("solve.kernel",), "tol": ("solve.tol",),
    "max_iterations": ("solve.max-iterations",), "closure": ("solve.closure",),
    "nxm_points": ("solve.nxm-points",), "mc_samples": ("solve.mc-samples",),
    "mc_seed": ("solve.mc-seed",),
    "filter": ("render.filter",), "sigma": ("render.sigma",), "exposure": ("render.exposure",),
    "sampling": ("render.sampling",), "area_samples": ("render.area-samples",),
    "edge_samples": ("render.edge-samples",),
    "method": ("visibility.method",), "unit": ("visibility.task-unit", "hierarchy.task-unit"),
    "epsilon": ("hierarchy.epsilon",), "link_rays": ("hierarchy.link-rays",),
    "processes": ("cluster.processes",), "direct": ("direct.mode",),
    "accuracy": ("viewfactors.accuracy",), "cutoff": ("viewfactors.cutoff",),
    "enclosure": ("viewfactors.enclosure",),
}


def overrides_of(**options) -> dict:
    """{"section.key": value} of the options given by keyword (OPTIONS; None: not given);
    an unknown keyword is a RadiosityError that lists the known ones."""
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise RadiosityError(f"unknown option(s) {', '.join(unknown)} (options: "
                             f"{', '.join(OPTIONS)})")
    return {key: v for name, v in options.items() if v is not None for key in OPTIONS[name]}


def options(base: Settings | None = None, **given) -> Settings:
    """The settings of the options given by keyword (tol=1e-6, method="pairs", ...) over `base`
    (None: dask.config's radiosity.*), checked: `radiosity.render`'s and the tests' way in."""
    return resolve(overrides_of(**given), base=base)


def _at_least(lo):
    return lambda v: math.isfinite(v) and v >= lo, f"{lo} or more"


def _above(lo):
    return lambda v: math.isfinite(v) and v > lo, f"a number above {lo}"


def _one_of(*names):
    return lambda v: v in names, f"one of {', '.join(map(str, names))}"


def _registered(module: str, getter: str, extra=()):
    """A name the registry's getter knows (core.kernels.get_kernel, core.solvers.get_solver),
    or one of `extra`: the getter's own error ("unknown kernel 'x': use one of ...")."""
    import importlib

    def ok(v):
        return v in extra or getattr(importlib.import_module(module), getter)(v) is not None

    return ok, "a registered name"


_ON_OFF = _one_of("auto", "on", "off", True, False)

#: The checks of every value a user sets by name: setting -> (test, what it must be).
CHECKS = {
    "subdivide.subpixel": _at_least(1), "subdivide.variant": _one_of("exact", "seed", "none"),
    "subdivide.subscenes": _at_least(0),
    "solve.solver": _registered("radiosity.core.solvers", "get_solver", ("auto",)),
    "solve.kernel": _registered("radiosity.core.kernels", "get_kernel"),
    "solve.tol": (lambda v: math.isfinite(v) and 0 < v < 1, "a number in (0, 1)"),
    "solve.max-iterations": _at_least(1), "solve.closure": _ON_OFF,
    "solve.nxm-points": _at_least(1), "solve.mc-samples": _at_least(1),
    "solve.mc-seed": _at_least(0),
    "render.filter": _one_of("box", "gaussian"), "render.sigma": _above(0),
    "render.exposure": (lambda v: v is None or v == "auto" or (
        isinstance(v, (int, float)) and math.isfinite(v) and v > 0),
        "a positive number or auto"),
    "render.sampling": _one_of("area", "point"), "render.area-samples": _at_least(1),
    "render.edge-samples": _at_least(0),
    "visibility.task-unit": _one_of("block", "stripe", "auto"),
    "hierarchy.task-unit": _one_of("block", "stripe", "auto"),
    "hierarchy.epsilon": (lambda v: v == "auto" or (
        isinstance(v, (int, float)) and math.isfinite(v) and v >= 0), "a number >= 0 or auto"),
    "hierarchy.link-rays": _at_least(1),
    "hierarchy.receiver": _one_of("auto", "reflected", "arriving"),
    "direct.mode": _one_of("auto", "points", "links"), "direct.samples": _at_least(1),
    "direct.leaf-points": (lambda v: v >= 1 and math.isqrt(int(v)) ** 2 == v,
                           "a square (1, 4, 9, ...)"),
    "direct.auto-share": (lambda v: math.isfinite(v) and 0 <= v <= 1, "a number in [0, 1]"),
    "cluster.processes": _one_of("auto", "true", "false", True, False),
    "viewfactors.accuracy": (lambda v: math.isfinite(v) and 0 < v < 1, "a number in (0, 1)"),
    "viewfactors.cutoff": _at_least(0), "viewfactors.enclosure": _ON_OFF,
    "reference.spp": _at_least(1), "reference.passes": _at_least(1),
    "reference.seed": _at_least(0),
}
# radiosity heat's settings (radiosity.heat.*)
CHECKS.update({
    "heat.tol": (lambda v: math.isfinite(v) and 0 < v < 1, "a number in (0, 1)"),
    "heat.max-iterations": _at_least(1), "heat.conductances": _ON_OFF,
    "heat.conductance-max-facets": _at_least(0), "heat.conductance-cutoff": _at_least(0),
    "heat.conductance-block-mb": _at_least(1), "heat.esatan-max-conductors": _at_least(0),
    "heat.conductance-dense-facets": _at_least(0),
})
OPTIONS.update({"conductances": ("heat.conductances",),
                "conductance_cutoff": ("heat.conductance-cutoff",)})
# the oracle with the emitters' light at points (methods/hierarchical/params.smooth_weights)
CHECKS.update({"direct.oracle": _one_of("smooth", "plain"),
               "direct.smooth-floor": (lambda v: math.isfinite(v) and v >= 0, "a number >= 0")})
_FLAGS = {key: name for name, keys in OPTIONS.items() for key in keys}


def check(settings: Settings) -> Settings:
    """`settings`, its user-set values checked (CHECKS); the first bad one is a RadiosityError
    naming the option, its flag and its setting: "tol (--tol, radiosity.solve.tol) must be a
    number in (0, 1), got 2.0" from the CLI and the API alike."""
    for key, (ok, what) in CHECKS.items():
        section, _, name = key.partition(".")
        v = getattr(getattr(settings, section), name.replace("-", "_"))
        opt = _FLAGS.get(key)
        where = f"{opt} (--{opt.replace('_', '-')}, radiosity.{key})" if opt else f"radiosity.{key}"
        try:
            good = bool(ok(v))
        except TypeError:
            good = False
        except RadiosityError as e:  # a registry's own line, which lists the names
            raise RadiosityError(f"{where}: {e}") from None
        if not good:
            finite = (isinstance(v, float) and not math.isfinite(v))
            raise RadiosityError(f"{where} must be {what}, got {v!r}"
                                 + (": not a finite number" if finite else ""))
    return settings


def sampling_of(solve: SolveSettings, kernel: str | None = None):
    """The sample points kernel `kernel` (default solve.kernel) needs: a kernels.Sampling, or
    None for one ray between centres."""
    from radiosity.core.kernels import make_sampling

    return make_sampling(kernel or solve.kernel, solve.nxm_points, solve.mc_samples, solve.mc_seed)
