"""Where numba's compile time goes: a recorder of numba's compile events (each kernel's own
time, nested compiles of its callees subtracted), used by `radiosity warmup` and the
Quick-start benchmark. Kernels compile on first call into their cache (`cache=True`), once per
machine; a load from that cache is not a compile and is not recorded here."""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field


@dataclass
class CompileLog:
    """Seconds of compile per kernel ("module.function"), exclusive of the callees it compiled,
    and how many signatures each got."""

    seconds: dict = field(default_factory=dict)
    signatures: dict = field(default_factory=dict)

    @property
    def total_s(self) -> float:
        return float(sum(self.seconds.values()))

    def top(self, n: int = 10) -> list[tuple[str, float, int]]:
        rows = sorted(self.seconds.items(), key=lambda kv: -kv[1])[:n]
        return [(k, v, self.signatures[k]) for k, v in rows]

    def to_dict(self) -> dict:
        return {"total_s": round(self.total_s, 3), "kernels": len(self.seconds),
                "per_kernel_s": {k: round(v, 3) for k, v, _ in self.top(len(self.seconds))},
                "signatures": dict(self.signatures)}


def _name(data) -> str:
    d = data.get("dispatcher") if isinstance(data, dict) else None
    f = getattr(d, "py_func", None)
    if f is None:
        return "?"
    return f"{f.__module__.replace('radiosity.', '')}.{f.__qualname__}"


@contextlib.contextmanager
def recording(echo=None, every_s: float | None = None):
    """Record every numba compile in this process while the block runs. `echo(line)` is told of
    each kernel as it finishes or, with `every_s`, of the running count at most that often
    (progress for a first run whose compile takes minutes)."""
    from numba.core import event

    log = CompileLog()
    stack: list[list] = []  # [name, start, children seconds]
    last = [time.perf_counter()]

    class Listener(event.Listener):
        def on_start(self, ev):
            stack.append([_name(ev.data), time.perf_counter(), 0.0])

        def on_end(self, ev):
            if not stack:
                return
            name, t0, inner = stack.pop()
            took = time.perf_counter() - t0
            if stack:
                stack[-1][2] += took
            log.seconds[name] = log.seconds.get(name, 0.0) + took - inner
            log.signatures[name] = log.signatures.get(name, 0) + 1
            if echo is None or stack:
                return
            now = time.perf_counter()
            if every_s is None:
                echo(f"compiled {name} ({took:.1f} s)")
            elif now - last[0] >= every_s:
                last[0] = now
                echo(f"numba: {len(log.seconds)} kernels compiled in {log.total_s:.0f} s so far "
                     "(once per machine: later runs load them from the cache)")

    with listening(Listener()):
        yield log


@contextlib.contextmanager
def listening(listener):
    """A numba compile-event listener (numba.core.event.Listener) registered while the block
    runs: this recorder's, and precompile.recording_order's."""
    from numba.core import event

    event.register("numba:compile", listener)
    try:
        yield listener
    finally:
        event.unregister("numba:compile", listener)
