"""A first run's numba compile on two cores: while the run compiles its kernels in the order it
needs them, a helper process compiles the same kernels from the other end of that order into the
same cache (`cache=True`), so the two meet in the middle and the run loads the rest from the
cache. The order and the signatures are recorded in `kernels.txt` next to this file
(`radiosity warmup --record` with an empty cache; a test checks that it still covers the
kernels a render of either method compiles): the pairs method's own kernels first, then a
Quick-start render's. The helper takes the kernels not in the cache yet: all of them on a
first run, the pairs method's on a first pairs render after a Quick start. Once every kernel
is in the cache, nothing is started."""

from __future__ import annotations

import argparse
import contextlib
import functools
import importlib
import os
import subprocess
import sys

#: The recorded numba signatures (kernels.txt): module, function and argument types a line.
SIGNATURES_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "kernels.txt")


# ----------------------------------------------------------------------------- signatures as text

def typestr(t) -> str:
    """A numba type as a Python expression over `types`, `np` and the classes it names: the
    inverse of parse_type. Raises TypeError for a type it does not know (literals, lists, ...):
    the recorder leaves such a signature out, and the run compiles it itself."""
    from numba.core import types

    if isinstance(t, types.Array):
        return (f"types.Array({typestr(t.dtype)}, {t.ndim}, {t.layout!r}, readonly={not t.mutable}, "
                f"aligned={t.aligned})")
    if isinstance(t, types.Record):
        return f"numba.from_dtype(np.dtype({t.dtype.descr!r}, align={t.aligned}))"
    if isinstance(t, (types.NamedUniTuple, types.NamedTuple)):
        cls = f"cls('{t.instance_class.__module__}', '{t.instance_class.__qualname__}')"
        if isinstance(t, types.NamedUniTuple):
            return f"types.NamedUniTuple({typestr(t.dtype)}, {t.count}, {cls})"
        return f"types.NamedTuple([{', '.join(typestr(x) for x in t.types)}], {cls})"
    if isinstance(t, types.UniTuple):
        return f"types.UniTuple({typestr(t.dtype)}, {t.count})"
    if isinstance(t, types.Tuple):
        return f"types.Tuple([{', '.join(typestr(x) for x in t.types)}])"
    if isinstance(t, (types.Integer, types.Float, types.Boolean, types.Complex)) \
            and not isinstance(t, types.Literal):
        return f"types.{'boolean' if isinstance(t, types.Boolean) else t.name}"
    if isinstance(t, types.NoneType):
        return "types.none"
    raise TypeError(f"no text form for the numba type {t!r}")


def _cls(module: str, qualname: str):
    obj = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def parse_type(s: str):
    """The numba type that typestr wrote as s."""
    import numba
    import numpy as np
    from numba.core import types

    return eval(s, {"types": types, "numba": numba, "np": np, "cls": _cls})  # noqa: S307


def _split_top(s: str) -> list[str]:
    """s split at the commas outside brackets and quotes."""
    out, depth, cur, quote = [], 0, [], None
    for ch in s:
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append("".join(cur).strip())
            cur = []
            continue
        cur.append(ch)
    if "".join(cur).strip():
        out.append("".join(cur).strip())
    return out


def read_entries(path: str = SIGNATURES_PATH) -> list[tuple[str, str, str]]:
    """(module, function, argument types as text) per line of kernels.txt, in compile order."""
    out = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if line and not line.startswith("#"):
                mod, fn, args = line.split("\t")
                out.append((mod, fn, args))
    return out


def resolve(entry) -> tuple:
    """(dispatcher, argument types tuple) of an entry."""
    mod, fn, args = entry
    disp = _cls(mod, fn)
    return disp, tuple(parse_type(a) for a in _split_top(args))


# ----------------------------------------------------------------------------- the helper

def _in_cache(entry) -> bool:
    """Whether numba's cache has an index for the entry's kernel (any of its signatures)."""
    try:
        mod, fn, _ = entry
        return os.path.isfile(_cls(mod, fn)._cache._cache_file._index_path)
    except Exception:
        return True  # never start a helper on a guess


def cold_entries(entries=None) -> list:
    """The entries whose kernel has no cache index yet, in the recorded order: all of them on
    a fresh install; after a Quick start, the pairs method's own (kernels.txt's first lines)."""
    entries = read_entries() if entries is None else entries
    return [e for e in entries if not _in_cache(e)]


def cache_is_warm(entries=None) -> bool:
    """Whether numba's cache has an index for every recorded kernel: then the run loads its
    kernels (or recompiles the few whose source changed) and no helper is needed."""
    return not cold_entries(entries)


def start_helper() -> subprocess.Popen | None:
    """Start the helper when the cache is cold (the first run on a machine); None otherwise.
    The caller stops it with stop_helper when its own run ends."""
    if os.environ.get("RADIOSITY_NO_PRECOMPILE") or not os.path.isfile(SIGNATURES_PATH):
        return None
    if cache_is_warm():
        return None
    return subprocess.Popen([sys.executable, "-m", "radiosity.runtime.precompile"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)


def stop_helper(proc: subprocess.Popen | None) -> None:
    """Stop the helper (numba writes each cache file whole, so stopping it loses nothing but
    the kernel it was compiling)."""
    if proc is None or proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        proc.kill()


@contextlib.contextmanager
def precompiling():
    """The helper for the duration of a command: started when the cache is cold, stopped when
    the block ends (however it ends)."""
    proc = start_helper()
    try:
        yield proc
    finally:
        stop_helper(proc)


def with_helper(fn):
    """Decorator: run fn within precompiling() (the render commands and the Python API)."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with precompiling():
            return fn(*args, **kwargs)
    return wrapper


def compile_backwards(entries, meet: int = 3, echo=None) -> int:
    """Compile the entries from the last to the first, each into the cache; stop after `meet`
    entries in a row were already there (the run has got that far). Returns how many compiled."""
    import time

    done, in_cache = 0, 0
    for entry in reversed(entries):
        t = time.perf_counter()
        try:
            disp, sig = resolve(entry)
            misses = sum(disp._cache_misses.values())
            hits = sum(disp._cache_hits.values())
            disp.compile(sig)  # nothing when this process compiled it already (as a callee)
        except Exception:  # a stale line (kernel renamed, types changed): the run compiles it
            continue
        if sum(disp._cache_misses.values()) > misses:
            done += 1
            in_cache = 0
            if echo:
                echo(f"compiled {entry[0]}.{entry[1]} in {time.perf_counter() - t:.1f} s")
        elif sum(disp._cache_hits.values()) > hits:  # loaded: the run compiled it
            in_cache += 1
            if in_cache >= meet:
                break
    return done


# ----------------------------------------------------------------------------- the recorder

@contextlib.contextmanager
def recording_order():
    """Collect, while the block runs, every radiosity kernel signature this process compiles,
    as kernels.txt lines (module, function, argument types), in the order compilation started.
    Signatures with literal arguments (a callee typed inside its caller) are left out: they
    compile with their caller."""
    from numba.core import event

    from radiosity.runtime.warmup import listening

    seen, order = set(), []

    class Listener(event.Listener):
        def on_start(self, ev):
            d = ev.data.get("dispatcher") if isinstance(ev.data, dict) else None
            f = getattr(d, "py_func", None)
            if f is None or not f.__module__.startswith("radiosity."):
                return
            try:
                line = (f.__module__, f.__qualname__,
                        ", ".join(typestr(a) for a in ev.data.get("args")))
            except TypeError:
                return
            if line not in seen:
                seen.add(line)
                order.append(line)

        def on_end(self, ev):
            pass

    with listening(Listener()):
        yield order


def write_entries(order, path: str = SIGNATURES_PATH) -> int:
    """Write kernels.txt (every line checked to read back first). Returns the line count."""
    for line in order:
        resolve(line)
    with open(path, "w") as f:
        f.write("# numba kernels, in the order their compilation started: those a pairs-method "
                "render adds first,\n# then a Quick-start render's (the helper of a first run "
                "compiles the cold ones from the end)\n# (radiosity.runtime.precompile); "
                "regenerate with an empty cache:\n"
                "# NUMBA_CACHE_DIR=$(mktemp -d) radiosity warmup --record\n")
        for line in order:
            f.write("\t".join(line) + "\n")
    return len(order)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m radiosity.runtime.precompile",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--last", type=int, default=0, help="compile only the last N entries")
    ap.add_argument("-v", "--verbose", action="store_true")
    a = ap.parse_args(argv)
    entries = cold_entries()  # what is cached already, the run loads: the meeting is elsewhere
    if a.last:
        entries = entries[-a.last:]
    compile_backwards(entries, echo=print if a.verbose else None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
