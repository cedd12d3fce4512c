"""The engine's tunables: one commented YAML (`radiosity.yaml`) registered in dask.config.

`section("solve")` is the one reader of radiosity.* (settings.resolve calls it once per run);
`get` serves the cluster start only, which dask's own configuration shapes too.
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


def get(key: str, override=None):
    """Value of `radiosity.<key>`, or `override` when that is not None: the cluster start only."""
    if override is not None:
        return override
    return dask.config.get(f"radiosity.{key}")
