"""Tunables resolved on the driver into the plain values worker inputs carry.

Stage masters call these (they read radiosity.* from dask.config); worker code receives the
results and never reads the configuration itself.
"""

from __future__ import annotations

from radiosity import config
from radiosity.core.kernels import Sampling, make_sampling


def sampling_of(kernel: str, points: int | None = None, samples: int | None = None,
                seed: int | None = None) -> Sampling | None:
    """The sample points kernel `kernel` needs (None: one ray between centres), from
    radiosity.solve.nxm-points / mc-samples / mc-seed unless given."""
    return make_sampling(kernel, config.get("solve.nxm-points", points),
                         config.get("solve.mc-samples", samples), config.get("solve.mc-seed", seed))


METHODS = ("auto", "pairs", "hierarchical")


def choose_method(sub_elements: int, setting: str | None = None,
                  kernel: str | None = None, originals: int = 1) -> tuple[str, str]:
    """(method, why) for a run of `sub_elements`: radiosity.visibility.method unless given;
    auto takes hierarchical above radiosity.visibility.hierarchical-above sub-elements, where it
    measured faster at the same error (bench_hierarchy: 2.6x at 128^2, 19x at 256^2 on the
    Cornell box), and the seed's pairs below, where both cost the same and pairs is the exact
    all-pairs limit. A sampled kernel (nxm, mc) is the pairs method's (links sample their
    own rays): auto takes pairs for it, and for scenes of many originals with few sub-elements
    each (visibility.hierarchical-min-per-original: a 20 000-triangle floor at 16^2 took 67 s
    hierarchical against 17 s with pairs)."""
    from radiosity.errors import RadiosityError

    method = config.get("visibility.method", setting)
    if method not in METHODS:
        raise RadiosityError(f"--method must be one of {', '.join(METHODS)}, got {method!r}")
    if method != "auto":
        return method, f"{method}: stated (method: {method})"
    above = int(config.get("visibility.hierarchical-above"))
    kernel = config.get("solve.kernel", kernel)
    if kernel not in ("point", "disc", "point-nf", "disc-nf"):
        return "pairs", f"pairs: auto, the {kernel} kernel samples the pairs' own rays"
    per = float(config.get("visibility.hierarchical-min-per-original"))
    if sub_elements < per * originals:
        return "pairs", (f"pairs: auto, {sub_elements} sub-elements on {originals} originals "
                         f"(under {per:g} each: no trees for links to coarsen)")
    if sub_elements > above:
        return "hierarchical", (f"hierarchical: auto, {sub_elements} sub-elements > {above} "
                                "(links grow at most like m, pairs like m^2)")
    return "pairs", f"pairs: auto, {sub_elements} sub-elements <= {above} (all pairs cost no more)"
