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
("An efficient branch-and-bound algorithm for finding a maximum clique", DMTCS 2003) over Python
integer bit sets, under a budget of search nodes; when the budget runs out the best clique found
so far is returned and flagged as not proven maximum.

Everything is deterministic: ties are broken by vertex index, so the same graph always gives the
same clique.
"""

from __future__ import annotations

import numpy as np

__all__ = ["maximum_clique"]


def _greedy(adjacency: np.ndarray, rank: np.ndarray, start: int, floor: int) -> list[int]:
    """A clique grown from ``start``: add candidates in order of degree (Pattabiraman et al.)."""
    clique = [start]
    candidates = rank[adjacency[start, rank]]  # neighbours of start, highest degree first
    while candidates.size:
        v = int(candidates[0])
        clique.append(v)
        candidates = candidates[1:][adjacency[v, candidates[1:]]]
        if len(clique) + candidates.size <= floor:
            return []  # cannot beat the best any more
    return sorted(clique)


def _colour_order(p: int, bits: list[int]) -> tuple[list[int], list[int]]:
    """Greedy colouring of the vertex set ``p``: vertices in colour order and their colours."""
    order: list[int] = []
    colours: list[int] = []
    colour = 0
    uncoloured = p
    while uncoloured:
        colour += 1
        q = uncoloured
        while q:
            low = q & -q
            v = low.bit_length() - 1
            q &= ~low
            q &= ~bits[v]
            uncoloured &= ~low
            order.append(v)
            colours.append(colour)
    return order, colours


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
    m = adjacency.shape[0]
    if m == 0:
        return np.zeros(0, dtype=np.int64), True
    degree = adjacency.sum(axis=1)
    best: list[int] = [int(np.argmax(degree))] if lower_bound < 1 else []
    # heuristic: grow a clique from each vertex that could still beat the best (high degree first)
    rank = np.lexsort((np.arange(m), -degree))  # highest degree first, ties by index
    for v in rank[:starts]:
        size = max(len(best), lower_bound)
        if degree[v] < size:  # a vertex in a larger clique has at least `size` neighbours
            break
        clique = _greedy(adjacency, rank[degree[rank] >= size], int(v), size)
        if len(clique) > len(best):
            best = clique
    # exact search on the vertices that could be in a larger clique
    floor = max(len(best), lower_bound)
    # peel to the floor-core: a vertex of a larger clique has ≥ floor neighbours in that core
    alive = degree >= floor
    while True:
        inner = np.count_nonzero(adjacency[:, alive], axis=1)
        peeled = alive & (inner >= floor)
        if np.array_equal(peeled, alive):
            break
        alive = peeled
    keep = np.flatnonzero(alive)
    if keep.size <= floor:
        return np.asarray(best, dtype=np.int64), True
    sub = adjacency[np.ix_(keep, keep)]
    packed = np.packbits(sub, axis=1, bitorder="little")  # row i as the bit set of its neighbours
    bits = [int.from_bytes(row.tobytes(), "little") for row in packed]
    state: dict = {"best": [], "nodes": 0}
    best_size = [max(len(best), lower_bound)]
    exhausted = [False]

    def expand(clique: list[int], p: int) -> None:
        if exhausted[0]:
            return
        state["nodes"] += 1
        if state["nodes"] > budget:
            exhausted[0] = True
            return
        order, colours = _colour_order(p, bits)
        for k in range(len(order) - 1, -1, -1):
            if len(clique) + colours[k] <= best_size[0]:
                return
            v = order[k]
            new_p = p & bits[v]
            clique.append(v)
            if new_p:
                expand(clique, new_p)
            elif len(clique) > best_size[0]:
                best_size[0] = len(clique)
                state["best"] = list(clique)
            clique.pop()
            p &= ~(1 << v)
            if exhausted[0]:
                return

    expand([], (1 << keep.size) - 1)
    found = state["best"]
    if len(found) > len(best):
        best = sorted(int(keep[i]) for i in found)
    return np.asarray(sorted(best), dtype=np.int64), not exhausted[0]
