r"""Deformation-rate clustering (paper sec. 3.2, Algorithm 2) and resource limiting (sec. 3.5).

Elements are visited breadth-first over face adjacency from seeds. A cluster
keeps component-wise bounds of the 9 entries of F_dot over its members and
their centre (eq. 5),

.. math:: \dot F_{centre} = \tfrac12 (\dot F_{min} + \dot F_{max}),

and a face neighbour n of the current element e joins when

.. math:: d = \| \dot F_{centre} - \dot F_n \| < \tau \qquad (6)

with tau = tau_A if n or e was elastic in the previous frame, else tau_E, or
when n is in the forced set C of resource limiting. Clusters are vertex
disjoint (every vertex maps to at most one affine body in G): an element with
a vertex already owned by another cluster (a hinge) is skipped and stays
elastic. Single-element clusters are dissolved. The BFS runs in a compiled
kernel; its cost is linear in the number of elements.

Choices where the paper is silent: an element is enqueued at most once per
cluster (a queued flag), so it is tested against the centre at the time its
first accepting neighbour is processed; singletons are dissolved as soon as
their BFS ends, releasing their vertices for later clusters; elements touching
fixed vertices (``excluded``) never join or seed a cluster.
"""
import numpy as np
from numba import njit

from skfem_affine import _compile_notice  # noqa: F401 (one stderr line when the cached kernels compile)


def element_adjacency(t):
    """CSR ``(indptr, indices)`` of face-adjacent elements (sharing 3 vertices)."""
    m = t.shape[1]
    faces = np.sort(np.concatenate([t[[1, 2, 3]], t[[0, 2, 3]], t[[0, 1, 3]], t[[0, 1, 2]]], axis=1), axis=0)
    n = np.int64(t.max()) + 1
    key = (faces[0].astype(np.int64) * n + faces[1]) * n + faces[2]
    owner = np.tile(np.arange(m), 4)
    order = np.argsort(key, kind="stable")
    ks, os_ = key[order], owner[order]
    pair = np.flatnonzero(ks[1:] == ks[:-1])
    a, b = os_[pair], os_[pair + 1]
    rows = np.concatenate([a, b])
    cols = np.concatenate([b, a])
    o = np.lexsort((cols, rows))
    rows, cols = rows[o], cols[o]
    indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=m))]).astype(np.int64)
    return indptr, cols.astype(np.int32)


def seed_order(m, strategy, rng=None, previous_seeds=None):
    """Order in which elements seed clusters: "random", "index" or "temporal" (sec. 4.1)."""
    rng = rng if rng is not None else np.random.default_rng(0)
    if strategy == "index":
        return np.arange(m, dtype=np.int64)
    if strategy == "random":
        return rng.permutation(m).astype(np.int64)
    if strategy == "temporal":
        prev = np.asarray(previous_seeds if previous_seeds is not None else [], dtype=np.int64)
        prev = prev[(prev >= 0) & (prev < m)]
        rest = np.setdiff1d(np.arange(m), prev)
        return np.concatenate([prev, rng.permutation(rest)]).astype(np.int64)
    raise ValueError(f"unknown seeding strategy {strategy!r}; use 'random', 'index' or 'temporal'")


def _check(Fdot, tau_a, tau_e):
    for name, tau in (("tau_a", tau_a), ("tau_e", tau_e)):
        if not np.isfinite(tau) or tau < 0:
            raise ValueError(f"threshold {name} must be finite and >= 0, got {tau}")
    F9 = np.ascontiguousarray(np.asarray(Fdot, dtype=float).reshape(-1, 9))
    if not np.all(np.isfinite(F9)):
        raise ValueError("deformation rates contain NaN or inf")
    return F9


def _mask(a, m, default=False):
    if a is None:
        return np.full(m, default)
    a = np.asarray(a, dtype=bool)
    if a.shape != (m,):
        raise ValueError(f"element mask must have shape ({m},), got {a.shape}")
    return a


def cluster_deformation_rates(Fdot, adjacency, t, n_vertices, tau_a, tau_e, was_affine=None, excluded=None,
                              forced=None, seeds=None, return_seeds=False, return_distances=False, min_size=2):
    """Affine clusters by greedy BFS on deformation rates (Algorithm 2).

    Parameters
    ----------
    Fdot : (m, 3, 3) deformation-rate per element (eq. 4).
    adjacency : ``(indptr, indices)`` from :func:`element_adjacency`.
    t : (4, m) element vertices; n_vertices : number of vertices.
    tau_a, tau_e : thresholds (>= 0) for elastic and for previously affine pairs.
    was_affine, excluded, forced : (m,) bool masks (previous frame's affine
        elements; elements that must stay elastic; the resource-limiting set C).
    seeds : element order to start clusters from (default ``arange(m)``).
    min_size : clusters with fewer elements are dissolved (2: singletons, as the paper).

    Returns
    -------
    labels : (m,) int, -1 elastic, else the cluster id (contiguous from 0);
    plus, if asked, the seed of each cluster and, per element, the distance d
    (eq. 6) at which it was accepted (NaN for seeds and elastic elements).
    """
    F9 = _check(Fdot, tau_a, tau_e)
    m = F9.shape[0]
    seeds = np.arange(m, dtype=np.int64) if seeds is None else np.asarray(seeds, dtype=np.int64)
    flags = _flags(m, was_affine=was_affine, excluded=excluded, forced=forced)
    labels, cseeds, dist = _bfs_call(adjacency, t, n_vertices, F9, tau_a, tau_e, flags, seeds, False, min_size,
                                     return_distances)
    out = (labels,)
    if return_seeds:
        out += (cseeds,)
    if return_distances:
        out += (dist,)
    return out[0] if len(out) == 1 else out


def cluster_components(eligible, adjacency, t, n_vertices, excluded=None, seeds=None, min_size=2):
    """Connected components of ``eligible`` elements, vertex-disjoint, smaller than ``min_size`` dissolved.

    The clustering of the rigidification baseline (same kernel and hinge rule).
    """
    m = t.shape[1]
    seeds = np.arange(m, dtype=np.int64) if seeds is None else np.asarray(seeds, dtype=np.int64)
    flags = _flags(m, excluded=excluded, eligible=eligible)
    labels, _, _ = _bfs_call(adjacency, t, n_vertices, np.zeros((m, 9)), 0.0, 0.0, flags, seeds, True, min_size)
    return labels


def forced_set(Fdot, adjacency, fraction):
    """Resource limiting (sec. 3.5): the ``round(fraction m)`` elements with the smallest
    largest deformation-rate difference to a face neighbour, by linear-time selection."""
    fraction = float(fraction)
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"resource limit fraction must lie in [0, 1], got {fraction}")
    F9 = np.asarray(Fdot, dtype=float).reshape(-1, 9)
    m = F9.shape[0]
    k = int(round(fraction * m))
    out = np.zeros(m, dtype=bool)
    if k == 0:
        return out
    if k == m:
        out[:] = True
        return out
    indptr, indices = adjacency
    worst = _worst_neighbour_difference(np.asarray(indptr, dtype=np.int64), np.asarray(indices, dtype=np.int64),
                                        np.ascontiguousarray(F9))
    out[np.argpartition(worst, k - 1)[:k]] = True
    return out


@njit(cache=True)
def _worst_neighbour_difference(indptr, indices, F9):
    """Per element, the largest Frobenius distance of its rate to a face neighbour's (inf: no neighbour)."""
    m = F9.shape[0]
    worst = np.full(m, np.inf)
    for e in range(m):
        if indptr[e + 1] == indptr[e]:
            continue
        w = 0.0
        for k in range(indptr[e], indptr[e + 1]):
            j = indices[k]
            d = 0.0
            for c in range(9):
                t = F9[e, c] - F9[j, c]
                d += t * t
            if d > w:
                w = d
        worst[e] = np.sqrt(w)
    return worst


# per-element flag bits of the BFS (one byte read per neighbour instead of five arrays)
_VISITED, _QUEUED, _EXCLUDED, _WAS_AFFINE, _FORCED, _ELIGIBLE = 1, 2, 4, 8, 16, 32


def _flags(m, was_affine=None, excluded=None, forced=None, eligible=None):
    f = np.zeros(m, dtype=np.uint8)
    for mask, bit in ((was_affine, _WAS_AFFINE), (excluded, _EXCLUDED), (forced, _FORCED), (eligible, _ELIGIBLE)):
        if mask is not None:
            f |= _mask(mask, m).astype(np.uint8) * np.uint8(bit)
    return f


def _bfs_call(adjacency, t, n_vertices, F9, tau_a, tau_e, flags, seeds, by_eligibility, min_size, distances=False):
    """Run :func:`_bfs` with compact arrays: in a frame its data arrive from memory cold (the
    element evaluation streamed tens of MB through the caches), so bytes, not operations, cost."""
    tv = np.ascontiguousarray(np.asarray(t).T, dtype=np.int32)  # (m, 4): 16 bytes per element
    labels, cseeds, dist = _bfs(adjacency[0], adjacency[1].astype(np.int32, copy=False), tv, int(n_vertices), F9,
                                float(tau_a), float(tau_e), flags, seeds, by_eligibility, int(min_size), bool(distances))
    return labels.astype(np.int64), cseeds, dist


@njit(cache=True)
def _bfs(indptr, indices, tv, n_vertices, F, tau_a, tau_e, flags, seeds, by_eligibility, min_size, distances):
    """Algorithm 2 over element-major connectivity ``tv`` (m, 4) and packed ``flags`` (bits above)."""
    m = F.shape[0]
    labels = np.full(m, -1, dtype=np.int32)
    owner = np.full(n_vertices, -1, dtype=np.int32)
    dist = np.full(m if distances else 0, np.nan)
    queue = np.empty(m, dtype=np.int32)
    members = np.empty(m, dtype=np.int32)
    cseeds = np.empty(m, dtype=np.int64)
    fmin = np.empty(9)
    fmax = np.empty(9)
    centre = np.empty(9)
    skip = _VISITED | _QUEUED | _EXCLUDED
    tau_a2, tau_e2 = tau_a * tau_a, tau_e * tau_e
    j = 0
    for s in seeds:
        fs = flags[s]
        if fs & (_VISITED | _EXCLUDED) or (by_eligibility and not fs & _ELIGIBLE):
            continue
        head, tail, size = 0, 1, 0
        queue[0] = s
        flags[s] |= _QUEUED
        for c in range(9):
            fmin[c] = fmax[c] = centre[c] = F[s, c]
        while head < tail:
            e = queue[head]
            head += 1
            flags[e] |= _VISITED
            hinge = False
            for k in range(4):
                o = owner[tv[e, k]]
                if o >= 0 and o != j:
                    hinge = True
            if hinge:
                continue
            labels[e] = j
            members[size] = e
            size += 1
            for c in range(9):
                fmin[c] = min(fmin[c], F[e, c])
                fmax[c] = max(fmax[c], F[e, c])
                centre[c] = 0.5 * (fmin[c] + fmax[c])  # eq. 5
            for k in range(4):
                owner[tv[e, k]] = j
            e_affine = flags[e] & _WAS_AFFINE
            for p in range(indptr[e], indptr[e + 1]):
                nb = indices[p]
                fn = flags[nb]
                if fn & skip:
                    continue
                if by_eligibility:
                    ok = (fn & _ELIGIBLE) != 0
                    d2 = 0.0
                else:
                    tau2 = tau_e2 if (fn & _WAS_AFFINE and e_affine) else tau_a2
                    d2 = 0.0
                    for c in range(9):
                        x = centre[c] - F[nb, c]
                        d2 += x * x
                    ok = d2 < tau2 or (fn & _FORCED) != 0  # eq. 6, squared
                if ok:
                    flags[nb] |= _QUEUED
                    if distances:
                        dist[nb] = np.sqrt(d2)
                    queue[tail] = nb
                    tail += 1
        for q in range(tail):  # elements rejected later in this BFS may join another cluster
            flags[queue[q]] &= ~np.uint8(_QUEUED)
        if size < min_size:
            for q in range(size):
                e = members[q]
                labels[e] = -1
                for k in range(4):
                    owner[tv[e, k]] = -1
        elif size > 0:
            cseeds[j] = s
            j += 1
    if distances:
        for e in range(m):
            if labels[e] < 0:
                dist[e] = np.nan
    return labels, cseeds[:j].copy(), dist
