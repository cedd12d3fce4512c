"""OBJ (+ MTL) files -> RawMesh, keeping quads as quads: an OBJ face with four vertices is one
element (trimesh triangulates on load, which would lose the seed's quad elements). MTL gives
each material's reflectance (Kd) and emitted radiance (Ke)."""

from __future__ import annotations

import gc
import os
import re

import numpy as np

from radiosity.errors import SceneError
from radiosity.formats.objscan import scan_obj
from radiosity.formats.raw import RawMesh

_KEYWORD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_GARBLED = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f\ufffd]")


def _floats(parts, fn, lineno, n=3):
    try:
        vals = [float(p) for p in parts[:n]]
    except ValueError:
        raise SceneError(f"{fn}:{lineno}: expected {n} numbers, got {' '.join(parts)!r}") from None
    if len(vals) < n:
        raise SceneError(f"{fn}:{lineno}: expected {n} numbers, got {' '.join(parts)!r}")
    return vals


def _check_line(fn: str, lineno: int, line: str, key: str, kind: str) -> None:
    """A text line of an OBJ or MTL file starts with a keyword and holds no binary bytes
    (unknown keywords are skipped, as other readers do; garbage is not)."""
    if _GARBLED.search(line) or not _KEYWORD.match(key):
        raise SceneError(f"{fn} could not be parsed as {kind} (line {lineno}): "
                         f"{line.strip()[:40]!r} is not an {kind} statement")


def _read_whole(fn: str) -> str:
    try:
        with open(fn, encoding="utf-8", errors="replace") as f:
            return f.read()
    except FileNotFoundError:
        raise SceneError(f"mesh file not found: {fn}") from None
    except OSError as e:
        raise SceneError(f"cannot read mesh file {fn}: {e.strerror}") from None


def _read_text(fn: str) -> list[str]:
    return _read_whole(fn).splitlines()


def _load_mtl(fn: str) -> dict:
    mats: dict = {}
    cur = None
    for lineno, line in enumerate(_read_text(fn), 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        key, args = parts[0], parts[1:]
        _check_line(fn, lineno, line.split("#", 1)[0], key, "MTL")
        if key == "newmtl":
            cur = " ".join(args)
            mats[cur] = {}
        elif cur is not None and key == "Kd":
            mats[cur]["reflectance"] = _floats(args, fn, lineno)
        elif cur is not None and key == "Ke":
            mats[cur]["emission"] = _floats(args, fn, lineno)
    return mats


#: OBJ texts up to this many characters (about 2 000 lines) are read line by line
SMALL_OBJ = 1 << 16


def load_obj(fn: str) -> RawMesh:
    """Minimal OBJ reader (v, f, usemtl, mtllib) that keeps quads as quads.

    trimesh triangulates on load, which would lose the seed's quad elements. The plain lines
    (`v x y z`, `f i j k ...`, comments, unknown statements) are read in bulk
    (formats.objscan.scan_obj); a file with anything else in a `v` or `f` line, or any error, is
    read line by line (`_load_obj_lines`), which says what is wrong and where. So is a file of
    at most SMALL_OBJ characters: the same result, without compiling the bulk scanner on a
    first run (docs/src/measurements/choices.md).
    """
    text = _read_whole(fn)
    raw = _load_obj_bulk(fn, text) if len(text) > SMALL_OBJ else None
    return raw if raw is not None else _load_obj_lines(fn, text.splitlines())


def _load_obj_bulk(fn: str, text: str) -> RawMesh | None:
    """The OBJ text read as _load_obj_lines reads it, or None where that reader must (a line the
    scanner leaves to it, an error: it names the first bad line)."""
    if "\r" in text:
        text = text.replace("\r\n", "\n")  # one line break for splitlines too; a lone \r: None
    if not text.isascii() and any(c in text for c in "\x85\u2028\u2029"):
        return None  # more of splitlines' line breaks
    data = text.encode("utf-8")
    scan = scan_obj(np.frombuffer(data, np.uint8))
    if scan is None:
        return None
    coords, slow_pos, slow_buf, fidx, fcount, fline, other = scan
    if len(slow_pos):  # numbers beyond the exact fast path (17 digits, large exponents)
        s = slow_buf[:-1].tobytes().decode("ascii")
        try:
            vals = np.fromstring(s, sep=" ")
        except ValueError:
            vals = np.array([float(t) for t in s.split()])
        if len(vals) != len(slow_pos):
            return None
        coords[slow_pos] = vals
    mats: dict = {}
    cur = "default"
    ev_line, ev_name = [], []
    base = os.path.dirname(fn)
    try:
        for li, start, end in other.tolist():
            line = data[start:end].decode("utf-8")
            parts = line.split("#", 1)[0].split()
            if not parts:
                continue
            key, args = parts[0], parts[1:]
            _check_line(fn, li + 1, line.split("#", 1)[0], key, "OBJ")
            if key in ("v", "f"):
                return None
            if key == "usemtl":
                cur = " ".join(args) or "default"
                ev_line.append(li)
                ev_name.append(cur)
            elif key == "mtllib":
                mfn = os.path.join(base, " ".join(args))
                if not os.path.exists(mfn):
                    return None
                mats.update(_load_mtl(mfn))
    except Exception:  # an error: the line reader says it, with the first bad line's number
        return None
    which = np.searchsorted(np.asarray(ev_line, np.int64), fline, side="right")
    fmat = np.array(["default"] + ev_name, dtype=object)[which].tolist()
    collect = gc.isenabled()
    gc.disable()  # a million small lists: the cyclic collector would walk them all many times
    try:
        if len(fcount) and np.all(fcount == fcount[0]):
            faces = fidx.reshape(len(fcount), -1).tolist()
        else:  # the faces of each size at once, then in file order
            starts = np.zeros(len(fcount) + 1, np.int64)
            np.cumsum(fcount, out=starts[1:])
            faces = np.empty(len(fcount), object)
            for c in np.unique(fcount).tolist():
                sel = np.flatnonzero(fcount == c)
                rows = fidx[starts[sel][:, None] + np.arange(c)].tolist()
                faces[sel] = np.fromiter(rows, object, count=len(rows))
            faces = faces.tolist()
    finally:
        if collect:
            gc.enable()
    return RawMesh(coords.reshape(-1, 3), faces, fmat, mats)


def _load_obj_lines(fn: str, lines: list[str]) -> RawMesh:
    """The OBJ reader, one line at a time (for what _load_obj_bulk leaves to it)."""
    verts, faces, fmat, mats = [], [], [], {}
    cur = "default"
    base = os.path.dirname(fn)
    for lineno, line in enumerate(lines, 1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        key, args = parts[0], parts[1:]
        _check_line(fn, lineno, line.split("#", 1)[0], key, "OBJ")
        if key == "v":
            verts.append(_floats(args, fn, lineno))
        elif key == "f":
            idx = []
            for a in args:
                try:
                    k = int(a.split("/")[0])
                except ValueError:
                    raise SceneError(f"{fn}:{lineno}: bad face index {a!r}") from None
                k = k - 1 if k > 0 else len(verts) + k
                if not 0 <= k < len(verts):
                    raise SceneError(f"{fn}:{lineno}: face refers to vertex {a} that does not exist")
                idx.append(k)
            if len(idx) < 3:
                raise SceneError(f"{fn}:{lineno}: a face needs at least 3 vertices")
            faces.append(idx)
            fmat.append(cur)
        elif key == "usemtl":
            cur = " ".join(args) or "default"
        elif key == "mtllib":
            mfn = os.path.join(base, " ".join(args))
            if not os.path.exists(mfn):
                raise SceneError(f"{fn}:{lineno}: material library not found: {mfn}")
            mats.update(_load_mtl(mfn))
    return RawMesh(np.array(verts, float).reshape(-1, 3), faces, fmat, mats)


def load_obj_file(fn: str, default_material: str = "default") -> RawMesh:
    """load_obj, its faces without a material (`default`) given `default_material`."""
    raw = load_obj(fn)
    if default_material != "default":
        raw.face_material = [default_material if m == "default" else m for m in raw.face_material]
    return raw


#: The readers of this module, by file extension (merged in formats.load).
loaders = {".obj": load_obj_file}
