"""Radiosity with simplified form factors (Debelov & Sattarov), as a Dask application."""

__version__ = "0.1.0"
