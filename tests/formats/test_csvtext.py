"""The compiled CSV writer against Python's own formatting (printf's %.7g and %d)."""

import csv
import io
import math

import numpy as np

from radiosity.formats.csvtext import csv_cell, csv_chunks


def csv_body(columns) -> bytes:
    return b"".join(bytes(c) for c in csv_chunks(columns, csv_cell))


def _tie(x: float) -> bool:
    """x lies within 1e-6 of a unit of a decimal tie at its 8th significant digit."""
    e = math.floor(math.log10(abs(x)))
    frac = abs(x) / 10.0 ** (e - 6) % 1.0
    return abs(frac - 0.5) < 1e-6


def test_floats_and_integers_read_as_printf_writes_them():
    rng = np.random.default_rng(7)
    x = np.concatenate([
        rng.standard_normal(20000) * 10.0 ** rng.integers(-320, 300, 20000),
        np.concatenate([np.round(rng.uniform(0, 1000, 2000), k) for k in range(6)]),
        [0.0, -0.0, np.nan, np.inf, -np.inf, 1e7, 9999999.0, 9999999.5, 1e-4, 9.999999e-5,
         1e-5, 123456.75, 5e-324, 1.7976931348623157e308, 0.5, 1.0, 100.0, 1e6, -2.5e-7]])
    got = csv_body([x]).decode().splitlines()
    want = ["%.7g" % v for v in x.tolist()]
    assert len(got) == len(x)
    off = [(g, w, v) for g, w, v in zip(got, want, x.tolist()) if g != w]
    # printf rounds the exact binary value; the kernel rounds once after scaling: they may
    # differ only where the value is a decimal tie at the 8th digit
    assert all(_tie(v) and abs(float(g) - float(w)) <= 1.01e-6 * abs(v) for g, w, v in off), off
    assert len(off) < len(x) // 100
    ints = np.concatenate([rng.integers(-2 ** 63, 2 ** 63 - 1, 2000),
                           [0, -1, 1, -2 ** 63, 2 ** 63 - 1]]).astype(np.int64)
    assert csv_body([ints]).decode().splitlines() == ["%d" % v for v in ints.tolist()]


def test_rows_mix_numbers_and_quoted_names():
    names = np.array(["white", "lamp, blue-less", 'the "red" wall'] * 3)
    body = csv_body([np.arange(9), names, np.linspace(0.0, 1.0, 9), np.arange(9) % 2 == 0])
    rows = list(csv.reader(io.StringIO(body.decode())))
    assert len(rows) == 9
    assert [r[1] for r in rows] == names.tolist()
    assert [int(r[0]) for r in rows] == list(range(9))
    np.testing.assert_allclose([float(r[2]) for r in rows], np.linspace(0.0, 1.0, 9), rtol=1e-6)
    assert [r[3] for r in rows] == ["1", "0"] * 4 + ["1"]
    assert csv_body([np.zeros(0), np.zeros(0, int)]) == b""


def test_chunks_join_to_the_same_text(monkeypatch):
    import radiosity.formats.csvtext as ct

    rng = np.random.default_rng(2)
    cols = [rng.uniform(0, 1, 1000), rng.integers(0, 9, 1000), np.array(["a", "b,c"] * 500)]
    whole = csv_body(cols)
    monkeypatch.setattr(ct, "ROWS_PER_CALL", 7)
    assert csv_body(cols) == whole
    assert len(list(ct.csv_chunks(cols, csv_cell))) == -(-1000 // 7)
