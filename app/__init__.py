"""Radiosity with simplified form factors (Debelov & Sattarov), as a Dask application."""

__version__ = "0.1.0"


def __getattr__(name):
    """`view_factors` is imported on first use, so that `import radiosity` stays cheap."""
    if name == "view_factors":
        from radiosity.viewfactors.api import viewfactors

        return viewfactors
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
