"""The OBJ byte scanner (numba): the plain `v` and `f` lines of an OBJ file read in bulk, an exact
stand-in for the per-line Python reader (formats.obj): it only takes the lines it reads exactly
as that reader does, and leaves everything else to it (see `scan_obj`). Issue #25: a mesh of
10^6 triangles loads in seconds.
"""

from __future__ import annotations

import numba
import numpy as np

# line kinds of scan_obj
SKIP, VERTEX, FACE, OTHER = 0, 1, 2, 3

_POW10 = np.array([1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13,
                   1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22])
_TWO53 = 2 ** 53


@numba.njit(cache=True, nogil=True)
def _float_token(b, t0, t1, pow10):
    """The decimal number b[t0:t1] if it is one of the strict form
    [+-]?(d+[.d*]|.d+)([eE][+-]?d+)?: (0, value) when exact by Clinger's fast path (an integer
    mantissa of at most 2^53 times or over a power of ten up to 1e22: one correctly rounded operation,
    the value float() gives), (1, 0.0) when valid but not so (float() must read it), (2, 0.0) when
    not of that form."""
    i = t0
    neg = False
    if b[i] == 43 or b[i] == 45:  # + -
        neg = b[i] == 45
        i += 1
    m = 0
    nsig = 0
    ndig = 0
    exp = 0
    long = False
    while i < t1 and 48 <= b[i] <= 57:
        d = b[i] - 48
        ndig += 1
        if m > 0 or d > 0:
            if nsig < 18:
                m = m * 10 + d
                nsig += 1
            else:
                long = True
        i += 1
    if i < t1 and b[i] == 46:  # .
        i += 1
        while i < t1 and 48 <= b[i] <= 57:
            d = b[i] - 48
            ndig += 1
            if m > 0 or d > 0:
                if nsig < 18:
                    m = m * 10 + d
                    nsig += 1
                    exp -= 1
                else:
                    long = True
            else:
                exp -= 1
            i += 1
    if ndig == 0:
        return 2, 0.0
    if i < t1 and (b[i] == 101 or b[i] == 69):  # e E
        i += 1
        eneg = False
        if i < t1 and (b[i] == 43 or b[i] == 45):
            eneg = b[i] == 45
            i += 1
        ne = 0
        e10 = 0
        while i < t1 and 48 <= b[i] <= 57:
            if e10 < 100000:
                e10 = e10 * 10 + (b[i] - 48)
            ne += 1
            i += 1
        if ne == 0:
            return 2, 0.0
        exp += -e10 if eneg else e10
    if i != t1:
        return 2, 0.0
    if long:
        return 1, 0.0
    if m == 0:
        v = 0.0
    elif m <= _TWO53 and -22 <= exp <= 22:
        v = float(m)
        if exp >= 0:
            v = v * pow10[exp]
        else:
            v = v / pow10[-exp]
    else:
        return 1, 0.0
    return 0, -v if neg else v


@numba.njit(cache=True, nogil=True)
def _is_space(c):
    return c == 32 or c == 9


@numba.njit(cache=True, nogil=True)
def _scan(b, st, coords, slow, slow_buf, fidx, faces, other):
    """scan_obj's loop over the lines of b, from where st (int64 (9,)) says: byte offset, line
    number (0-based) of the last line read, then the counts so far of vertices, face indices,
    faces, slow numbers, their bytes and OTHER lines. Writes coordinates, positions and bytes
    of the numbers float() must read (slow, slow_buf), face indices (fidx), (vertex count,
    line) of each face (faces) and (line, start, end) of each OTHER line (other). Returns 0
    when done, 1 when the Python reader must read the file, 2 when an output may not hold the
    next line (st says where it stopped, st[8] which outputs: bits 1 fidx, 2 faces, 4 slow,
    8 slow_buf, 16 other; grow them and call again)."""
    pow10 = _POW10
    n = len(b)
    s, li, nv, nidx, nf, nslow, nslowb, nother = st[0], st[1], st[2], st[3], st[4], st[5], st[6], st[7]
    while s < n:
        ls = s
        e = s  # the end of the line; any other of str.splitlines' line breaks: fail
        while e < n and b[e] != 10:
            c = b[e]
            if c == 13 or c == 11 or c == 12 or c == 28 or c == 29 or c == 30:
                return 1
            e += 1
        full = 0  # room for this line, whatever it holds
        if nidx + (e - ls) > len(fidx):
            full |= 1
        if nf + 1 > faces.shape[0]:
            full |= 2
        if nslow + 3 > len(slow):
            full |= 4
        if nslowb + (e - ls) + 3 > len(slow_buf):
            full |= 8
        if nother + 1 > other.shape[0]:
            full |= 16
        if full or 3 * nv + 3 > len(coords):
            st[0], st[1], st[2], st[3], st[4], st[5], st[6], st[7] = ls, li, nv, nidx, nf, nslow, nslowb, nother
            st[8] = full
            return 2
        li += 1
        s = e + 1
        i = ls
        while i < e and _is_space(b[i]):
            i += 1
        if i == e or b[i] == 35:  # blank or a comment
            continue
        pc = i  # the end of the part before a comment
        printable = True
        while pc < e and b[pc] != 35:
            c = b[pc]
            if not (c == 9 or 32 <= c <= 126):
                printable = False
            pc += 1
        k = i
        while k < pc and not _is_space(b[k]):
            k += 1
        if not printable:
            kind = OTHER
        elif k - i == 1 and b[i] == 118:  # v
            j = k
            ntok = 0
            while ntok < 3:
                while j < pc and _is_space(b[j]):
                    j += 1
                if j == pc:
                    break
                t0 = j
                while j < pc and not _is_space(b[j]):
                    j += 1
                code, val = _float_token(b, t0, j, pow10)
                if code == 2:
                    return 1
                if code == 0:
                    coords[3 * nv + ntok] = val
                else:
                    slow[nslow] = 3 * nv + ntok
                    for t in range(t0, j):
                        slow_buf[nslowb + t - t0] = b[t]
                    slow_buf[nslowb + j - t0] = 32
                    nslow += 1
                    nslowb += j - t0 + 1
                ntok += 1
            if ntok < 3:
                return 1
            nv += 1
            kind = VERTEX
        elif k - i == 1 and b[i] == 102:  # f
            j = k
            ntok = 0
            while True:
                while j < pc and _is_space(b[j]):
                    j += 1
                if j == pc:
                    break
                t0 = j
                while j < pc and not _is_space(b[j]):
                    j += 1
                # the index: the token up to its first '/', -?[0-9]{1,18}
                q = t0
                neg = False
                if b[q] == 45:
                    neg = True
                    q += 1
                val = 0
                nd = 0
                while q < j and 48 <= b[q] <= 57:
                    val = val * 10 + (b[q] - 48)
                    nd += 1
                    q += 1
                if nd == 0 or nd > 18 or (q < j and b[q] != 47):
                    return 1
                if neg:
                    val = -val
                idx = val - 1 if val > 0 else nv + val
                if not 0 <= idx < nv:
                    return 1
                fidx[nidx + ntok] = idx
                ntok += 1
            if ntok < 3:
                return 1
            faces[nf, 0] = ntok
            faces[nf, 1] = li
            nidx += ntok
            nf += 1
            kind = FACE
        else:
            keyword = b[i] == 95 or 65 <= b[i] <= 90 or 97 <= b[i] <= 122
            for t in range(i + 1, k):
                c = b[t]
                if not (c == 95 or 65 <= c <= 90 or 97 <= c <= 122 or 48 <= c <= 57):
                    keyword = False
            if keyword and k - i == 6 and (
                    (b[i] == 117 and b[i + 1] == 115 and b[i + 2] == 101 and b[i + 3] == 109
                     and b[i + 4] == 116 and b[i + 5] == 108)  # usemtl
                    or (b[i] == 109 and b[i + 1] == 116 and b[i + 2] == 108 and b[i + 3] == 108
                        and b[i + 4] == 105 and b[i + 5] == 98)):  # mtllib
                keyword = False
            kind = SKIP if keyword else OTHER
        if kind == OTHER:
            other[nother, 0] = li
            other[nother, 1] = ls
            other[nother, 2] = e
            nother += 1
    st[0], st[1], st[2], st[3], st[4], st[5], st[6], st[7] = s, li, nv, nidx, nf, nslow, nslowb, nother
    return 0


def _grow(a: np.ndarray) -> np.ndarray:
    b = np.empty((max(2 * len(a), 16),) + a.shape[1:], a.dtype)
    b[:len(a)] = a
    return b


def scan_obj(b: np.ndarray, room: int | None = None):
    """The OBJ bytes b (uint8, UTF-8) read in bulk: None where the Python reader must read the
    file (a line it might read otherwise or reject: a `v` or `f` line not of the plain forms
    `v x y z [...]` (numbers [+-]d.dE[+-]d) and `f i[/...] j k ...` (indices, negative ones
    relative) or one naming a vertex not read yet, a line break other than '\\n', ...); else
    (vertex coordinates (3 V,), the positions among them of those float() must read and their
    bytes (space-separated), face indices (flat, 0-based), vertices per face, line of each
    face, and (line, start, end) of each line left to the Python reader: usemtl, mtllib,
    non-ASCII or malformed statements). room: the outputs' first size (None: sizes that
    usually hold the file; the outputs grow as needed)."""
    lines = int(np.count_nonzero(b == 10)) + 1
    st = np.zeros(9, np.int64)
    st[1] = -1
    coords = np.empty(3 * lines)  # three per line at most
    if room is None:
        out = [np.empty(lines + 1024, np.int64), np.empty((lines // 2 + 1024, 2), np.int64),
               np.empty(1024, np.int64), np.empty(1 << 16, np.uint8), np.empty((256, 3), np.int64)]
    else:
        out = [np.empty(room, np.int64), np.empty((room, 2), np.int64), np.empty(room, np.int64),
               np.empty(room, np.uint8), np.empty((room, 3), np.int64)]
    while True:
        fidx, faces, slow, slow_buf, other = out
        status = _scan(b, st, coords, slow, slow_buf, fidx, faces, other)
        if status != 2:
            break
        out = [_grow(a) if st[8] & bit else a for a, bit in zip(out, (1, 2, 4, 8, 16))]
    if status:
        return None
    nv, nidx, nf, nslow, nslowb, nother = st[2:8].tolist()
    return (coords[:3 * nv], slow[:nslow], slow_buf[:nslowb], fidx[:nidx], faces[:nf, 0],
            faces[:nf, 1], other[:nother])
