"""numba loops of the mesh loader (scene.meshes): the OBJ byte scanner and the greedy merge of
triangle pairs into parallelograms.

Both are exact stand-ins for the per-line and per-triangle Python loops they replaced: the scanner
only takes the lines it can read exactly as the Python reader would (anything else is left to
it, see `scan_obj`), and the merge tries the same candidates in the same order with the same
floating-point expressions (no fused multiply-adds: numba's default, fastmath off).
"""

from __future__ import annotations

import numba
import numpy as np

# line kinds of scan_obj
SKIP, VERTEX, FACE, OTHER = 0, 1, 2, 3

_POW10 = np.array([1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13,
                   1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22])
_TWO53 = 2 ** 53


@numba.njit(cache=True)
def _float_token(b, t0, t1, pow10):
    """The decimal number b[t0:t1] if it is one of the strict form
    [+-]?(d+[.d*]|.d+)([eE][+-]?d+)?: (0, value) when exact by Clinger's fast path (an integer
    mantissa below 2^53 times or over a power of ten up to 1e22: one correctly rounded operation,
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


@numba.njit(cache=True)
def _is_space(c):
    return c == 32 or c == 9


@numba.njit(cache=True)
def _room(a, n):
    """a, or a copy twice as long, holding at least n + 1 entries."""
    if n < len(a):
        return a
    b = np.empty(max(2 * len(a), n + 1), a.dtype)
    b[:len(a)] = a
    return b


@numba.njit(cache=True)
def _scan(b):
    """scan_obj's loop over the lines of b. Returns status (1: the Python reader must read the
    file), coordinates (3 V,), positions and bytes of the numbers float() must read, face
    indices, counts and lines, and the line, start and end of each OTHER line."""
    pow10 = _POW10
    n = len(b)
    coords = np.empty(3 * 1024)
    slow_pos = np.empty(16, np.int64)
    slow_buf = np.empty(256, np.uint8)
    fidx = np.empty(3 * 1024, np.int64)
    fcount = np.empty(1024, np.int64)
    fline = np.empty(1024, np.int64)
    other = np.empty((16, 3), np.int64)
    nv = 0
    nf = 0
    nidx = 0
    nslow = 0
    nslowb = 0
    nother = 0
    fail = (1, coords[:0], slow_pos[:0], slow_buf[:0], fidx[:0], fcount[:0], fline[:0], other[:0])
    li = -1
    s = 0
    while s < n:
        li += 1
        ls = s
        e = s  # the end of the line; any other of str.splitlines' line breaks: fail
        while e < n and b[e] != 10:
            c = b[e]
            if c == 13 or c == 11 or c == 12 or c == 28 or c == 29 or c == 30:
                return fail
            e += 1
        i = s
        s = e + 1
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
        kind = OTHER
        if not printable:
            kind = OTHER
        elif k - i == 1 and b[i] == 118:  # v
            j = k
            ntok = 0
            coords = _room(coords, 3 * nv + 2)
            while ntok < 3:
                while j < pc and _is_space(b[j]):
                    j += 1
                if j == pc:
                    break
                t0 = j
                while j < pc and not _is_space(b[j]):
                    j += 1
                st, val = _float_token(b, t0, j, pow10)
                if st == 2:
                    return fail
                if st == 0:
                    coords[3 * nv + ntok] = val
                else:
                    slow_pos = _room(slow_pos, nslow)
                    slow_pos[nslow] = 3 * nv + ntok
                    slow_buf = _room(slow_buf, nslowb + j - t0)
                    for t in range(t0, j):
                        slow_buf[nslowb + t - t0] = b[t]
                    slow_buf[nslowb + j - t0] = 32
                    nslow += 1
                    nslowb += j - t0 + 1
                ntok += 1
            if ntok < 3:
                return fail
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
                    return fail
                if neg:
                    val = -val
                idx = val - 1 if val > 0 else nv + val
                if not 0 <= idx < nv:
                    return fail
                fidx = _room(fidx, nidx + ntok)
                fidx[nidx + ntok] = idx
                ntok += 1
            if ntok < 3:
                return fail
            fcount = _room(fcount, nf)
            fline = _room(fline, nf)
            fcount[nf] = ntok
            fline[nf] = li
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
            if nother == len(other):
                grown = np.empty((2 * nother, 3), np.int64)
                grown[:nother] = other
                other = grown
            other[nother, 0] = li
            other[nother, 1] = ls
            other[nother, 2] = e
            nother += 1
    return (0, coords[:3 * nv], slow_pos[:nslow], slow_buf[:nslowb], fidx[:nidx], fcount[:nf],
            fline[:nf], other[:nother])


def scan_obj(b: np.ndarray):
    """The OBJ bytes b (uint8, UTF-8) read in bulk: None where the Python reader must read the
    file (a line it might read otherwise or reject: a `v` or `f` line not of the plain forms
    `v x y z [...]` (numbers [+-]d.dE[+-]d) and `f i[/...] j k ...` (indices, negative ones
    relative) or one naming a vertex not read yet, a line break other than '\\n', ...); else
    (vertex coordinates (3 V,), the positions among them of those float() must read and their
    bytes (space-separated), face indices (flat, 0-based), vertices per face, line of each
    face, and (line, start, end) of each line left to the Python reader: usemtl, mtllib,
    non-ASCII or malformed statements)."""
    out = _scan(b)
    return None if out[0] else out[1:]


# ----------------------------------------------------------------------------- merge

@numba.njit(cache=True)
def _norm3(x, y, z):
    return np.sqrt(x * x + y * y + z * z)


@numba.njit(cache=True)
def merge_pairs(P, vid, mat, order, gstart, group, tol):
    """The greedy pairing of merge_parallelograms. P (t, 3, 3): the triangles' vertices; vid
    (t, 3): vertex identities; mat (t,): material codes; order: the edge slots 3 k + e sorted by
    edge (stable: in the order the Python loop appended them), gstart: where each edge's run
    starts in order (and its end), group (3 t,): the run of each slot; tol: merge tolerance.
    Returns partner (t,) (-1: none), edge (t,): the shared edge e of the triangle that became
    the quad (-1 for the others), and pedge (t,): the slot ej of that edge in its partner."""
    t = P.shape[0]
    partner = -np.ones(t, np.int64)
    edge = -np.ones(t, np.int64)
    pedge = -np.ones(t, np.int64)
    for k in range(t):
        if partner[k] >= 0:
            continue
        for e in range(3):
            e1 = (e + 1) % 3
            e2 = (e + 2) % 3
            b = vid[k, e1]
            g = group[3 * k + e]
            for r in range(gstart[g], gstart[g + 1]):
                s = order[r]
                j = s // 3
                ej = s - 3 * j
                if j == k or partner[j] >= 0 or mat[j] != mat[k]:
                    continue
                if vid[j, ej] != b:
                    continue
                y = (ej + 2) % 3
                pax, pay, paz = P[k, e, 0], P[k, e, 1], P[k, e, 2]
                pbx, pby, pbz = P[k, e1, 0], P[k, e1, 1], P[k, e1, 2]
                pxx, pxy, pxz = P[k, e2, 0], P[k, e2, 1], P[k, e2, 2]
                qyx, qyy, qyz = P[j, y, 0], P[j, y, 1], P[j, y, 2]
                d1 = _norm3(pax - pbx, pay - pby, paz - pbz)
                d2 = _norm3(pxx - qyx, pxy - qyy, pxz - qyz)
                d = d2 if d2 > d1 else d1
                m = _norm3((pax + pbx) - (pxx + qyx), (pay + pby) - (pxy + qyy),
                           (paz + pbz) - (pxz + qyz))
                if m > tol * d:
                    continue
                ux, uy, uz = pbx - pax, pby - pay, pbz - paz
                vx, vy, vz = pxx - pax, pxy - pay, pxz - paz
                n1x, n1y, n1z = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
                ux, uy, uz = pax - pbx, pay - pby, paz - pbz
                vx, vy, vz = qyx - pbx, qyy - pby, qyz - pbz
                n2x, n2y, n2z = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
                dot = n1x * n2x + n1y * n2y + n1z * n2z
                cx = n1y * n2z - n1z * n2y
                cy = n1z * n2x - n1x * n2z
                cz = n1x * n2y - n1y * n2x
                if dot <= 0 or _norm3(cx, cy, cz) > tol * _norm3(n1x, n1y, n1z) * _norm3(n2x, n2y, n2z):
                    continue
                partner[k] = j
                partner[j] = k
                edge[k] = e
                pedge[k] = ej
                break
            if partner[k] >= 0:
                break
    return partner, edge, pedge


@numba.njit(cache=True)
def diameter(verts):
    """Largest vertex-to-vertex distance of each polygon (n, 4, 3): core.geometry.diameter's
    values to the bit (its norms sum the squares x, y, z left to right), without its
    (n, 4, 4, 3) temporaries."""
    n = verts.shape[0]
    out = np.empty(n)
    for p in range(n):
        m = 0.0
        for i in range(4):
            for j in range(i + 1, 4):
                dx = verts[p, i, 0] - verts[p, j, 0]
                dy = verts[p, i, 1] - verts[p, j, 1]
                dz = verts[p, i, 2] - verts[p, j, 2]
                d = np.sqrt(dx * dx + dy * dy + dz * dz)
                if d > m:
                    m = d
        out[p] = m
    return out
