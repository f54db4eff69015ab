"""Communication graphs and their doubly-stochastic consensus weights.

Robot ``i`` talks to its one-hop neighbours in an undirected graph (distributed-MSCKF paper,
§III), weighted by Metropolis–Hastings weights ``Aᵢⱼ = 1 / (1 + max(dᵢ, dⱼ))``,
``Aᵢᵢ = 1 − Σⱼ Aᵢⱼ``: symmetric, non-negative and doubly stochastic on any undirected graph, and
computable by each robot from the two degrees of an edge. Communication loss (§VI-B) removes
each edge with probability ``r`` at each step and the weights are recomputed on the surviving
edges (:class:`EdgeLoss`).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from teamslam.errors import InputError

__all__ = [
    "GRAPH_KINDS",
    "CommunicationGraph",
    "EdgeLoss",
    "complete",
    "drop_edges",
    "from_edges",
    "make",
    "metropolis_weight",
    "metropolis_weights",
    "path",
    "random_geometric",
    "ring",
    "star",
]


@dataclass(frozen=True)
class CommunicationGraph:
    """An undirected communication graph over robots ``0 .. n-1``.

    Attributes
    ----------
    adjacency
        ``(n, n)`` symmetric boolean matrix, ``False`` on the diagonal.
    name
        A short description (``"ring(5)"``).
    """

    adjacency: np.ndarray
    name: str = "graph"

    def __post_init__(self) -> None:
        adjacency = np.asarray(self.adjacency)
        if adjacency.ndim != 2 or adjacency.shape[0] != adjacency.shape[1]:
            raise InputError(f"adjacency must be square, got shape {adjacency.shape}")
        if adjacency.shape[0] < 1:
            raise InputError("a communication graph needs at least one robot")
        adjacency = adjacency.astype(bool)
        if not np.array_equal(adjacency, adjacency.T):
            raise InputError("adjacency must be symmetric (communication is two-way)")
        if np.any(np.diag(adjacency)):
            raise InputError("adjacency must have no self-loops")
        adjacency.setflags(write=False)
        object.__setattr__(self, "adjacency", adjacency)

    @property
    def n(self) -> int:
        """Number of robots."""
        return self.adjacency.shape[0]

    @property
    def edges(self) -> list[tuple[int, int]]:
        """Undirected edges ``(i, j)`` with ``i < j``."""
        i, j = np.nonzero(np.triu(self.adjacency))
        return [(int(a), int(b)) for a, b in zip(i, j, strict=True)]

    def neighbours(self, robot: int) -> list[int]:
        """One-hop neighbours of ``robot``, excluding itself."""
        return [int(j) for j in np.flatnonzero(self.adjacency[robot])]

    def degrees(self) -> np.ndarray:
        """Degree of every robot."""
        return self.adjacency.sum(axis=1)

    def is_connected(self) -> bool:
        """Whether every robot can reach every other one."""
        return _is_connected(self.adjacency)

    def weights(self) -> np.ndarray:
        """Metropolis–Hastings weights of this graph (no loss)."""
        return metropolis_weights(self.adjacency)


def _is_connected(adjacency: np.ndarray) -> bool:
    n = adjacency.shape[0]
    reached = np.zeros(n, dtype=bool)
    reached[0] = True
    frontier = reached.copy()
    while frontier.any():
        frontier = adjacency[frontier].any(axis=0) & ~reached
        reached |= frontier
    return bool(reached.all())


def metropolis_weight(degree_i, degree_j):
    """``A_ij = 1 / (1 + max(d_i, d_j))`` for a link between robots of degrees ``d_i``, ``d_j``.

    The one place the weight is written: :func:`metropolis_weights` applies it to a whole
    graph; scalars or arrays (broadcast) are accepted.
    """
    return 1.0 / (1.0 + np.maximum(degree_i, degree_j))


def metropolis_weights(adjacency: np.ndarray) -> np.ndarray:
    """Doubly-stochastic Metropolis–Hastings weights of an undirected graph.

    Parameters
    ----------
    adjacency
        ``(n, n)`` symmetric boolean adjacency without self-loops.

    Returns
    -------
    numpy.ndarray
        ``(n, n)`` symmetric, non-negative matrix whose rows and columns sum to one, positive
        exactly on the edges and the diagonal (an isolated robot gets weight 1 on itself).
    """
    adjacency = np.asarray(adjacency, dtype=bool)
    degree = adjacency.sum(axis=1)
    weights = np.where(adjacency, metropolis_weight(degree[:, None], degree[None, :]), 0.0)
    np.fill_diagonal(weights, 1.0 - weights.sum(axis=1))
    return weights


def drop_edges(adjacency: np.ndarray, rate: float, rng: np.random.Generator) -> np.ndarray:
    """Remove each undirected edge independently with probability ``rate``."""
    if not 0.0 <= rate <= 1.0:
        raise InputError(f"loss rate must lie in [0, 1], got {rate}")
    adjacency = np.asarray(adjacency, dtype=bool)
    keep = np.triu(rng.random(adjacency.shape) >= rate, k=1)
    keep = keep | keep.T
    return adjacency & keep


class EdgeLoss:
    """Per-step random edge loss on a graph, reproducible from a seed.

    Each call of :meth:`step` draws which edges survive this step (each lost independently
    with probability ``rate``) and returns the surviving adjacency with its recomputed
    Metropolis weights. With ``rate = 0`` the graph's own weights come back every step.

    Parameters
    ----------
    graph
        The full communication graph.
    rate
        Loss probability ``r`` of each edge at each step, in ``[0, 1]``.
    seed
        Seed or generator for the loss draws.
    """

    def __init__(
        self,
        graph: CommunicationGraph,
        rate: float,
        seed: int | np.random.Generator | None = None,
    ) -> None:
        if not 0.0 <= rate <= 1.0:
            raise InputError(f"loss rate must lie in [0, 1], got {rate}")
        self.graph = graph
        self.rate = float(rate)
        self.rng = np.random.default_rng(seed)

    def step(self) -> tuple[np.ndarray, np.ndarray]:
        """Surviving adjacency and its doubly-stochastic weights for the next step."""
        if self.rate == 0.0:
            active = self.graph.adjacency.copy()
        else:
            active = drop_edges(self.graph.adjacency, self.rate, self.rng)
        return active, metropolis_weights(active)

    def __iter__(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        while True:
            yield self.step()


def from_edges(
    n: int, edges: Iterable[tuple[int, int]], name: str | None = None
) -> CommunicationGraph:
    """Graph over ``n`` robots from an undirected edge list."""
    if n < 1:
        raise InputError(f"number of robots must be positive, got {n}")
    adjacency = np.zeros((n, n), dtype=bool)
    for edge in edges:
        a, b = (int(v) for v in edge)
        if not (0 <= a < n and 0 <= b < n):
            raise InputError(f"edge ({a}, {b}) names a robot outside 0..{n - 1}")
        if a == b:
            raise InputError(f"edge ({a}, {b}) is a self-loop")
        adjacency[a, b] = adjacency[b, a] = True
    return CommunicationGraph(adjacency, name or f"edges({n})")


def complete(n: int) -> CommunicationGraph:
    """Every robot talks to every other robot."""
    if n < 1:
        raise InputError(f"number of robots must be positive, got {n}")
    return CommunicationGraph(~np.eye(n, dtype=bool), f"complete({n})")


def path(n: int) -> CommunicationGraph:
    """Robots in a line: i talks to i ± 1."""
    return from_edges(n, [(i, i + 1) for i in range(n - 1)], f"path({n})")


def ring(n: int) -> CommunicationGraph:
    """Robots in a cycle (a path for n ≤ 2)."""
    edges = [(i, (i + 1) % n) for i in range(n)] if n > 2 else [(i, i + 1) for i in range(n - 1)]
    return from_edges(n, edges, f"ring({n})")


def star(n: int, centre: int = 0) -> CommunicationGraph:
    """One hub robot talks to all the others."""
    if not 0 <= centre < n:
        raise InputError(f"star centre {centre} outside 0..{n - 1}")
    return from_edges(n, [(centre, j) for j in range(n) if j != centre], f"star({n})")


def random_geometric(
    n: int,
    radius: float | None = None,
    seed: int | np.random.Generator | None = None,
    max_tries: int = 1000,
) -> CommunicationGraph:
    """Random geometric graph: robots uniform in the unit square, linked within ``radius``.

    Redraws until the graph is connected. The default radius ``sqrt(2 ln n / n)`` (at least
    0.5) makes a connected draw likely for every ``n``.
    """
    if n < 1:
        raise InputError(f"number of robots must be positive, got {n}")
    if radius is None:
        radius = max(0.5, float(np.sqrt(2.0 * np.log(max(n, 2)) / n)))
    if radius <= 0:
        raise InputError(f"radius must be positive, got {radius}")
    rng = np.random.default_rng(seed)
    for _ in range(max_tries):
        points = rng.random((n, 2))
        distance = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=-1)
        adjacency = (distance <= radius) & ~np.eye(n, dtype=bool)
        if _is_connected(adjacency):
            return CommunicationGraph(adjacency, f"random_geometric({n}, r={radius:.3g})")
    raise InputError(
        f"no connected random geometric graph with radius {radius} in {max_tries} draws"
    )


GRAPH_KINDS = ("complete", "ring", "path", "star", "random")


def make(kind: str, n: int, seed: int | None = None) -> CommunicationGraph:
    """Graph by name: one of :data:`GRAPH_KINDS`."""
    if kind == "complete":
        return complete(n)
    if kind == "ring":
        return ring(n)
    if kind == "path":
        return path(n)
    if kind == "star":
        return star(n)
    if kind == "random":
        return random_geometric(n, seed=seed)
    raise InputError(f"unknown graph kind {kind!r}; choose one of {', '.join(GRAPH_KINDS)}")
