"""The engine's tunables: one commented YAML (`radiosity.yaml`) registered in dask.config.

`section("solve")` is the one reader of radiosity.* (settings.resolve calls it once per run);
`dask_get` and `dask_set` serve the cluster start only, which dask's own configuration
(jobqueue.*, distributed.*) shapes too: the one place outside settings that touches dask.config.
"""

from __future__ import annotations

import os

import dask.config
import yaml

_FN = os.path.join(os.path.dirname(__file__), "radiosity.yaml")

with open(_FN) as _f:
    _DEFAULTS = yaml.safe_load(_f)

dask.config.update_defaults(_DEFAULTS)
dask.config.ensure_file(source=_FN)


def section(name: str) -> dict:
    """The radiosity.<name>.* table as dask.config holds it now (user files, environment
    variables and dask.config.set included)."""
    return dict(dask.config.get(f"radiosity.{name}"))


def dask_get(key: str, default=None):
    """A key of dask's own configuration (`jobqueue.slurm.cores`, `distributed.scheduler.preload`),
    `default` when unset: the cluster start only (radiosity.* keys come from settings)."""
    return dask.config.get(key, default=default)


def dask_set(values: dict):
    """dask.config.set(values) as a context manager: the local cluster's nanny environment."""
    return dask.config.set(values)
