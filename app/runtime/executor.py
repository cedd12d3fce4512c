"""Task groups of a pass on a Dask cluster (`GroupExecutor`): each group pinned to one worker so
its caches stay warm across passes, failed groups resubmitted anywhere, and a pass whose
scattered data died with a worker scattered again and rerun. The transport operators of every
method run their passes here (methods/pairs/transport.py, methods/hierarchical/solve/transport.py).
"""

from __future__ import annotations

from typing import Callable

from radiosity.errors import RadiosityError
from radiosity.runtime.cluster import Scattered
from radiosity.runtime.runner import gather_retrying


class GroupExecutor:
    """Task groups on a Dask cluster, each pinned to one worker (its cache stays warm across
    passes), resubmitted anywhere when it fails; a pass whose scattered data died with a worker
    scatters its inputs again and reruns. Operators of every method run their passes here."""

    def __init__(self, client, inputs, ngroups: int, retries: int):
        self.client = client
        self.inputs = inputs
        self.ngroups = ngroups
        self.retries = retries
        self._pin()
        self.shared = Scattered(client, inputs)

    def _pin(self) -> None:
        alive = sorted(self.client.scheduler_info()["workers"])
        self.workers = [alive[g % len(alive)] if alive else None for g in range(self.ngroups)]

    def replace_inputs(self, inputs) -> None:
        """New inputs for every later pass (one scatter)."""
        self.inputs = inputs
        self.shared = Scattered(self.client, inputs)

    def run(self, fn, args_of: Callable, vectors: tuple, name: str, count: int | None = None) -> list:
        """[fn(inputs, *args_of(i, *vector_futures)) for each group i], in group order.
        `vectors` are scattered once per pass (sent again when their only copy dies)."""
        from concurrent.futures import CancelledError

        count = self.ngroups if count is None else count
        for attempt in range(self.retries + 1):
            try:
                vf = self.client.scatter(list(vectors), broadcast=False, hash=False)

                def submit(i, again):
                    if again and any(f.status != "finished" for f in vf):
                        vf[:] = self.client.scatter(list(vectors), broadcast=False, hash=False)
                    w = self.workers[i % len(self.workers)] if self.workers else None
                    return self.client.submit(fn, self.shared.future(), *args_of(i, *vf), pure=False,
                                              workers=[w] if w else None,
                                              allow_other_workers=bool(w))

                return gather_retrying(self.client, submit, count, self.retries, name=name)
            except (CancelledError, OSError) as e:  # FutureCancelledError, CommClosedError
                if attempt == self.retries:
                    raise RadiosityError(f"a solver pass failed {attempt + 1} times: workers were "
                                         f"lost ({type(e).__name__}: {e})") from None
                self._pin()
