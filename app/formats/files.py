"""Writing a file whole: to a temporary name next to it first, then renamed onto it, so that a
reader (or a run killed half-way) never sees half a file."""

from __future__ import annotations

import os


def temp_path(path: str) -> str:
    """A name next to `path` to write to first and os.replace onto it (no half-written file)."""
    root, ext = os.path.splitext(path)
    return f"{root}.tmp{os.getpid()}{ext}"


def write_bytes(path: str, data: bytes) -> None:
    """`data` as the file `path`, written whole, then renamed onto it."""
    tmp = temp_path(path)
    with open(tmp, "wb") as f:
        f.write(data)
    os.replace(tmp, path)
