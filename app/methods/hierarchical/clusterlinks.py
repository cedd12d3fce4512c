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


@numba.njit(cache=True, nogil=True)
def cluster_gather(Lroot, parent, leaf_orig, area, p, q, g, G):
    """G (C, n) += the cluster links' transfer into the originals' roots (front side), from
    Lroot (C, n) the originals' area-weighted mean radiance: pull up the cluster tree (S: the
    nodes' A L sums), gather over the links (node a receives g S_b / (A_a A_b)), push down to
    the leaves' originals. Returns the link terms."""
    K = parent.shape[0]
    C = Lroot.shape[0]
    S = np.zeros((C, K))
    H = np.zeros((C, K))
    inv = np.zeros(K)
    for x in range(K):
        inv[x] = 1.0 / area[x] if area[x] > 0 else 0.0
        o = leaf_orig[x]
        if o >= 0:
            for c in range(C):
                S[c, x] = area[x] * Lroot[c, o]
    for x in range(K - 1, 0, -1):
        for c in range(C):
            S[c, parent[x]] += S[c, x]
    for k in range(p.shape[0]):
        a, b = p[k], q[k]
        w = g[k] * inv[a] * inv[b]
        for c in range(C):
            H[c, a] += w * S[c, b]
            H[c, b] += w * S[c, a]
    for x in range(1, K):
        for c in range(C):
            H[c, x] += H[c, parent[x]]
    for x in range(K):
        o = leaf_orig[x]
        if o >= 0:
            for c in range(C):
                G[c, o] += H[c, x]
    return 2 * p.shape[0]
