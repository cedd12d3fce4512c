"""Tunables resolved on the driver into the plain values worker inputs carry.

Stage masters call these (they read radiosity.* from dask.config); worker code receives the
results and never reads the configuration itself.
"""

from __future__ import annotations

from . import config
from .kernels import Sampling, make_sampling


def sampling_of(kernel: str, points: int | None = None, samples: int | None = None,
                seed: int | None = None) -> Sampling | None:
    """The sample points kernel `kernel` needs (None: one ray between centres), from
    radiosity.solve.nxm-points / mc-samples / mc-seed unless given."""
    return make_sampling(kernel, config.get("solve.nxm-points", points),
                         config.get("solve.mc-samples", samples), config.get("solve.mc-seed", seed))
