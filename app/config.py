"""The engine's tunables: one commented YAML (`radiosity.yaml`) registered in dask.config.

`get("subdivide.max-depth")` reads a value; CLI flags pass explicit values that win. Only the
driver reads it (stage masters, the CLI): worker code receives every value it needs explicitly,
so a worker with another config computes what the run's token says.
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


def default(key: str):
    """The packaged default of `radiosity.<key>` (radiosity.yaml as shipped, not the user's
    dask.config): for code that must not depend on where it runs (worker-side defaults)."""
    node = _DEFAULTS["radiosity"]
    for part in key.split("."):
        node = node[part]
    return node


def get(key: str, override=None):
    """Value of `radiosity.<key>`, or `override` when that is not None (a CLI flag)."""
    if override is not None:
        return override
    return dask.config.get(f"radiosity.{key}")
