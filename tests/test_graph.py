"""Communication graphs and Metropolis weights."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teamslam import graph


def assert_doubly_stochastic(w: np.ndarray, adjacency: np.ndarray) -> None:
    np.testing.assert_allclose(w, w.T, atol=1e-15)
    assert np.all(w >= 0)
    np.testing.assert_allclose(w.sum(axis=0), 1.0, atol=1e-12)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    off = ~np.eye(len(w), dtype=bool)
    # positive exactly on the edges
    np.testing.assert_array_equal(w[off] > 0, adjacency[off])
    assert np.all(np.diag(w) > 0)


@given(st.integers(1, 25), st.integers(0, 2**31), st.floats(0.0, 1.0))
@settings(max_examples=150, deadline=None)
def test_metropolis_on_random_graphs_with_and_without_loss(n, seed, rate):
    g = graph.random_geometric(n, seed=seed)
    assert g.is_connected()
    assert_doubly_stochastic(g.weights(), g.adjacency)
    loss = graph.EdgeLoss(g, rate, seed=seed)
    for _ in range(3):
        active, w = loss.step()
        assert not np.any(active & ~g.adjacency)  # loss only removes edges
        np.testing.assert_array_equal(active, active.T)
        assert_doubly_stochastic(w, active)


@pytest.mark.parametrize(
    ("maker", "degrees"),
    [
        (graph.complete, [4, 4, 4, 4, 4]),
        (graph.ring, [2, 2, 2, 2, 2]),
        (graph.path, [1, 2, 2, 2, 1]),
        (graph.star, [4, 1, 1, 1, 1]),
    ],
)
def test_named_graphs(maker, degrees):
    g = maker(5)
    np.testing.assert_array_equal(g.degrees(), degrees)
    assert g.is_connected()
    assert_doubly_stochastic(g.weights(), g.adjacency)


def test_complete_graph_weights_are_uniform():
    np.testing.assert_allclose(graph.complete(3).weights(), np.full((3, 3), 1 / 3))


def test_loss_rate_is_respected_and_seeded():
    g = graph.complete(10)
    loss = graph.EdgeLoss(g, 0.3, seed=7)
    kept = np.mean([loss.step()[0][np.triu_indices(10, 1)].mean() for _ in range(400)])
    assert kept == pytest.approx(0.7, abs=0.01)
    a = [graph.EdgeLoss(g, 0.5, seed=3).step()[0] for _ in range(2)]
    np.testing.assert_array_equal(a[0], a[1])
    full, w = graph.EdgeLoss(g, 1.0, seed=0).step()
    assert not full.any()
    np.testing.assert_allclose(w, np.eye(10))


def test_from_edges_and_errors():
    g = graph.from_edges(4, [(0, 1), (1, 2)])
    assert not g.is_connected()
    assert g.neighbours(1) == [0, 2]
    assert g.edges == [(0, 1), (1, 2)]
    with pytest.raises(ValueError, match="outside"):
        graph.from_edges(3, [(0, 3)])
    with pytest.raises(ValueError, match="self-loop"):
        graph.from_edges(3, [(1, 1)])
    with pytest.raises(ValueError, match="symmetric"):
        graph.CommunicationGraph(np.array([[0, 1], [0, 0]]))
    with pytest.raises(ValueError, match="loss rate"):
        graph.EdgeLoss(g, 1.5)
    with pytest.raises(ValueError, match="unknown graph kind"):
        graph.make("mesh", 3)
