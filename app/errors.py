"""User-facing errors: each names the file, element, material or option at fault."""


class RadiosityError(Exception):
    """An error the CLI prints as one clear line (no traceback)."""


class SceneError(RadiosityError, ValueError):
    """Bad scene input: file, format, geometry, material or camera."""


class StoreError(RadiosityError):
    """A run store that is missing, from another version, or corrupted."""


class RenderError(RadiosityError):
    """Bad render input: an unreadable image file, an unknown filter, a bad parameter."""
