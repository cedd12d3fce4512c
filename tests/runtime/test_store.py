"""runtime/store.py: RunStore.write_arrays writes arrays of one chunk or many (chunk by chunk,
WRITE_CHUNKS at a time) and reads them back as they were."""

from __future__ import annotations

import numpy as np
import pytest

from radiosity.runtime import store


@pytest.mark.parametrize("gate", [1, store.WRITE_CHUNKS])
def test_arrays_of_many_chunks_come_back_as_written(tmp_path, monkeypatch, gate):
    monkeypatch.setattr(store, "WRITE_CHUNKS", gate)
    rng = np.random.default_rng(5)
    arrays = {"empty": np.zeros((0, 3)),
              "small": np.arange(5),
              "rows": rng.random(((3 << 20) // 3 + 7, 3)),              # 4 chunks, the last part
              "flat": rng.integers(0, 1 << 30, (5 << 20) + 11).astype(np.int32)}
    rs = store.RunStore(str(tmp_path), "w")
    rs.write_arrays("t", arrays, {"token": "x"})
    back = store.RunStore(str(tmp_path)).read_arrays("t")
    for name, a in arrays.items():
        assert back[name].dtype == a.dtype and np.array_equal(back[name], a), name
    z = rs.root["t"]["rows"]
    assert z.chunks == store.chunks_of(arrays["rows"]) and z.chunks[0] < len(arrays["rows"])
    assert rs.group_attrs("t") == {"token": "x"}
