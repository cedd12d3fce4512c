"""Radiosity with simplified form factors (Debelov & Sattarov), as a Dask application."""

import os as _os

__version__ = "0.1.0"

# LLVM's -O1 for the numba kernels unless the user chose a level: they compile in about 2/3 of
# the time of -O3 and run as fast (benchmarks/bench_quickstart.py --opt; docs: measurements).
# It must be set before numba is imported (worker processes inherit it).
_os.environ.setdefault("NUMBA_OPT", "1")


def __getattr__(name):
    """`render` and `view_factors` are imported on first use, so that `import radiosity` stays
    cheap."""
    if name == "view_factors":
        from radiosity.viewfactors.api import viewfactors

        return viewfactors
    if name == "render":
        from radiosity.pipeline import render

        return render
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
