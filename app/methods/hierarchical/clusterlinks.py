"""The cluster layer's links as a solve holds them and their transport (SPEC §9; design:
docs/src/design/methods-hierarchical-clusters.md): q sends its elements' area-weighted mean
radiance, p receives it uniformly (Sillion's isotropic cluster), one symmetric weight a link."""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np


@dataclass(frozen=True)
class ClusterLinks:
    """The cluster layer of a solve: the cluster tree (K nodes; parent (K,), leaf_orig (K,) the
    original of each leaf or -1, area (K,)) and its links p, q (k,) int32 node ids sorted by
    (p, q), each with one weight g (k,) float32 = A_p F_pq v = A_q F_qp v: the transfer is
    symmetric by construction, so energy is conserved whatever g's rounding, in 12 bytes a link
    (the 10^6-triangle terrain keeps 229 M of them). Front sides only."""

    parent: np.ndarray
    leaf_orig: np.ndarray
    area: np.ndarray
    p: np.ndarray
    q: np.ndarray
    g: np.ndarray

    def arrays(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}

    @property
    def links(self) -> int:
        return len(self.p)


#: The cluster links are gathered in this many parts, each into its own buffer, summed in a
#: fixed order (threads share the parts; the same bits on any number of cores).
GATHER_PARTS = 2


def cluster_gather(Lroot, parent, leaf_orig, area, p, q, g, G, threads=None) -> int:
    """G (C, n) += the cluster links' transfer into the originals' roots (front side), from
    Lroot (C, n) the originals' area-weighted mean radiance: pull up the cluster tree (the
    nodes' mean radiance), gather over the links (node a receives g Lbar_b / A_a), push down to
    the leaves' originals. The links go in GATHER_PARTS parts, mapped by `threads` (a function
    (fn, items) -> [fn(x) for x in items], in threads; None: one after another). Returns the
    link terms."""
    S, inv = _pull_means(Lroot, parent, leaf_orig, area)
    cut = np.linspace(0, len(p), GATHER_PARTS + 1).astype(np.int64)

    def part(k):
        H = np.zeros_like(S)
        _link_sums(S, p[cut[k]:cut[k + 1]], q[cut[k]:cut[k + 1]], g[cut[k]:cut[k + 1]], H)
        return H

    parts = (threads or (lambda fn, items: [fn(x) for x in items]))(part, list(range(GATHER_PARTS)))
    H = parts[0]
    for h in parts[1:]:
        H += h
    _push_down(H, inv, parent, leaf_orig, G)
    return 2 * len(p)


@numba.njit(cache=True, nogil=True)
def _pull_means(Lroot, parent, leaf_orig, area):
    """(K, C) the nodes' area-weighted mean radiance from the originals' (Lroot (C, n)), and
    (K,) 1 / area (0 for no area). One row a node: a link reads and writes whole rows."""
    K = parent.shape[0]
    C = Lroot.shape[0]
    S = np.zeros((K, C))
    inv = np.zeros(K)
    for x in range(K):
        inv[x] = 1.0 / area[x] if area[x] > 0 else 0.0
        o = leaf_orig[x]
        if o >= 0:
            for c in range(C):
                S[x, c] = area[x] * Lroot[c, o]
    for x in range(K - 1, 0, -1):
        for c in range(C):
            S[parent[x], c] += S[x, c]
    for x in range(K):
        for c in range(C):
            S[x, c] *= inv[x]
    return S, inv


@numba.njit(cache=True, nogil=True)
def _link_sums(S, p, q, g, H):
    """H[a] += g Lbar_b and H[b] += g Lbar_a over the links (a, b) (power received, A_a E_a)."""
    C = S.shape[1]
    for k in range(p.shape[0]):
        a, b = p[k], q[k]
        w = np.float64(g[k])
        for c in range(C):
            H[a, c] += w * S[b, c]
            H[b, c] += w * S[a, c]


@numba.njit(cache=True, nogil=True)
def _push_down(H, inv, parent, leaf_orig, G):
    """G[:, o] += the irradiance each leaf's original receives: H / A at every node, summed
    down the tree (parents before children)."""
    K, C = H.shape
    for x in range(K):
        for c in range(C):
            H[x, c] *= inv[x]
    for x in range(1, K):
        for c in range(C):
            H[x, c] += H[parent[x], c]
    for x in range(K):
        o = leaf_orig[x]
        if o >= 0:
            for c in range(C):
                G[c, o] += H[x, c]
