"""Radiosity with simplified form factors (Debelov & Sattarov), as a Dask application.

`radiosity.render(scene, out)` renders a scene, `radiosity.view_factors(mesh)` computes the
view factors between a mesh's facets, `radiosity.heat(scene)` the radiative heat exchange
between them; all raise `radiosity.RadiosityError` on bad input.
"""

import os as _os

__version__ = "0.1.0"

# LLVM's -O1 for the numba kernels unless the user chose a level: they compile in about 2/3 of
# the time of -O3 and run as fast (benchmarks/bench_quickstart.py --opt; docs: measurements).
# It must be set before numba is imported (worker processes inherit it).
_os.environ.setdefault("NUMBA_OPT", "1")

# name -> (module, attribute): imported on first use, so that `import radiosity` stays cheap
_LAZY = {
    "render": ("radiosity.pipeline", "render"),
    "view_factors": ("radiosity.viewfactors.api", "viewfactors"),
    "heat": ("radiosity.viewfactors.api", "heat"),
    "RadiosityError": ("radiosity.errors", "RadiosityError"),
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name):
    """The names of `_LAZY`, imported on first use."""
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    module, attr = _LAZY[name]
    return getattr(importlib.import_module(module), attr)


def __dir__():
    """What `dir(radiosity)` and tab completion show: the public names, lazy ones included."""
    return sorted(set(__all__) | {k for k in globals() if not k.startswith("_")})
