"""The largest mutually consistent set of correspondences: a maximum clique.

Pairwise consistency maximisation (PCM, Mangelson, Dominic, Eustice & Vasudevan, "Pairwise
Consistency Maximization for Robust Multi-Robot Map Merging", ICRA 2018) turns a set of candidate
correspondences into a graph — one vertex per candidate, an edge between two candidates that are
consistent with each other — and keeps its maximum clique. PCM finds it with the solver of
Pattabiraman et al. ("Fast algorithms for the maximum clique problem on massive graphs with
applications to overlapping community detection", Internet Mathematics 2015): a greedy heuristic
gives a lower bound that prunes every vertex of smaller degree, then an exact branch and bound
runs on what is left. :func:`maximum_clique` does the same: the heuristic of Pattabiraman et al.
(grow a clique from each vertex, always adding the candidate with the most neighbours among the
remaining candidates) and an exact search with the greedy-colouring bound of Tomita & Seki
("An efficient branch-and-bound algorithm for finding a maximum clique", DMTCS 2003) over bit sets
of 64-bit words, compiled with numba (depth first, an explicit stack of search nodes), under a
budget of search nodes; when the budget runs out the best clique found so far is returned and
flagged as not proven maximum.

Everything is deterministic: ties are broken by vertex index, so the same graph always gives the
same clique.
"""

from __future__ import annotations

import numba
import numpy as np

from teamslam.errors import InputError

__all__ = ["maximum_clique"]


@numba.njit(cache=True)
def _greedy(
    adjacency: np.ndarray, rank: np.ndarray, start: int, floor: int, work: np.ndarray
) -> np.ndarray:
    """A clique grown from ``start``: add candidates in order of degree (Pattabiraman et al.);
    empty when it cannot grow beyond ``floor``. ``work`` is scratch of ``rank``'s size."""
    n = 0
    for u in rank:  # neighbours of start, highest degree first
        if adjacency[start, u]:
            work[n] = u
            n += 1
    clique = [start]
    head = 0
    while head < n:
        v = work[head]
        clique.append(v)
        kept = 0
        for i in range(head + 1, n):
            if adjacency[v, work[i]]:
                work[head + 1 + kept] = work[i]
                kept += 1
        head += 1
        n = head + kept
        if len(clique) + kept <= floor:
            return np.empty(0, dtype=np.int64)  # cannot beat the best any more
    return np.sort(np.array(clique, dtype=np.int64))


# a de Bruijn sequence: the top 6 bits of (lowest set bit × it) name the bit's index
_DEBRUIJN = 0x03F79D71B4CB0A89
_DEBRUIJN_INDEX = np.zeros(64, dtype=np.int64)
_DEBRUIJN_INDEX[[((_DEBRUIJN << i) & (2**64 - 1)) >> 58 for i in range(64)]] = np.arange(64)


@numba.njit(cache=True)
def _lowest(word: np.uint64, table: np.ndarray) -> int:
    """Index of the lowest set bit of a non-zero word."""
    low = word & (~word + np.uint64(1))
    return table[(low * np.uint64(0x03F79D71B4CB0A89)) >> np.uint64(58)]


@numba.njit(cache=True)
def _colour_order(
    p: np.ndarray, bits: np.ndarray, order: np.ndarray, colours: np.ndarray, table: np.ndarray
) -> int:
    """Greedy colouring of the vertex set ``p`` (a bit set of words): colour classes one after
    another, each grown from the lowest uncoloured vertex; writes the vertices in colour order
    and their colours, returns how many."""
    words = p.size
    uncoloured = p.copy()
    q = np.empty(words, dtype=np.uint64)
    n = 0
    colour = 0
    first = 0  # lowest word of `uncoloured` that may be non-zero
    while True:
        while first < words and uncoloured[first] == 0:
            first += 1
        if first == words:
            return n
        colour += 1
        q[:] = uncoloured
        w = first
        while True:
            while w < words and q[w] == 0:
                w += 1
            if w == words:
                break
            v = 64 * w + _lowest(q[w], table)
            for x in range(words):
                q[x] &= ~bits[v, x]
            bit = np.uint64(1) << np.uint64(v - 64 * w)
            q[w] &= ~bit
            uncoloured[w] &= ~bit
            order[n] = v
            colours[n] = colour
            n += 1


@numba.njit(cache=True)
def _branch_and_bound(
    bits: np.ndarray, m: int, budget: int, floor: int, table: np.ndarray, degree: int
) -> tuple[np.ndarray, bool]:
    """Tomita & Seki's branch and bound over bit sets, depth first in colour order.

    ``degree`` is the largest degree of the graph: no clique is larger than ``degree + 1``,
    which bounds the depth of the search. Returns the largest clique found above ``floor``
    (empty when none) and whether the search finished within ``budget`` search nodes.
    """
    words = bits.shape[1]
    depth = min(m, degree + 1) + 1
    sets = np.zeros((depth, words), dtype=np.uint64)
    order = np.empty((depth, m), dtype=np.int64)
    colours = np.empty((depth, m), dtype=np.int64)
    size = np.zeros(depth, dtype=np.int64)
    k = np.zeros(depth, dtype=np.int64)
    clique = np.empty(depth, dtype=np.int64)
    best = np.empty(0, dtype=np.int64)
    best_size = floor
    for v in range(m):
        sets[0, v // 64] |= np.uint64(1) << np.uint64(v % 64)
    nodes = 1
    if nodes > budget:
        return best, False
    size[0] = _colour_order(sets[0], bits, order[0], colours[0], table)
    k[0] = size[0] - 1
    d = 0
    while d >= 0:
        if k[d] < 0 or d + colours[d, k[d]] <= best_size:
            # this node is done: back to its parent, which drops the vertex it tried
            d -= 1
            if d >= 0:
                v = clique[d]
                sets[d, v // 64] &= ~(np.uint64(1) << np.uint64(v % 64))
                k[d] -= 1
            continue
        v = order[d, k[d]]
        clique[d] = v
        empty = True
        for x in range(words):
            sets[d + 1, x] = sets[d, x] & bits[v, x]
            if sets[d + 1, x] != 0:
                empty = False
        if empty:
            if d + 1 > best_size:
                best_size = d + 1
                best = clique[: d + 1].copy()
            sets[d, v // 64] &= ~(np.uint64(1) << np.uint64(v % 64))
            k[d] -= 1
            continue
        nodes += 1
        if nodes > budget:
            return best, False
        d += 1
        size[d] = _colour_order(sets[d], bits, order[d], colours[d], table)
        k[d] = size[d] - 1
    return best, True


def maximum_clique(
    adjacency: np.ndarray, budget: int = 20_000, lower_bound: int = 0, starts: int = 24
) -> tuple[np.ndarray, bool]:
    """A maximum clique of an undirected graph.

    Parameters
    ----------
    adjacency
        ``(m, m)`` boolean symmetric matrix with a false diagonal.
    starts
        Vertices (of the highest degree) the greedy heuristic grows a clique from.
    budget
        Search nodes the exact branch and bound may visit before it stops and returns the best
        clique found so far.
    lower_bound
        Cliques no larger than this are not of interest: the search may return an empty clique
        when it finds nothing larger.

    Returns
    -------
    clique, exact
        Sorted vertex indices, and whether the clique is proven maximum (the search finished
        within its budget).
    """
    adjacency = np.asarray(adjacency, dtype=bool)
    if adjacency.ndim != 2 or adjacency.shape[0] != adjacency.shape[1]:
        raise InputError(f"maximum_clique needs a square adjacency matrix, got {adjacency.shape}")
    # the compiled search sizes its stack by the degrees: a self-loop or a one-sided edge
    # would let it descend past it
    if adjacency.diagonal().any():
        raise InputError("maximum_clique needs an adjacency matrix with a false diagonal")
    if not np.array_equal(adjacency, adjacency.T):
        raise InputError("maximum_clique needs a symmetric adjacency matrix")
    clique, exact = _maximum_clique(
        np.ascontiguousarray(adjacency), int(budget), int(lower_bound), int(starts), _DEBRUIJN_INDEX
    )
    return clique, bool(exact)


@numba.njit(cache=True)
def _maximum_clique(
    adjacency: np.ndarray, budget: int, lower_bound: int, starts: int, table: np.ndarray
) -> tuple[np.ndarray, bool]:
    """:func:`maximum_clique` compiled: the heuristic, the peeling, the exact search."""
    m = adjacency.shape[0]
    if m == 0:
        return np.zeros(0, dtype=np.int64), True
    degree = np.zeros(m, dtype=np.int64)
    for i in range(m):
        for j in range(i + 1, m):
            if adjacency[i, j]:
                degree[i] += 1
                degree[j] += 1
    best = np.empty(0, dtype=np.int64)
    if lower_bound < 1:
        best = np.array([np.argmax(degree)], dtype=np.int64)
    # heuristic: grow a clique from each vertex that could still beat the best (high degree first)
    rank = np.argsort(-degree, kind="mergesort")  # highest degree first, ties by index
    work = np.empty(m, dtype=np.int64)
    for v in rank[:starts]:
        size = max(best.size, lower_bound)
        if degree[v] < size:  # a vertex in a larger clique has at least `size` neighbours
            break
        clique = _greedy(adjacency, rank[degree[rank] >= size], v, size, work)
        if clique.size > best.size:
            best = clique
    # exact search on the vertices that could be in a larger clique
    floor = max(best.size, lower_bound)
    # peel to the floor-core: a vertex of a larger clique has ≥ floor neighbours in that core
    # (the floor-core is unique: vertices are removed one at a time, their neighbours' counts
    # of live neighbours updated)
    alive = degree >= floor
    inner = np.zeros(m, dtype=np.int64)
    for i in range(m):
        if alive[i]:
            for j in range(m):
                inner[j] += adjacency[i, j]
    stack = [i for i in range(m) if alive[i] and inner[i] < floor]
    for i in stack:
        alive[i] = False
    while stack:
        i = stack.pop()
        for j in range(m):
            if adjacency[i, j]:
                inner[j] -= 1
                if alive[j] and inner[j] < floor:
                    alive[j] = False
                    stack.append(j)
    keep = np.flatnonzero(alive)
    if keep.size <= floor:
        return best, True
    # row i as the bit set of its neighbours, in 64-bit words
    words = (keep.size + 63) // 64
    bits = np.zeros((keep.size, words), dtype=np.uint64)
    for i in range(keep.size):
        for j in range(keep.size):
            if adjacency[keep[i], keep[j]]:
                bits[i, j // 64] |= np.uint64(1) << np.uint64(j % 64)
    found, done = _branch_and_bound(bits, keep.size, budget, floor, table, inner[keep].max())
    if found.size > best.size:
        best = np.sort(keep[found])
    return best, done
