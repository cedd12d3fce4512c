"""A per-worker-process cache of what passes read from the run store, bounded in bytes."""

from __future__ import annotations

import threading
from collections import OrderedDict


class BoundedCache:
    """A least-recently-used cache bounded in bytes, safe under several threads per worker
    (the loads run outside the lock: two threads may load the same key once each)."""

    def __init__(self):
        self._items: OrderedDict = OrderedDict()  # key -> (value, bytes)
        self._bytes = 0
        self._lock = threading.Lock()

    def get(self, key, load, nbytes, cap: int):
        with self._lock:
            got = self._items.get(key)
            if got is not None:
                self._items.move_to_end(key)
                return got[0]
        value = load()
        size = int(nbytes(value))
        if size <= cap:
            with self._lock:
                if key not in self._items:
                    self._items[key] = (value, size)
                    self._bytes += size
                while self._bytes > cap and self._items:
                    _, (_, old) = self._items.popitem(last=False)
                    self._bytes -= old
        return value

    @property
    def nbytes(self) -> int:
        return self._bytes

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self._bytes = 0


CACHE = BoundedCache()  # one per worker process: what passes read from the store
