"""CSV files of tables (`write_csv`), their text made in compiled code: a table of 10^6 rows is
about 15 million numbers, too many for Python's `%` formatting (timed in
docs/src/measurements/hierarchical.md#clusters). Numbers are written as C's printf writes
them: integers as %d, floats as %.7g (7 significant digits, trailing zeros removed, exponent
form below 1e-4 and from 1e7 on, "nan", "inf", "-inf"); the 7 digits are the value rounded
once from its product with an exact power of ten, which can differ from printf's exact
decimal rounding only on ties closer than 1e-16 relative.

Columns (one kernel call per ROWS_PER_CALL rows): kinds[c] 0 float (floats[idx[c]]), 1 integer
(ints[idx[c]]), 2 text (codes[idx[c]] into the pre-quoted byte strings `text` at offsets
`toff`).
"""

from __future__ import annotations

import os

import numba
import numpy as np

from radiosity.formats.files import temp_path

FLOAT, INT, TEXT = 0, 1, 2
_NUM_WIDTH = 24  # the widest number: "-1.234567e-308" and int64's 20 digits fit


@numba.njit(cache=True, nogil=True)
def _digits(v, buf, pos):
    """The decimal digits of v >= 0 at buf[pos:]; returns the new position."""
    if v == 0:
        buf[pos] = 48
        return pos + 1
    n = 0
    w = v
    while w > 0:
        n += 1
        w //= 10
    for k in range(n - 1, -1, -1):
        buf[pos + k] = 48 + v % 10
        v //= 10
    return pos + n


@numba.njit(cache=True, nogil=True)
def _int(v, buf, pos):
    if v < 0:
        buf[pos] = 45
        pos += 1
        if v == -9223372036854775808:  # no positive counterpart
            pos = _digits(922337203685477580, buf, pos)
            buf[pos] = 56
            return pos + 1
        v = -v
    return _digits(v, buf, pos)


@numba.njit(cache=True, nogil=True)
def _scaled(x, k):
    """round(x * 10^k) (k may be negative): one rounding of an exact power of ten's product."""
    if k >= 0:
        if k <= 22:
            return np.rint(x * 10.0 ** k)
        return np.rint(x * 10.0 ** 22 * 10.0 ** (k - 22))
    if -k <= 22:
        return np.rint(x / 10.0 ** (-k))
    return np.rint(x / 10.0 ** 22 / 10.0 ** (-k - 22))


@numba.njit(cache=True, nogil=True)
def _g7(x, buf, pos, d):
    """x as printf's %.7g at buf[pos:] (d: scratch for 7 digits); returns the new position."""
    if x != x:
        buf[pos], buf[pos + 1], buf[pos + 2] = 110, 97, 110  # nan
        return pos + 3
    if x < 0.0 or (x == 0.0 and np.copysign(1.0, x) < 0.0):
        buf[pos] = 45
        pos += 1
        x = -x
    if x == np.inf:
        buf[pos], buf[pos + 1], buf[pos + 2] = 105, 110, 102  # inf
        return pos + 3
    if x == 0.0:
        buf[pos] = 48
        return pos + 1
    e = int(np.floor(np.log10(x)))
    m = _scaled(x, 6 - e)
    if m >= 1e7:  # log10 rounded up, or the rounding carried into an 8th digit
        e += 1
        m = _scaled(x, 6 - e)
    elif m < 1e6:
        e -= 1
        m = _scaled(x, 6 - e)
    if m >= 1e7:
        e += 1
        m = 1e6
    mi = int(m)
    for k in range(6, -1, -1):
        d[k] = mi % 10
        mi //= 10
    last = 6  # the last digit kept: trailing zeros go
    while last > 0 and d[last] == 0:
        last -= 1
    if -4 <= e < 7:
        if e >= 0:
            for k in range(e + 1):
                buf[pos] = 48 + d[k]
                pos += 1
            if last > e:
                buf[pos] = 46
                pos += 1
                for k in range(e + 1, last + 1):
                    buf[pos] = 48 + d[k]
                    pos += 1
        else:
            buf[pos], buf[pos + 1] = 48, 46  # "0."
            pos += 2
            for k in range(-e - 1):
                buf[pos] = 48
                pos += 1
            for k in range(last + 1):
                buf[pos] = 48 + d[k]
                pos += 1
        return pos
    buf[pos] = 48 + d[0]
    pos += 1
    if last > 0:
        buf[pos] = 46
        pos += 1
        for k in range(1, last + 1):
            buf[pos] = 48 + d[k]
            pos += 1
    buf[pos] = 101  # e
    buf[pos + 1] = 45 if e < 0 else 43
    pos += 2
    a = -e if e < 0 else e
    if a < 10:
        buf[pos] = 48
        pos += 1
    return _digits(a, buf, pos)


@numba.njit(cache=True, nogil=True)
def _rows(kinds, idx, floats, ints, codes, text, toff, buf):
    n = floats.shape[1] if floats.shape[0] else (ints.shape[1] if ints.shape[0]
                                                 else codes.shape[1])
    pos = 0
    d = np.empty(7, np.int64)
    for r in range(n):
        for c in range(kinds.shape[0]):
            if c:
                buf[pos] = 44
                pos += 1
            if kinds[c] == FLOAT:
                pos = _g7(floats[idx[c], r], buf, pos, d)
            elif kinds[c] == INT:
                pos = _int(ints[idx[c], r], buf, pos)
            else:
                t = codes[idx[c], r]
                for b in range(toff[t], toff[t + 1]):
                    buf[pos] = text[b]
                    pos += 1
        buf[pos] = 10
        pos += 1
    return pos


#: Rows formatted per kernel call: the text buffer stays a few tens of MiB for any table.
ROWS_PER_CALL = 1 << 16


def csv_chunks(columns: list, quote):
    """The rows of a table as CSV bytes (no header), ROWS_PER_CALL rows at a time (memoryviews
    of one reused buffer: write each before taking the next): columns, a list of (rows,)
    arrays (numbers as above; anything else is text, each distinct value passed once through
    `quote`)."""
    kinds, idx, fl, it, cd, parts = [], [], [], [], [], []
    strings: dict = {}
    width = 1
    for v in columns:
        v = np.asarray(v)
        if v.dtype.kind == "f":
            kinds.append(FLOAT), idx.append(len(fl)), fl.append(v.astype(np.float64))
            width += _NUM_WIDTH
        elif v.dtype.kind in "iub":
            kinds.append(INT), idx.append(len(it)), it.append(v.astype(np.int64))
            width += _NUM_WIDTH
        else:
            uniq, inv = np.unique(v.astype(str), return_inverse=True)
            code = []
            for u in uniq.tolist():
                if u not in strings:
                    strings[u] = len(parts)
                    parts.append(quote(u).encode("utf-8"))
                code.append(strings[u])
            kinds.append(TEXT), idx.append(len(cd)), cd.append(np.asarray(code, np.int64)[inv])
            width += 1 + max((len(parts[c]) for c in code), default=0)
    n = len(columns[0]) if columns else 0
    toff = np.concatenate([[0], np.cumsum([len(p) for p in parts])]).astype(np.int64)
    text = np.frombuffer(b"".join(parts), np.uint8) if parts else np.zeros(0, np.uint8)
    kinds, idx = np.asarray(kinds, np.int64), np.asarray(idx, np.int64)
    buf = np.empty(min(n, ROWS_PER_CALL) * width, np.uint8)
    for a in range(0, n, ROWS_PER_CALL):
        b = min(n, a + ROWS_PER_CALL)
        rows = lambda arrs, dt: (np.stack([x[a:b] for x in arrs]) if arrs  # noqa: E731
                                 else np.zeros((0, b - a), dt))
        end = _rows(kinds, idx, rows(fl, np.float64), rows(it, np.int64), rows(cd, np.int64),
                    text, toff, buf)
        yield memoryview(buf)[:end]


def csv_cell(v) -> str:
    """One CSV cell: the text of v, quoted (with doubled quotes) where it holds a comma, a
    quote or a line break."""
    s = str(v)
    if any(ch in s for ch in ',"\n\r'):
        s = '"' + s.replace('"', '""') + '"'
    return s


def write_csv(path: str, table: dict) -> None:
    """One table (dict column name -> (rows,) array) as CSV: a header of the column names,
    numbers with 7 significant digits ("nan" where undefined), names quoted where they need
    it (`csv_chunks` writes the rows). Written whole, then renamed."""
    cols = list(table)
    tmp = temp_path(path)
    with open(tmp, "wb") as f:
        f.write((",".join(csv_cell(c) for c in cols) + "\n").encode("utf-8"))
        for chunk in csv_chunks([table[k] for k in cols], csv_cell):
            f.write(chunk)
    os.replace(tmp, path)
