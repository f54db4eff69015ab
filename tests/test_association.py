"""Association of two robots' objects without shared ids: consistency, drift, symmetry, no guess."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam.association import (
    AssociationSettings,
    CorrespondenceTable,
    ObjectSummary,
    associate,
    consistency_graph,
    fit_transform,
    flipped,
    maximum_clique,
    pair_innovation_consistent,
    score_correspondences,
)
from teamslam.association.candidates import _neighbourhoods, neighbourhood_sets, select_candidates
from teamslam.association.distances import nearest_neighbours, pair_distances
from teamslam.association.gate import frame_scale
from teamslam.association.kernels import (
    consistent_pairs,
    gathered_objects,
    shared_neighbourhood,
)
from teamslam.errors import InputError
from teamslam.geometry import so3

SIGMA = 0.1


def _scene(rng: np.random.Generator, n: int, extent: float = 120.0, spacing: float = 4.0):
    """``n`` objects on the ground spread over ``extent`` metres, at least ``spacing`` apart."""
    points = []
    while len(points) < n:
        p = np.array([*rng.uniform(0, extent, 2), rng.uniform(0, 2)])
        if all(np.linalg.norm(p - q) >= spacing for q in points):
            points.append(p)
    return np.array(points)


def _pose(yaw_deg: float, shift) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = so3.exp(np.array([0.0, 0.0, np.deg2rad(yaw_deg)]))
    t[:3, 3] = shift
    return t


def _summary(robot, ids, truth, rng, T_map_world=None, sigma=SIGMA):
    means = truth + rng.normal(0, sigma, truth.shape)
    covs = np.repeat((sigma**2 * np.eye(3))[None], len(ids), axis=0)
    s = ObjectSummary(robot, ids, means, covs)
    return s if T_map_world is None else s.transformed(T_map_world)


def _two_maps(seed=0, shared=40, own=20, yaw=0.0, shift=(0.0, 0.0, 0.0)):
    """Two robots' summaries over one scene; ids unrelated; truth: own id → object index."""
    rng = np.random.default_rng(seed)
    world = _scene(rng, shared + 2 * own)
    in_a = np.arange(0, shared + own)
    in_b = np.concatenate([np.arange(shared), np.arange(shared + own, shared + 2 * own)])
    ids_a = rng.permutation(1000)[: in_a.size] + 5000
    ids_b = rng.permutation(1000)[: in_b.size] + 9000
    a = _summary(1, ids_a, world[in_a], rng)
    b = _summary(2, ids_b, world[in_b], rng, _pose(yaw, shift))
    return a, b, (ids_a, in_a), (ids_b, in_b)


def test_pairwise_consistency_of_a_known_configuration():
    rng = np.random.default_rng(1)
    pts = np.array([[0.0, 0, 0], [10, 0, 0], [0, 20, 0], [30, 30, 1]])
    covs = np.repeat((0.01 * np.eye(3))[None], 4, axis=0)
    moved = pts @ so3.exp(np.array([0.1, -0.2, 0.7])).T + [5.0, -3.0, 2.0]
    geo_a = pair_distances(pts, covs)
    geo_b = pair_distances(moved + rng.normal(0, 0.01, moved.shape), covs)
    settings = AssociationSettings(drift_ratio=0.0)
    # candidates: the four true pairs, and object 0 wrongly paired with 3
    ia = np.array([0, 1, 2, 3, 0])
    ib = np.array([0, 1, 2, 3, 3])
    graph = consistency_graph(ia, ib, geo_a, geo_b, settings)
    assert graph[:4, :4].sum() == 12  # every two true pairs are consistent
    assert not graph[4, 1] and not graph[4, 2]  # |0-1| = 10 vs |3-1| ≈ 36: inconsistent
    assert not graph[4, 0] and not graph[4, 3]  # pairs sharing an object never are
    assert np.array_equal(graph, graph.T)
    clique, exact = maximum_clique(graph)
    assert exact and clique.tolist() == [0, 1, 2, 3]


def test_drift_allowance_is_relative_to_distance():
    pts = np.array([[0.0, 0, 0], [100.0, 0, 0]])
    covs = np.repeat((1e-4 * np.eye(3))[None], 2, axis=0)
    stretched = pts * 1.02  # a 2 % deformation
    geo_a, geo_b = pair_distances(pts, covs), pair_distances(stretched, covs)
    ia = ib = np.array([0, 1])
    strict = consistency_graph(ia, ib, geo_a, geo_b, AssociationSettings(drift_ratio=0.0))
    loose = consistency_graph(ia, ib, geo_a, geo_b, AssociationSettings(drift_ratio=0.02))
    assert not strict[0, 1] and loose[0, 1]


def test_compiled_loops_equal_the_formulas_in_numpy():
    # the consistency test and the neighbourhood comparison, written out in numpy (float32 as
    # the compiled loops): the same booleans and the same counts, on maps of random size
    rng = np.random.default_rng(4)
    quarter, chi2 = np.float32(0.25 * 0.05**2), np.float32(6.63)
    a, b = _scene(rng, 30), _scene(rng, 25)
    geo_a = tuple(
        x.astype(np.float32) for x in pair_distances(a, np.tile(0.3 * np.eye(3), (30, 1, 1)))
    )
    geo_b = tuple(
        x.astype(np.float32) for x in pair_distances(b, np.tile(0.2 * np.eye(3), (25, 1, 1)))
    )
    ia, ib = rng.integers(0, 30, 400), rng.integers(0, 25, 400)
    d1, d2 = geo_a[0][np.ix_(ia, ia)], geo_b[0][np.ix_(ib, ib)]
    var = geo_a[1][np.ix_(ia, ia)] + geo_b[1][np.ix_(ib, ib)] + quarter * (d1 + d2) ** 2
    expected = ((d1 - d2) ** 2 <= chi2 * var) & (ia[:, None] != ia) & (ib[:, None] != ib)
    graph = consistent_pairs(ia, ib, *geo_a, *geo_b, quarter, chi2)
    assert expected.any() and not expected.all()
    assert np.array_equal(graph, expected)
    near_a, near_b = nearest_neighbours(geo_a[0], 6), nearest_neighbours(geo_b[0], 6)
    allowed = rng.random((30, 25)) < 0.8
    members = np.full((30, 25, 6), -1, dtype=np.int16)
    count, _ = shared_neighbourhood(
        *_neighbourhoods(geo_a, 6), *_neighbourhoods(geo_b, 6), allowed, quarter, chi2, members
    )

    def agree(d1, v1, d2, v2):
        return (d1 - d2) ** 2 <= chi2 * (v1 + v2 + quarter * (d1 + d2) ** 2)

    for x, y in zip(*np.nonzero(allowed), strict=True):
        da, va = geo_a[0][x, near_a[x]], geo_a[1][x, near_a[x]]
        db, vb = geo_b[0][y, near_b[y]], geo_b[1][y, near_b[y]]
        z = (da[:, None] - db[None]) ** 2 / (
            va[:, None] + vb[None] + quarter * (da[:, None] + db[None]) ** 2
        )
        matches = sorted(zip(*np.nonzero(z <= chi2), strict=True), key=lambda p: z[p])
        ends = [(near_a[x, i], near_b[y, j]) for i, j in matches]
        fits = np.array(
            [
                [
                    a1 != a2
                    and b1 != b2
                    and agree(
                        geo_a[0][a1, a2], geo_a[1][a1, a2], geo_b[0][b1, b2], geo_b[1][b1, b2]
                    )
                    for a2, b2 in ends
                ]
                for a1, b1 in ends
            ]
        ).reshape(len(ends), len(ends))
        chosen = []
        for p in np.argsort(-fits.sum(axis=1), kind="stable"):
            if all(fits[p, q] for q in chosen):
                chosen.append(p)
        assert count[x, y] == len(chosen)
        if len(chosen) >= 2:  # the set's members, in the order they were taken
            taken = [matches[p][0] * 6 + matches[p][1] for p in chosen][:6]
            assert members[x, y, : len(taken)].tolist() == taken
            assert (members[x, y, len(taken) :] == -1).all()
    assert count[~allowed].max() == 0 and count.max() >= 3


def test_compiled_search_and_test_refuse_what_they_cannot_read():
    # the compiled loops read without bounds checks: bad input is refused before them, by name
    loop = np.zeros((4, 4), dtype=bool)
    loop[1, 1] = True
    with pytest.raises(InputError, match="false diagonal"):
        maximum_clique(loop)
    one_sided = np.zeros((4, 4), dtype=bool)
    one_sided[0, 2] = True
    with pytest.raises(InputError, match="symmetric"):
        maximum_clique(one_sided)
    rng = np.random.default_rng(1)
    a, b = _scene(rng, 6), _scene(rng, 5)
    geo_a = pair_distances(a, np.tile(0.3 * np.eye(3), (6, 1, 1)))
    geo_b = pair_distances(b, np.tile(0.3 * np.eye(3), (5, 1, 1)))
    settings = AssociationSettings()
    good = consistency_graph(np.array([0, 1]), np.array([0, 1]), geo_a, geo_b, settings)
    assert good.shape == (2, 2)
    with pytest.raises(InputError, match="ib has an index outside"):
        consistency_graph(np.array([0, 1]), np.array([0, 5]), geo_a, geo_b, settings)
    with pytest.raises(InputError, match="differ in length"):
        consistency_graph(np.array([0, 1]), np.array([0]), geo_a, geo_b, settings)
    with pytest.raises(InputError, match="integer indices"):
        consistency_graph(np.array([0.0, 1.0]), np.array([0, 1]), geo_a, geo_b, settings)
    with pytest.raises(InputError, match="square"):
        consistency_graph(np.array([0]), np.array([0]), (geo_a[0][:3], geo_a[1]), geo_b, settings)


def test_maximum_clique_is_exact_on_a_planted_clique():
    rng = np.random.default_rng(3)
    m = 60
    adj = rng.random((m, m)) < 0.2
    adj = np.triu(adj, 1)
    adj = adj | adj.T
    planted = np.sort(rng.choice(m, 12, replace=False))
    adj[np.ix_(planted, planted)] = True
    np.fill_diagonal(adj, False)
    clique, exact = maximum_clique(adj)
    assert exact
    assert clique.tolist() == planted.tolist()
    assert adj[np.ix_(clique, clique)].sum() == 12 * 11


def _clique_number(adj: np.ndarray) -> int:
    """Size of a maximum clique by Bron–Kerbosch with a pivot (the reference)."""
    neighbours = [set(np.flatnonzero(row).tolist()) for row in adj]
    best = 0

    def grow(r: int, p: set, x: set) -> None:
        nonlocal best
        if not p and not x:
            best = max(best, r)
            return
        pivot = max(p | x, key=lambda u: len(neighbours[u] & p))
        for v in list(p - neighbours[pivot]):
            grow(r + 1, p & neighbours[v], x & neighbours[v])
            p = p - {v}
            x = x | {v}

    grow(0, set(range(adj.shape[0])), set())
    return best


@pytest.mark.parametrize(("m", "density", "seed"), [(70, 0.35, 0), (130, 0.25, 1), (200, 0.2, 2)])
def test_maximum_clique_matches_a_reference_across_word_boundaries(m, density, seed):
    # graphs of more than 64 vertices: the bit sets span several words; one greedy start only,
    # so the exact search (not the heuristic) has to find the maximum
    rng = np.random.default_rng(seed)
    adj = np.triu(rng.random((m, m)) < density, 1)
    adj = adj | adj.T
    clique, exact = maximum_clique(adj, budget=10**7, starts=1)
    assert exact
    assert clique.size == _clique_number(adj)
    assert adj[np.ix_(clique, clique)].sum() == clique.size * (clique.size - 1)


def test_maximum_clique_out_of_budget_is_flagged_and_still_a_clique():
    rng = np.random.default_rng(5)
    m = 150
    adj = np.triu(rng.random((m, m)) < 0.5, 1)
    adj = adj | adj.T
    clique, exact = maximum_clique(adj, budget=3, starts=1)
    assert not exact
    assert clique.size >= 2
    assert adj[np.ix_(clique, clique)].sum() == clique.size * (clique.size - 1)
    full, exact_full = maximum_clique(adj, budget=10**7)
    assert exact_full and full.size >= clique.size


@pytest.mark.parametrize(("yaw", "shift"), [(0.0, (0, 0, 0)), (30.0, (20.0, 0.0, 0.0))])
def test_shifted_and_rotated_map_is_matched_correctly(yaw, shift):
    a, b, (ids_a, in_a), (ids_b, in_b) = _two_maps(yaw=yaw, shift=shift)
    result = associate(a, b)
    assert result.matched, result.status
    truth_a = (ids_a, in_a)
    truth_b = (ids_b, in_b)
    score = score_correspondences(result.pairs, a.ids, b.ids, truth_a, truth_b)
    assert score.shared == 40
    assert score.wrong == 0
    assert score.correct == 40
    # the transform is the one applied to the second map, inverted
    expected = np.linalg.inv(_pose(yaw, shift))
    assert np.allclose(result.T_first_second[:3, :3], expected[:3, :3], atol=0.01)
    assert np.allclose(result.T_first_second[:3, 3], expected[:3, 3], atol=0.3)


def test_the_rule_is_the_same_on_both_ends():
    a, b, *_ = _two_maps(seed=5, yaw=30.0, shift=(20.0, -5.0, 0.0))
    forward = associate(a, b)
    rng = np.random.default_rng(9)
    # the other end holds the same summaries, perhaps in another order
    backward = associate(b.take(rng.permutation(len(b))), a.take(rng.permutation(len(a))))
    assert forward.matched and backward.matched
    assert np.array_equal(backward.swapped().pairs, forward.pairs)
    assert np.array_equal(backward.pairs, forward.swapped().pairs)
    assert np.allclose(backward.T_first_second @ forward.T_first_second, np.eye(4), atol=1e-9)


def test_a_regular_grid_gives_no_correspondence():
    # every object of a grid looks like every other: shifting by a cell is as good an answer
    x, y = np.meshgrid(np.arange(8) * 5.0, np.arange(8) * 5.0)
    grid = np.column_stack([x.ravel(), y.ravel(), np.zeros(64)])
    rng = np.random.default_rng(2)
    a = _summary(0, np.arange(64), grid, rng, sigma=0.05)
    b = _summary(1, np.arange(64) + 100, grid, rng, _pose(0.0, (1.0, 2.0, 0.0)), sigma=0.05)
    result = associate(a, b)
    assert not result.matched
    assert result.pairs.shape == (0, 2)
    assert result.T_first_second is None


def test_too_few_shared_objects_give_no_correspondence():
    rng = np.random.default_rng(4)
    world = _scene(rng, 42, extent=300.0)
    a = _summary(0, np.arange(20), world[np.r_[0:2, 2:20]], rng)
    b = _summary(1, np.arange(22) + 100, world[np.r_[0:2, 20:40]], rng)
    for settings in (AssociationSettings(), AssociationSettings(min_inliers=3)):
        result = associate(a, b, settings)
        assert not result.matched
        assert result.pairs.size == 0


def test_maps_of_different_places_give_no_correspondence():
    rng = np.random.default_rng(6)
    a = _summary(0, np.arange(60), _scene(rng, 60), rng)
    b = _summary(1, np.arange(60) + 100, _scene(rng, 60), rng)
    result = associate(a, b)
    assert not result.matched, (result.status, result.pairs)


def _shared_patch(seed: int, private_near: int = 4, private_far: int = 20):
    """Two maps sharing 8 objects of a 20 m patch; each also holds ``private_near`` objects of
    its own among them (so each shared object's nearest neighbours differ between the maps)
    and ``private_far`` more elsewhere; the second map shifted 20 m and turned 30°. The shared
    objects come first in both maps."""
    rng = np.random.default_rng(seed)
    near = _scene(rng, 8 + 2 * private_near, extent=20.0, spacing=3.0)
    far_a = _scene(rng, private_far, extent=60.0, spacing=4.0) + np.array([30.0, 0, 0])
    far_b = _scene(rng, private_far, extent=60.0, spacing=4.0) - [66.0, 0, 0]
    world_a = np.concatenate([near[:8], near[8 : 8 + private_near], far_a])
    world_b = np.concatenate([near[:8], near[8 + private_near :], far_b])
    a = _summary(1, np.arange(len(world_a)) + 100, world_a, rng)
    b = _summary(2, np.arange(len(world_b)) + 500, world_b, rng, _pose(30.0, (20.0, 0, 0)))
    return a, b


def test_shared_objects_with_different_neighbours_are_candidates_and_matched():
    # each shared object's six nearest neighbours mix shared objects with objects only one map
    # holds; the shared ones must still be candidates. (Comparing the two lists of neighbour
    # distances element by element, many to one, let chance agreements outrank them: all 8
    # were candidates in 1 of these 10 scenes and 1 was matched.)
    complete = 0
    for seed in range(10):
        a, b = _shared_patch(seed)
        geo_a, geo_b = pair_distances(a.means, a.covs), pair_distances(b.means, b.covs)
        settings = AssociationSettings()
        score, mismatch, _ = neighbourhood_sets(a, b, geo_a, geo_b, settings)
        ia, ib = select_candidates(score, mismatch, settings)
        complete += np.count_nonzero((ia < 8) & (ia == ib)) == 8
        result = associate(a, b)
        assert result.matched, (seed, result.status)
        assert np.array_equal(
            result.pairs, np.column_stack([np.arange(8) + 100, np.arange(8) + 500])
        )
    assert complete >= 7


def test_unrelated_maps_give_no_correspondence():
    # the precision guard of a candidate rule: maps of different places, as dense as the
    # patches above, never give an answer
    for seed in range(20, 30):
        rng = np.random.default_rng(seed)
        a = _summary(0, np.arange(40), _scene(rng, 40, extent=50.0, spacing=3.0), rng)
        b = _summary(1, np.arange(40) + 100, _scene(rng, 40, extent=50.0, spacing=3.0), rng)
        result = associate(a, b.transformed(_pose(30.0, (20.0, 0, 0))))
        assert not result.matched, (seed, result.status, result.pairs)


def test_an_answer_thinned_below_the_minimum_is_no_answer(monkeypatch):
    # the last stage drops gate-added pairs that disagree with the consistent set; when that
    # leaves fewer than min_inliers pairs, the answer is refused like any other too-small one
    from teamslam.association import answer

    a, b, _, _ = _two_maps(seed=2)
    settings = AssociationSettings()
    assert associate(a, b, settings).matched
    keep = settings.min_inliers - 1
    monkeypatch.setattr(
        answer, "_beyond_the_clique", lambda a, b, rows, cols, *rest: (rows[:keep], cols[:keep])
    )
    result = associate(a, b, settings)
    assert result.status == "too-few" and result.pairs.shape == (0, 2)
    monkeypatch.setattr(
        answer, "_beyond_the_clique", lambda a, b, rows, cols, *rest: (rows[:-1], cols[:-1])
    )
    thinned = associate(a, b, settings)
    assert thinned.matched and thinned.pairs.shape[0] >= settings.min_inliers


def _strip_maps(seed: int, overlap: tuple[float, float] = (48.0, 62.0)):
    """Two robots' maps of one street: the first holds the objects west of ``overlap[1]``, the
    second, drifted (30°, 20 m), those east of ``overlap[0]``; the strip between is shared."""
    rng = np.random.default_rng(seed)
    world = _scene(rng, 60, extent=110.0, spacing=4.0)
    in_a = np.flatnonzero(world[:, 0] < overlap[1])
    in_b = np.flatnonzero(world[:, 0] > overlap[0])
    ids_a = rng.permutation(1000)[: in_a.size] + 5000
    ids_b = rng.permutation(1000)[: in_b.size] + 9000
    a = _summary(1, ids_a, world[in_a], rng)
    b = _summary(2, ids_b, world[in_b], rng, _pose(30.0, (20.0, 0, 0)))
    return a, b, (ids_a, in_a), (ids_b, in_b)


def test_a_small_shared_strip_is_found_from_the_neighbourhoods_seeds():
    # maps sharing 6-14 objects of a strip among 20-30 of their own: the largest consistent
    # sets among the candidates are often chance ones; the candidates' own neighbourhoods seed
    # the right one (the clique search alone answered 7 of these 12, all right)
    answered = wrong = 0
    for seed in range(12):
        a, b, truth_a, truth_b = _strip_maps(seed)
        result = associate(a, b)
        score = score_correspondences(result.pairs, a.ids, b.ids, truth_a, truth_b)
        answered += result.matched
        wrong += score.wrong
        assert associate(b, a).pairs.tolist() == result.swapped().pairs.tolist()
    assert answered >= 10 and wrong == 0


def test_maps_of_as_few_objects_as_an_answer_needs_are_associated_without_error():
    # a map of k objects or fewer has fewer than k neighbours per object: the seeds' neighbour
    # slots are read with that map's own count (this used to index past the end)
    for seed in range(30):
        rng = np.random.default_rng(seed)
        n_a, n_b = rng.integers(6, 9, size=2)
        world = _scene(rng, 12, extent=30.0, spacing=3.0)
        a = _summary(1, np.arange(n_a), world[:n_a], rng)
        b = _summary(2, np.arange(n_b) + 50, world[12 - n_b :], rng, _pose(10.0, (3.0, 0, 0)))
        result = associate(a, b)
        assert associate(b, a).pairs.tolist() == result.swapped().pairs.tolist()


def test_gathered_objects_counts_the_first_maps_objects_within_reach():
    rng = np.random.default_rng(4)
    ma, mb = rng.uniform(0, 20, (15, 3)), rng.uniform(0, 20, (12, 3))
    la, lb = rng.uniform(0.1, 2.0, 15), rng.uniform(0.1, 2.0, 12)
    rot = np.stack([so3.exp(rng.normal(0, 1, 3)) for _ in range(5)])
    trans = rng.normal(0, 3, (5, 3))
    got = gathered_objects(rot, trans, ma, mb, la, lb, 7.8)
    moved = np.einsum("hij,bj->hbi", rot, mb) + trans[:, None]
    d2 = ((ma[None, :, None] - moved[:, None]) ** 2).sum(axis=-1)  # (h, a, b)
    expected = (d2 <= 7.8 * (la[:, None] + lb[None])).any(axis=2).sum(axis=1)
    assert got.tolist() == expected.tolist() and expected.max() > 0


def test_half_shared_maps_are_matched_with_high_precision_and_recall():
    # 20 shared objects among 20 more in each map that the other does not hold, drifted map
    correct = wrong = shared = 0
    for seed in range(11, 16):
        a, b, truth_a, truth_b = _two_maps(seed=seed, shared=20, own=20, yaw=30.0, shift=(20, 0, 0))
        score = score_correspondences(associate(a, b).pairs, a.ids, b.ids, truth_a, truth_b)
        correct, wrong, shared = correct + score.correct, wrong + score.wrong, shared + score.shared
    assert shared == 100
    assert correct >= 90 and wrong <= 5


def test_classes_forbid_matching_objects_of_different_kinds():
    a, b, (ids_a, in_a), (ids_b, in_b) = _two_maps(seed=2)
    classes_a = (in_a % 2).astype(np.int64)
    classes_b = ((in_b + 1) % 2).astype(np.int64)  # every shared object gets the other class
    ca = ObjectSummary(a.robot, a.ids, a.means, a.covs, classes_a)
    cb = ObjectSummary(b.robot, b.ids, b.means, b.covs, classes_b)
    assert associate(a, b).matched
    result = associate(ca, cb)
    score = score_correspondences(result.pairs, a.ids, b.ids, (ids_a, in_a), (ids_b, in_b))
    assert score.correct == 0


def test_a_held_pair_whose_classes_came_to_differ_is_revoked():
    """An object's class is the majority of its boxes' labels: a pair held while the two agreed
    is revoked once one object's class changes (the association pairs equal classes only); the
    pairs whose classes still agree, and those with an object outside a summary, are kept."""
    table, result, a, b, *_ = _table_with_result()
    classes_a = np.zeros(len(a), np.int64)
    classes_b = np.zeros(len(b), np.int64)
    ca = ObjectSummary(a.robot, a.ids, a.means, a.covs, classes_a)
    cb = ObjectSummary(b.robot, b.ids, b.means, b.covs, classes_b)
    assert table.revoke_other_classes(ca, cb, step=1) == 0 and len(table) == 40
    assert table.revoke_other_classes(a, b, step=1) == 0  # no classes: nothing to compare
    own, their = result.pairs[3]
    changed = classes_a.copy()
    changed[np.flatnonzero(a.ids == own)] = 1
    # a second held pair, its own object missing from the summary, keeps its pair
    gone = result.pairs[5, 0]
    keep = a.ids != gone
    ca = ObjectSummary(a.robot, a.ids[keep], a.means[keep], a.covs[keep], changed[keep])
    assert table.revoke_other_classes(ca, cb, step=2) == 1
    assert (own, their) not in table and len(table) == 39 and table.counts()["revoked"] == 1
    assert tuple(result.pairs[5]) in table
    # revoked for good: the same answer again does not bring it back
    table.merge(result, a, b, step=3)
    assert (own, their) not in table


def test_summary_errors_name_the_field():
    with pytest.raises(InputError, match="duplicates"):
        ObjectSummary(0, [1, 1], np.zeros((2, 3)), np.repeat(np.eye(3)[None], 2, axis=0))
    with pytest.raises(InputError, match="covs must be"):
        ObjectSummary(0, [1, 2], np.zeros((2, 3)), np.eye(3))
    with pytest.raises(InputError, match="object 2 is not positive definite"):
        ObjectSummary(0, [1, 2], np.zeros((2, 3)), np.stack([np.eye(3), np.zeros((3, 3))]))
    with pytest.raises(InputError, match="drift_ratio"):
        AssociationSettings(drift_ratio=-1.0)
    one = ObjectSummary(3, [1], np.zeros((1, 3)), np.eye(3)[None])
    with pytest.raises(InputError, match="both are robot 3's"):
        associate(one, one)
    with pytest.raises(InputError, match="views must be"):
        ObjectSummary(0, [1, 2], np.zeros((2, 3)), np.stack([np.eye(3)] * 2), views=np.ones(3))
    with pytest.raises(InputError, match="views are not finite"):
        ObjectSummary(0, [1], np.zeros((1, 3)), np.eye(3)[None], views=[[0.0, np.nan, 1.0]])


def test_fit_transform_recovers_a_rigid_motion():
    rng = np.random.default_rng(8)
    pts = rng.normal(0, 10, (10, 3))
    t = _pose(40.0, (3.0, -2.0, 1.0))
    moved = pts @ t[:3, :3].T + t[:3, 3]
    assert np.allclose(fit_transform(moved, pts), t, atol=1e-9)


def _table_with_result(seed=0):
    a, b, truth_a, truth_b = _two_maps(seed=seed)
    result = associate(a, b)
    table = CorrespondenceTable(a.robot, b.robot)
    table.merge(result, a, b, step=0)
    return table, result, a, b, truth_a, truth_b


def test_table_keeps_pairs_and_maps_both_ways():
    table, result, a, b, *_ = _table_with_result()
    assert np.array_equal(table.pairs(), result.pairs)
    assert table.counts() == {"proposed": 40, "accepted": 40, "revoked": 0, "held": 40}
    own, their = result.pairs[3]
    assert table.theirs([own])[0] == their and table.ours([their])[0] == own
    assert table.theirs([-7])[0] == -1
    # the same result again adds and proposes nothing
    assert table.merge(result, a, b, step=1).size == 0
    assert table.counts()["proposed"] == 40


def test_a_wrong_pair_fails_its_innovation_test_and_is_revoked_for_good():
    table, result, a, b, *_ = _table_with_result()
    t = table.T_own_their
    own_id, their_id = result.pairs[0]
    ia = int(np.flatnonzero(a.ids == own_id)[0])
    ib = int(np.flatnonzero(b.ids == their_id)[0])
    ok = pair_innovation_consistent(a.means[ia], a.covs[ia], b.means[ib], b.covs[ib], t)
    assert ok.tolist() == [True]
    # the neighbour lies: 20 m off with a tiny covariance
    lie = b.means[ib] + [20.0, 0.0, 0.0]
    bad = pair_innovation_consistent(a.means[ia], a.covs[ia], lie, 1e-6 * np.eye(3), t)
    assert bad.tolist() == [False]
    assert table.revoke(own_id, their_id, step=3)
    assert (own_id, their_id) not in table
    assert not table.revoke(own_id, their_id)  # not held any more
    table.merge(result, a, b, step=4)
    assert (own_id, their_id) not in table  # never re-added
    assert table.counts()["revoked"] == 1 and len(table) == 39


def test_the_pair_check_with_a_link_scale_keeps_pairs_as_far_apart_as_the_scale_says():
    """Pairs whose differences are ``s`` times their covariances (``nis ~ s · χ²₃``, maps
    overconfident against each other by ``s``) fail the plain test far more often than
    ``1 − p``; with the link's scale ``s`` they fail at ``1 − p``. A neighbour 20 m off with a
    tiny covariance fails both."""
    rng = np.random.default_rng(3)
    n, s, p = 20000, 9.0, 0.999
    cov = np.broadcast_to(0.01 * np.eye(3), (n, 3, 3))
    diff = rng.normal(scale=np.sqrt(2 * 0.01 * s), size=(n, 3))
    own = rng.normal(size=(n, 3))
    plain = pair_innovation_consistent(own, cov, own + diff, cov, probability=p)
    scaled = pair_innovation_consistent(own, cov, own + diff, cov, probability=p, scale=s)
    assert 1 - plain.mean() > 0.3
    assert abs((1 - scaled.mean()) - (1 - p)) < 4 * np.sqrt(p * (1 - p) / n)
    lie = own[:1] + np.array([20.0, 0.0, 0.0])
    tiny = 1e-6 * np.eye(3)[None]
    assert not pair_innovation_consistent(own[:1], cov[:1], lie, tiny, probability=p, scale=s)[0]
    with pytest.raises(InputError, match="scale must be"):
        pair_innovation_consistent(own, cov, own, cov, scale=0.5)


def test_a_revoked_pair_may_return_after_the_hold_off():
    a, b, *_ = _two_maps()
    result = associate(a, b)
    table = CorrespondenceTable(a.robot, b.robot, hold_off=5)
    table.merge(result, a, b, step=0)
    own_id, their_id = result.pairs[0]
    table.revoke(own_id, their_id, step=10)
    table.merge(result, a, b, step=12)
    assert (own_id, their_id) not in table
    table.merge(result, a, b, step=15)
    assert (own_id, their_id) in table


def test_table_refuses_a_pair_that_disagrees_with_the_held_transform():
    table, result, a, b, *_ = _table_with_result()
    # a result naming two unmatched objects 30 m apart under the held transform
    own_free = np.setdiff1d(a.ids, table.pairs()[:, 0])[0]
    their_free = np.setdiff1d(b.ids, table.pairs()[:, 1])[0]
    ia = int(np.flatnonzero(a.ids == own_free)[0])
    ib = int(np.flatnonzero(b.ids == their_free)[0])
    gap = np.linalg.norm(a.means[ia] - b.transformed(table.T_own_their).means[ib])
    assert gap > 3.0
    fake = type(result)(a.robot, b.robot, np.array([[own_free, their_free]]), np.eye(4), "matched")
    assert table.merge(fake, a, b, step=1).size == 0
    assert table.counts()["proposed"] == 41 and table.counts()["accepted"] == 40


def test_scores_count_right_and_wrong_pairs():
    pairs = np.array([[1, 11], [2, 12], [3, 14]])
    truth_a = (np.array([1, 2, 3, 4]), np.array([100, 200, 300, 400]))
    truth_b = (np.array([11, 12, 13, 14]), np.array([100, 200, 300, 500]))
    score = score_correspondences(pairs, truth_a[0], truth_b[0], truth_a, truth_b)
    assert (score.correct, score.wrong, score.shared) == (2, 1, 3)
    assert score.precision == pytest.approx(2 / 3) and score.recall == pytest.approx(2 / 3)
    with pytest.raises(InputError, match="does not hold"):
        score_correspondences(np.array([[9, 11]]), truth_a[0], truth_b[0], truth_a, truth_b)


def test_extend_grows_the_table_identically_on_both_ends():
    from dataclasses import replace

    a, b, truth_a, truth_b = _two_maps(seed=0, yaw=30.0, shift=(20.0, 0.0, 0.0))
    full = associate(a, b)
    assert full.matched and len(full.pairs) == 40
    start = replace(full, pairs=full.pairs[:8])  # the maps held only a few of them at first
    mine = CorrespondenceTable(a.robot, b.robot)
    theirs = CorrespondenceTable(b.robot, a.robot)
    mine.merge(start, a, b, step=0)
    theirs.merge(start.swapped(), b, a, step=0)
    added = mine.extend(a, b, step=1)
    added_there = theirs.extend(b, a, step=1)
    assert len(added) >= 28  # most of the 32 others, and (below) none wrong
    assert np.array_equal(theirs.pairs(), mine.pairs()[np.argsort(mine.pairs()[:, 1])][:, ::-1])
    assert np.array_equal(added_there[np.argsort(added_there[:, 1])][:, ::-1], added)
    score = score_correspondences(mine.pairs(), a.ids, b.ids, truth_a, truth_b)
    assert score.wrong == 0 and score.correct == 8 + len(added)
    # a revoked pair does not come back through extend either
    own_id, their_id = full.pairs[20]
    mine.revoke(own_id, their_id, step=2)
    again = mine.extend(a, b, step=3)
    assert (own_id, their_id) not in mine
    assert [own_id, their_id] not in again.tolist()
    score = score_correspondences(mine.pairs(), a.ids, b.ids, truth_a, truth_b)
    assert score.wrong == 0


def test_extend_needs_three_held_pairs():
    from dataclasses import replace

    a, b, *_ = _two_maps(seed=3)
    full = associate(a, b)
    table = CorrespondenceTable(a.robot, b.robot)
    table.merge(replace(full, pairs=full.pairs[:2]), a, b)
    assert table.extend(a, b).size == 0 and len(table) == 2


def test_a_full_association_is_due_first_and_when_a_map_has_grown():
    a, b, *_ = _two_maps()
    table = CorrespondenceTable(a.robot, b.robot)
    assert table.due(len(a), len(b))
    table.merge(associate(a, b), a, b)
    assert not table.due(len(a), len(b))
    assert not table.due(len(a) + 10, len(b))  # 60 → 70: less than 25 % more
    assert table.due(len(a) + 15, len(b))
    assert table.due(len(a), 2 * len(b))
    with pytest.raises(InputError, match="growth"):
        table.due(1, 1, growth=1.0)


def test_a_link_without_an_answer_tries_again_after_as_many_new_objects_as_an_answer_needs():
    a, b, *_ = _two_maps(shared=3, own=40)  # three shared objects: no answer
    table = CorrespondenceTable(a.robot, b.robot)
    assert table.due(len(a), len(b))
    table.merge(associate(a, b), a, b)
    assert len(table) == 0
    need = table.settings.min_inliers
    n = len(a)  # 43 objects: a quarter more is 54
    assert not table.due(n, len(b))  # nothing new
    assert not table.due(n + need - 1, len(b))
    assert table.due(n + need, len(b))
    assert table.due(n, len(b) + need)
    # with an answer, only the growth by a quarter makes a full association due
    a, b, *_ = _two_maps()
    table = CorrespondenceTable(a.robot, b.robot)
    table.merge(associate(a, b), a, b)
    assert len(table) >= need
    assert not table.due(len(a) + need, len(b))
    assert table.due(len(a) + 15, len(b))


def test_the_cadence_answers_within_min_inliers_objects_of_an_attempt_at_every_exchange():
    # the second map grows by one object per exchange: first the objects only it holds, then
    # the shared ones; the cadence's first answer comes fewer than min_inliers objects after
    # that of a full association at every exchange, for a fraction of the full associations
    a, b, (ids_a, in_a), (ids_b, in_b) = _two_maps()
    rng = np.random.default_rng(0)
    order = np.concatenate(
        [rng.permutation(np.flatnonzero(in_b >= 40)), rng.permutation(np.flatnonzero(in_b < 40))]
    )
    runs = {}
    for cadence in (False, True):
        table = CorrespondenceTable(a.robot, b.robot)
        first, full = None, 0
        for n in range(26, len(b) + 1):
            seen = b.take(np.sort(order[:n]))
            if not cadence or table.due(len(a), len(seen)):
                table.merge(associate(a, seen), a, seen)
                full += 1
            else:
                table.extend(a, seen)
            first = n if first is None and len(table) else first
        runs[cadence] = (first, full, table.pairs())
    every, cadence = runs[False], runs[True]
    need = AssociationSettings().min_inliers
    assert every[0] is not None and every[0] <= cadence[0] < every[0] + need
    assert cadence[1] < every[1] / 4
    truth_a = dict(zip(ids_a.tolist(), in_a.tolist(), strict=True))
    truth_b = dict(zip(ids_b.tolist(), in_b.tolist(), strict=True))
    assert len(cadence[2]) >= 0.9 * len(every[2])
    assert all(truth_a[x] == truth_b[y] for x, y in cadence[2].tolist())


def _with_a_neighbour_of_an_unseen_partner(seed=0, elongation=10.0):
    """Two maps and, in the second, a neighbour (3 m along x) of an object only the first map
    holds, placed along x with a standard deviation of ``elongation`` metres: a car of the same
    row whose true partner the second robot has not seen."""
    rng = np.random.default_rng(seed)
    a, b, truth_a, _ = _two_maps(seed=seed)
    only_a = truth_a[1] >= 40  # objects the second map lacks
    k = int(np.flatnonzero(only_a)[0])
    cov = np.diag([elongation**2, SIGMA**2, SIGMA**2])
    mean = a.means[k] + np.array([3.0, 0.0, 0.0]) + rng.normal(0, SIGMA, 3)
    b2 = ObjectSummary(
        b.robot,
        np.append(b.ids, 99_999),
        np.vstack([b.means, mean]),
        np.concatenate([b.covs, cov[None]]),
    )
    return a, b2, int(a.ids[k])


def test_a_pair_whose_gate_spans_its_neighbours_is_not_a_match():
    a, b, own_id = _with_a_neighbour_of_an_unseen_partner()
    loose = associate(a, b, AssociationSettings(separation=0.0))
    assert [own_id, 99_999] in loose.pairs.tolist()  # the gate alone takes the neighbour
    strict = associate(a, b, AssociationSettings(separation=1.0))
    assert strict.matched and [own_id, 99_999] not in strict.pairs.tolist()
    assert len(strict.pairs) == len(loose.pairs) - 1  # every well-placed pair stays
    # objects placed well within their spacing lose no pair to the test
    a, b, *_ = _two_maps(seed=1, yaw=30.0, shift=(20.0, 0.0, 0.0))
    plain = associate(a, b, AssociationSettings(separation=1.0))
    assert np.array_equal(plain.pairs, associate(a, b, AssociationSettings()).pairs)
    assert len(plain.pairs) == 40


def test_extend_refuses_a_pair_whose_gate_spans_its_neighbours():
    a, b, own_id = _with_a_neighbour_of_an_unseen_partner()
    base = associate(a, b, AssociationSettings(separation=1.0))
    for separation, expected in ((0.0, True), (1.0, False)):
        settings = AssociationSettings(separation=separation)
        table = CorrespondenceTable(a.robot, b.robot, settings)
        table.merge(base, a, b)
        table.extend(a, b)
        assert ((own_id, 99_999) in table) is expected
        # the same decision at the other end of the link
        other = CorrespondenceTable(b.robot, a.robot, settings)
        other.merge(base.swapped(), b, a)
        other.extend(b, a)
        assert np.array_equal(
            other.pairs()[:, ::-1][np.argsort(other.pairs()[:, 1])], table.pairs()
        )


def _with_an_object_off_its_distances(offset, settings: AssociationSettings):
    """Two maps sharing 40 objects (held by the table) and one more object in each, both placed
    loosely (1 m standard deviation) in an empty region, ``offset`` metres apart along the line
    from the nearest held object: a pair whose Mahalanobis distance passes the ``χ²₃`` gate while
    its distance to that held object differs between the maps by ``offset``. With several
    offsets the second map holds one object (ids 99 999, 99 998, …) at each."""
    a, b, *_ = _two_maps(seed=0)
    base = associate(a, b, settings)
    table = CorrespondenceTable(a.robot, b.robot, settings)
    table.merge(base, a, b, step=0)
    other = CorrespondenceTable(b.robot, a.robot, settings)  # the other end of the link
    other.merge(base.swapped(), b, a, step=0)
    assert len(table) == len(other) == 40
    shared = a.means[np.isin(a.ids, table.pairs()[:, 0])]
    # the grid point farthest from every object of both maps
    grid = np.stack(np.meshgrid(np.arange(0, 121, 2.0), np.arange(0, 121, 2.0)), -1).reshape(-1, 2)
    grid = np.column_stack([grid, np.ones(len(grid))])
    every = np.vstack([a.means, b.means])
    p = grid[np.argmax(np.min(np.linalg.norm(grid[:, None] - every[None], axis=2), axis=1))]
    u = p - shared[np.argmin(np.linalg.norm(shared - p, axis=1))]
    u /= np.linalg.norm(u)
    cov = np.eye(3)[None]

    def plus(s: ObjectSummary, new_ids, means: np.ndarray) -> ObjectSummary:
        covs = np.repeat(cov, len(means), axis=0)
        return ObjectSummary(
            s.robot,
            np.append(s.ids, new_ids),
            np.vstack([s.means, means]),
            np.vstack([s.covs, covs]),
        )

    offsets = np.atleast_1d(offset)
    their = plus(b, 99_999 - np.arange(offsets.size), p + offsets[:, None] * u)
    return table, other, plus(a, [77_777], p[None]), their


def test_extend_refuses_a_pair_inconsistent_with_the_held_pairs():
    # 4.3 m apart with 1 m on each side: Mahalanobis distance² 9.2, inside the χ²₃(0.99) gate
    # (11.3), but the distance to the nearest held object (22 m away) differs by 4.3 m against a
    # standard deviation of 1.5 m with the drift allowance (χ²₁ 8.4 > 6.6): not consistent
    settings = AssociationSettings(drift_ratio=0.01)
    table, other, a, b = _with_an_object_off_its_distances(4.3, settings)
    t = table.T_own_their
    nu = a.means[-1] - (t[:3, :3] @ b.means[-1] + t[:3, 3])
    assert nu @ nu / 2.0 < settings.gate_threshold
    assert table.extend(a, b, step=1).size == 0 and (77_777, 99_999) not in table
    assert other.extend(b, a, step=1).size == 0 and (99_999, 77_777) not in other
    # the same objects placed alike in both maps make a pair
    table, other, a, b = _with_an_object_off_its_distances(0.5, settings)
    assert table.extend(a, b, step=1).tolist() == [[77_777, 99_999]]
    assert other.extend(b, a, step=1).tolist() == [[99_999, 77_777]]


def test_extend_refuses_a_pair_with_a_second_object_in_its_gate():
    # the partner 0.3 m away (Mahalanobis distance² 0.05) and a second object 3.5 m away (6.1):
    # both in the χ²₃ gate (11.3), the assignment prefers the first by more than the distinctness
    # margin, but the gate alone cannot tell which one is the same object; extension adds no pair
    settings = AssociationSettings(drift_ratio=0.01)
    table, other, a, b = _with_an_object_off_its_distances([0.3, -3.5], settings)
    assert table.extend(a, b, step=1).size == 0 and len(table) == 40
    assert other.extend(b, a, step=1).size == 0 and len(other) == 40
    # the second object outside the gate (6 m away: 18 > 11.3): the pair enters
    table, other, a, b = _with_an_object_off_its_distances([0.3, -6.0], settings)
    assert table.extend(a, b, step=1).tolist() == [[77_777, 99_999]]
    assert other.extend(b, a, step=1).tolist() == [[99_999, 77_777]]


def test_full_association_refuses_a_gated_pair_inconsistent_with_its_consistent_set():
    # the pair of the extension test above, offered to a full association: inside the gate of
    # the answer's transform, 4.3 m off in its distances to the consistent set's objects
    settings = AssociationSettings(drift_ratio=0.01)
    _, _, a, b = _with_an_object_off_its_distances(4.3, settings)
    result = associate(a, b, settings)
    t = result.T_first_second
    nu = a.means[-1] - (t[:3, :3] @ b.means[-1] + t[:3, 3])
    assert nu @ nu / 2.0 < settings.gate_threshold
    assert result.matched and (77_777, 99_999) not in set(map(tuple, result.pairs.tolist()))
    assert len(result.pairs) == 40
    swapped = associate(b, a, settings)
    assert (99_999, 77_777) not in set(map(tuple, swapped.pairs.tolist()))
    # placed alike in both maps, the same objects make a pair
    _, _, a, b = _with_an_object_off_its_distances(0.5, settings)
    assert (77_777, 99_999) in set(map(tuple, associate(a, b, settings).pairs.tolist()))


def _street(seed: int, views: bool, planar: bool = True, pairs: int = 10):
    """Two maps of a street: ``pairs`` objects on each side, each the other's mirror image
    across the street's axis (as parked cars face each other), within 5 cm of one plane (or,
    ``planar=False``, spread over 30 m in height); the cameras drove along the axis 1.2 m above
    them (``views``: the summaries say where). The second map is shifted 20 m and turned 30°.
    Object ``k`` is ``100 + k`` in the first map and ``500 + k`` in the second."""
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.uniform(4.0, 12.0, pairs))
    y = rng.uniform(3.0, 9.0, pairs)
    side = np.column_stack([x, y, rng.normal(0.0, 0.05, pairs)])
    if not planar:
        side[:, 2] = rng.uniform(0.0, 30.0, pairs)
    world = np.vstack([side, side * [1.0, -1.0, 1.0]])
    cameras = np.column_stack([world[:, 0] + rng.uniform(-8, 8, len(world)), np.zeros(len(world))])
    cameras = np.column_stack([cameras, world[:, 2] + 1.2])

    def summary(robot, first_id, T=None):
        s = _summary(robot, np.arange(len(world)) + first_id, world, rng)
        if views:
            toward = cameras - s.means
            toward /= np.linalg.norm(toward, axis=1)[:, None]
            s = ObjectSummary(s.robot, s.ids, s.means, s.covs, views=toward)
        return s if T is None else s.transformed(T)

    return summary(1, 100), summary(2, 500, _pose(30.0, (20.0, 0.0, 0.0)))


def test_the_mirror_image_of_a_street_is_refused_by_the_cameras_side():
    # distances cannot tell the street from its mirror image (each side's cars matched with
    # the other side's, the plane turned over): without the cameras no answer, with them the
    # right one on both ends of the link
    right = np.column_stack([np.arange(20) + 100, np.arange(20) + 500])
    for seed in range(5):
        a, b = _street(seed, views=False)
        blind = associate(a, b)
        assert blind.status == "ambiguous" and blind.flipped == 0, (seed, blind.status)
        a, b = _street(seed, views=True)
        seen = associate(a, b)
        assert seen.matched and seen.flipped >= 1, (seed, seen.status)
        assert np.array_equal(seen.pairs, right)
        assert np.array_equal(associate(b, a).pairs, right[:, ::-1])


def test_the_cameras_side_of_a_transform():
    a, b = _street(0, views=True)
    result = associate(a, b)
    rows, cols = np.arange(20), np.arange(20)
    assert not flipped(a, b, rows, cols, result.T_first_second)
    # the same pairs under the transform turned over about the street's axis
    half_turn = np.eye(4)
    half_turn[:3, :3] = so3.exp(np.array([np.pi, 0.0, 0.0]))
    assert flipped(a, b, rows, cols, half_turn @ result.T_first_second)
    # not near-planar: no side to speak of, never refused
    a, b = _street(0, views=True, planar=False)
    assert not flipped(a, b, rows, cols, half_turn @ result.T_first_second)
    # without views on one side, or views unknown (zero), nothing is refused
    blind = ObjectSummary(b.robot, b.ids, b.means, b.covs)
    assert not flipped(a, blind, rows, cols, half_turn @ result.T_first_second)
    unknown = ObjectSummary(b.robot, b.ids, b.means, b.covs, views=np.zeros((20, 3)))
    assert not flipped(a, unknown, rows, cols, half_turn @ result.T_first_second)


def test_views_change_nothing_on_a_set_that_is_not_planar():
    # objects spread in height, cameras anywhere (each robot's on its own side of them): the
    # answer with views is the answer without, pair for pair
    for seed in range(3):
        a, b, *_ = _two_maps(seed=seed, yaw=30.0, shift=(20.0, 0.0, 0.0))
        a = ObjectSummary(a.robot, a.ids, a.means * [1, 1, 15], a.covs)
        b = ObjectSummary(b.robot, b.ids, b.means * [1, 1, 15], b.covs)
        rng = np.random.default_rng(seed)
        with_a = ObjectSummary(a.robot, a.ids, a.means, a.covs, views=rng.normal(0, 1, (60, 3)))
        with_b = ObjectSummary(b.robot, b.ids, b.means, b.covs, views=rng.normal(0, 1, (60, 3)))
        blind, seen = associate(a, b), associate(with_a, with_b)
        assert blind.matched and len(blind.pairs) >= 30
        assert np.array_equal(blind.pairs, seen.pairs) and blind.status == seen.status
        rows = np.array([np.flatnonzero(a.ids == i)[0] for i in seen.pairs[:, 0]])
        cols = np.array([np.flatnonzero(b.ids == i)[0] for i in seen.pairs[:, 1]])
        turned = np.eye(4)
        turned[:3, :3] = so3.exp(np.array([np.pi, 0.0, 0.0]))
        for t in (seen.T_first_second, turned @ seen.T_first_second):
            assert not flipped(with_a, with_b, rows, cols, t)


def _row_of_cars(seed: int, off_row: int, along: float = 2.5):
    """A row of 12 parked cars 5 m apart, placed well across the row but poorly along it
    (standard deviation ``along`` metres: every car's gate reaches past its neighbours), and
    ``off_row`` objects placed well beside the row; the second map shifted 20 m and turned 30°.
    Ids: object ``k`` is ``100 + k`` in the first map and ``500 + k`` in the second."""
    rng = np.random.default_rng(seed)
    cars = 12
    row = np.column_stack([np.arange(cars) * 5.0, np.zeros(cars), np.zeros(cars)])
    beside = _scene(rng, off_row, extent=40.0, spacing=6.0) + np.array([0.0, 8.0, 0.0])
    world = np.vstack([row, beside])
    loose = np.diag([along**2, SIGMA**2, SIGMA**2])
    covs = np.array([loose if k < cars else SIGMA**2 * np.eye(3) for k in range(len(world))])

    def summary(robot, first_id, T=None):
        noise = np.array([rng.multivariate_normal(np.zeros(3), c) for c in covs])
        s = ObjectSummary(robot, np.arange(len(world)) + first_id, world + noise, covs)
        return s if T is None else s.transformed(T)

    return summary(1, 100), summary(2, 500, _pose(30.0, (20.0, 0.0, 0.0)))


def test_an_answer_holds_min_inliers_pairs_told_apart_from_their_neighbours():
    # the consistent set is the row and the objects beside it; the separation test leaves out
    # the cars (their gates span the next car). Four objects beside the row are fewer than an
    # answer needs: no answer (it used to be 'matched' with those four pairs in half the scenes)
    need = AssociationSettings().min_inliers
    for seed in range(10):
        a, b = _row_of_cars(seed, off_row=4)
        result = associate(a, b)
        assert result.status == "too-few" and len(result.pairs) == 0, (seed, result.pairs)
        # eight beside the row are an answer: those eight (or one car more), all right
        a, b = _row_of_cars(seed, off_row=8)
        result = associate(a, b)
        assert result.matched and len(result.pairs) >= need, (seed, result.status)
        assert np.all(result.pairs[:, 1] - result.pairs[:, 0] == 400)


def test_the_shared_frame_tells_a_regular_grid_apart():
    # the grid of the test above in one world frame: by shape a shift by a cell is as good an
    # answer, under the frame only the right one is allowed
    x, y = np.meshgrid(np.arange(8) * 5.0, np.arange(8) * 5.0)
    grid = np.column_stack([x.ravel(), y.ravel(), np.zeros(64)])
    rng = np.random.default_rng(2)
    a = _summary(0, np.arange(64), grid, rng, sigma=0.05)
    b = _summary(1, np.arange(40) + 100, grid[:40], rng, sigma=0.05)
    assert not associate(a, b).matched
    framed = AssociationSettings(frame_probability=0.99999)
    result = associate(a, b, framed)
    assert result.matched
    np.testing.assert_array_equal(result.pairs[:, 1], result.pairs[:, 0] + 100)
    assert len(result.pairs) >= 30
    # the same from the other end
    np.testing.assert_array_equal(associate(b, a, framed).pairs, result.pairs[:, ::-1])
    # maps whose frames disagree by far more than their covariances: nothing is allowed
    moved = b.transformed(_pose(0.0, (2.5, 2.5, 0.0)))
    assert not associate(a, moved, framed).matched


def test_frame_probability_is_a_probability():
    for bad in (0.0, 1.0, 1.5, float("nan")):
        with pytest.raises(InputError, match="frame_probability"):
            AssociationSettings(frame_probability=bad)
    assert AssociationSettings().frame_threshold is None


def test_frame_scale_is_a_robust_scale_never_below_one():
    rng = np.random.default_rng(0)
    chi2 = rng.chisquare(3, 400)
    assert frame_scale(np.zeros(0)) == 1.0
    assert frame_scale(0.2 * chi2) == 1.0  # maps better than their covariances: the test stays
    assert 0.8 < frame_scale(chi2) < 1.25
    assert 16.0 * 0.8 < frame_scale(16.0 * chi2) < 16.0 * 1.25
    # a minority of wrong pairs far off moves it little
    spoiled = np.concatenate([16.0 * chi2, np.full(40, 1e6)])
    assert frame_scale(spoiled) < 16.0 * 1.4
    for bad in (0.5, float("nan"), float("inf")):
        with pytest.raises(InputError, match="frame_scale"):
            AssociationSettings(frame_scale=bad)


def _drifting_grid(shift: float, seed: int = 2):
    """The 8 × 8 grid of objects 5 m apart in one world frame: the first map holds all of them;
    the second its first 40 (``b``) and then all of them (``later``), the 24 objects seen
    later off by ``shift`` metres along x and y that the covariances do not tell (the drift
    of noisy odometry the standard linearisation does not account for). Object ``k`` is ``k``
    in the first map and ``100 + k`` in the second."""
    x, y = np.meshgrid(np.arange(8) * 5.0, np.arange(8) * 5.0)
    grid = np.column_stack([x.ravel(), y.ravel(), np.zeros(64)])
    rng = np.random.default_rng(seed)
    a = _summary(0, np.arange(64), grid, rng, sigma=0.05)
    later = _summary(1, np.arange(64) + 100, grid, rng, sigma=0.05)
    later = ObjectSummary(
        1, later.ids, later.means + (np.arange(64) >= 40)[:, None] * [shift, shift, 0.0], later.covs
    )
    b = ObjectSummary(1, later.ids[:40], later.means[:40], later.covs[:40])
    return a, b, later


def _full_association(table: CorrespondenceTable, a: ObjectSummary, b: ObjectSummary) -> None:
    """A link's full association as a robot runs it: once more when it taught the table a
    larger frame scale, then merged."""
    result = associate(a, b, table.current_settings())
    if table.learn_frame(result, a, b):
        result = associate(a, b, table.current_settings())
    table.merge(result, a, b)


def _right(table: CorrespondenceTable) -> bool:
    pairs = table.pairs()
    return bool(np.all(pairs[:, 1] == pairs[:, 0] + 100))


def test_a_link_learns_the_scale_of_maps_overconfident_against_each_other():
    # the later objects' squared distance between the maps: about (2 · 0.35²) / (2 · 0.05²) =
    # 49 against the covariances' 3 (a factor of 16), beyond the frame's χ²₃ quantile
    a, b, later = _drifting_grid(0.35)
    framed = AssociationSettings(frame_probability=0.99999)
    table = CorrespondenceTable(a.robot, b.robot, framed)
    _full_association(table, a, b)
    assert len(table) >= 36 and _right(table)
    assert table.frame_scale == 1.0  # nothing to learn from before the link held an answer
    # with the frame taken at its word, the later objects are refused
    plain = associate(a, later, framed)
    assert np.count_nonzero(plain.pairs[:, 0] >= 40) <= 4
    # the link learns the scale from the answer's pairs and accepts them
    _full_association(table, a, later)
    assert 8.0 < table.frame_scale < 32.0
    assert np.count_nonzero(table.pairs()[:, 0] >= 40) >= 20 and _right(table)
    # maps whose frames disagree by half a cell are still refused with the learned scale
    learned = table.current_settings()
    assert learned.frame_scale == table.frame_scale
    assert associate(a, b, learned).matched
    moved = b.transformed(_pose(0.0, (2.5, 2.5, 0.0)))
    assert not associate(a, moved, learned).matched


def test_the_scale_is_not_learned_by_consistent_maps_nor_without_a_frame():
    a, b, later = _drifting_grid(0.0)
    framed = AssociationSettings(frame_probability=0.99999)
    table = CorrespondenceTable(a.robot, b.robot, framed)
    assert not table.learn_frame(associate(a, b, framed), a, b)  # no pair held yet
    _full_association(table, a, b)
    _full_association(table, a, later)
    assert len(table) >= 60 and _right(table)
    assert table.frame_scale < 2.0
    free = CorrespondenceTable(a.robot, b.robot)
    _full_association(free, a, b)
    _full_association(free, a, later)
    assert free.frame_scale == 1.0 and free.current_settings() is free.settings


def _reference_consistent_with(a, b, rows, cols, held_rows, held_cols, settings):
    """consistent_with as the block of the distances among both sets (pair_distances)."""

    def block(summary, x, y):
        both = np.concatenate([x, y])
        dist, var = pair_distances(summary.means[both], summary.covs[both])
        return dist[: x.size, x.size :], var[: x.size, x.size :]

    d_a, v_a = block(a, rows, held_rows)
    d_b, v_b = block(b, cols, held_cols)
    var = v_a + v_b + 0.25 * settings.drift_ratio**2 * (d_a + d_b) ** 2
    distinct = (rows[:, None] != held_rows[None, :]) & (cols[:, None] != held_cols[None, :])
    return distinct & ((d_a - d_b) ** 2 <= settings.consistency_threshold * var)


def test_distances_computed_alone_equal_their_definitions_bit_for_bit():
    """The nearest and anchor distances and the consistency of a few pairs with a set are
    computed without the all-pairs temporaries, and give the very numbers of their
    definitions (the same decisions downstream)."""
    from teamslam.association.consistency import consistent_with
    from teamslam.association.distances import anchor_distance, nearest_distance

    rng = np.random.default_rng(21)
    settings = AssociationSettings()
    for trial in range(60):
        n = 1 if trial % 10 == 0 else int(rng.integers(2, 120))
        means = rng.normal(size=(n, 3)) * rng.uniform(0.01, 500.0)
        anchors = rng.normal(size=(int(rng.integers(1, 40)), 3)) * 30.0
        np.testing.assert_array_equal(
            anchor_distance(means, anchors),
            np.min(np.linalg.norm(means[:, None] - anchors[None], axis=2), axis=1),
        )
        d2 = np.einsum("abi,abi->ab", means[:, None] - means[None], means[:, None] - means[None])
        np.fill_diagonal(d2, np.inf)
        np.testing.assert_array_equal(nearest_distance(means), np.sqrt(d2.min(axis=1)))
        if n < 4:
            continue
        m = int(rng.integers(4, 60))
        noise = rng.normal(size=(m, 3, 3)) * 0.1
        a = ObjectSummary(0, np.arange(n), means, np.tile(0.01 * np.eye(3), (n, 1, 1)))
        b = ObjectSummary(
            1,
            np.arange(m),
            rng.normal(size=(m, 3)) * 20.0,
            noise @ noise.swapaxes(1, 2) + np.eye(3),
        )
        k, h = int(rng.integers(1, min(n, m))), int(rng.integers(1, min(n, m)))
        rows, cols = rng.choice(n, k, replace=False), rng.choice(m, k, replace=False)
        held_rows, held_cols = rng.choice(n, h, replace=False), rng.choice(m, h, replace=False)
        for x, y in ((held_rows, held_cols), (rows, cols)):  # against the held, among themselves
            np.testing.assert_array_equal(
                consistent_with(a, b, rows, cols, x, y, settings),
                _reference_consistent_with(a, b, rows, cols, x, y, settings),
            )


def test_an_extension_of_few_new_objects_decides_as_one_gated_whole(monkeypatch):
    """An extension whose new objects are few first gates them alone and stops when none of
    them has a partner in the gate; what it decides equals the decision from the whole gate,
    pairs, distances under the identity and the frame's verdicts alike."""
    from teamslam.association import table as table_module

    a, b, _, _ = _two_maps(seed=0, yaw=30.0, shift=(20.0, 0.0, 0.0))
    a, b = a.sorted(), b.sorted()
    full = associate(a, b)
    assert full.matched and full.first == a.robot
    held = full.pairs[:8]
    settings = AssociationSettings()
    rng = np.random.default_rng(4)
    found = 0
    for trial in range(12):
        share = 0.02 if trial % 3 == 0 else 0.12
        fresh = (rng.random(len(a)) < share, rng.random(len(b)) < share)
        assert 2 * table_module._fresh_cells(fresh) < len(a) * len(b)  # the few-new path
        few = table_module._extend(a, b, held, settings, None, fresh)
        with monkeypatch.context() as patch:
            patch.setattr(table_module, "_fresh_cells", lambda fresh: 10**12)  # whole gate
            whole = table_module._extend(a, b, held, settings, None, fresh)
        for x, y in zip(few, whole, strict=True):
            np.testing.assert_array_equal(x, y)
        found += len(few[0])
    assert found > 0  # some trials add pairs: the comparison is not of empty answers only
