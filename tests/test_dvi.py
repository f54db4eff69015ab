"""Linear-Gaussian distributed inference: Prop. 3, the distributed KF, App. C, consistency."""

from __future__ import annotations

import numpy as np
import pytest

from teamslam import dvi, graph
from teamslam.dvi import kalman_predict, kalman_update
from teamslam.gaussian import Gaussian, average_common_marginal, chi2_band, nees


@pytest.fixture(scope="module")
def small_problem():
    return dvi.tracking_problem(agents=4, landmarks=3, steps=4, seed=1)


def _split_models(problem):
    return [dvi.split_common_prior(m, problem.n_agents) for m in problem.agents]


def test_batch_lifted_posterior_equals_kalman_filter(small_problem):
    """On a linear model the filter's last estimate equals the batch least-squares solution."""
    p = small_problem
    post, _ = dvi.centralized_lifted_posterior(_split_models(p), p.controls, p.observations)
    means, covs = dvi.run_centralized(p)
    n = p.centralized.dim
    np.testing.assert_allclose(post.mean[-n:], means[-1], atol=1e-8)
    np.testing.assert_allclose(post.cov[-n:, -n:], covs[-1], atol=1e-8)


def test_lifted_matrices_follow_equation_12(small_problem):
    m = small_problem.agents[0]
    lifted = dvi.LiftedModel(m, 3)
    f = m.transition
    f_bar = np.linalg.inv(lifted.f_bar_inv)
    n = m.dim
    # F̄ has F^(i-j) in block (i, j) below the diagonal
    np.testing.assert_allclose(f_bar[3 * n : 4 * n, 0:n], np.linalg.matrix_power(f, 3), atol=1e-9)
    np.testing.assert_allclose(f_bar[2 * n : 3 * n, 0:n], f @ f, atol=1e-9)
    np.testing.assert_allclose(f_bar[2 * n : 3 * n, n : 2 * n], f, atol=1e-9)
    np.testing.assert_allclose(f_bar[0:n, n : 2 * n], 0.0)


def test_info_form_iteration_equals_average_then_prop2(small_problem):
    """Eq. 42 (information form) and eqs. 15 + Prop. 2 + 16 (moment form) are the same step."""
    p = small_problem
    models = _split_models(p)
    local = [dvi.local_posterior(m, p.controls[i], p.observations[i]) for i, m in enumerate(models)]
    init = [
        dvi.LiftedModel(m, p.steps).prior_information(p.controls[i]) for i, m in enumerate(models)
    ]
    ci = dvi.lifted_common_index(models[0], p.steps)
    w = graph.ring(4).weights()
    a = dvi.mirror_descent_step(init, local, w, ci, 0.3)
    b = dvi.mirror_descent_step_moment(init, local, w, ci, 0.3)
    for x, y in zip(a, b, strict=True):
        scale = np.abs(x.info_matrix).max()
        np.testing.assert_allclose(x.info_matrix, y.info_matrix, atol=1e-9 * scale)
        np.testing.assert_allclose(x.moment().mean, y.moment().mean, atol=1e-7)


def test_agents_in_consensus_reach_their_local_posterior_in_one_step(small_problem):
    """Prop. 3 / eq. 17: consensus plus α = 1 gives the local posterior at once."""
    p = small_problem
    models = _split_models(p)
    ci = dvi.lifted_common_index(models[0], p.steps)
    local = [dvi.local_posterior(m, p.controls[i], p.observations[i]) for i, m in enumerate(models)]
    rng = np.random.default_rng(0)
    # different joints that share one marginal over the common block
    shared = Gaussian(rng.normal(size=ci.size), np.eye(ci.size) * 4.0)
    init = []
    for lp in local:
        dim = lp.dim
        a = rng.normal(size=(dim, dim))
        g = Gaussian(rng.normal(size=dim), a @ a.T / dim + np.eye(dim))
        init.append(g.replace_marginal(ci, shared).information())
    out = dvi.mirror_descent_step(init, local, graph.complete(4).weights(), ci, 1.0)
    for got, want in zip(out, local, strict=True):
        np.testing.assert_allclose(got.info_matrix, want.info_matrix, atol=1e-6)
        np.testing.assert_allclose(got.moment().mean, want.moment().mean, atol=1e-6)


@pytest.mark.parametrize("rate", [0.0, 0.4])
def test_mirror_descent_converges_to_centralized_mean(small_problem, rate):
    p = small_problem
    models = _split_models(p)
    ci = dvi.lifted_common_index(models[0], p.steps)
    local = [dvi.local_posterior(m, p.controls[i], p.observations[i]) for i, m in enumerate(models)]
    init = [
        dvi.LiftedModel(m, p.steps).prior_information(p.controls[i]) for i, m in enumerate(models)
    ]
    central, maps = dvi.centralized_lifted_posterior(models, p.controls, p.observations)
    target = central.mean[maps[0][ci]]
    loss = graph.EdgeLoss(graph.ring(4), rate, seed=5)
    states, disagreement = dvi.mirror_descent(
        init, local, ci, 1500, lambda k: loss.step()[1], lambda k: 1.0 / (k + 1)
    )
    errors = [np.linalg.norm(s.moment().mean[ci] - target) for s in states]
    initial_error = max(np.linalg.norm(s.moment().mean[ci] - target) for s in init)
    assert disagreement[-1] < 1e-3 * disagreement[0]
    assert max(errors) < 1e-3 * initial_error
    # monotone in the long run: the last tenth improves on the first tenth
    assert np.mean(disagreement[-150:]) < np.mean(disagreement[:150])


def test_correlated_update_with_zero_correlation_is_the_kalman_filter():
    rng = np.random.default_rng(2)
    a = rng.normal(size=(5, 5))
    p = a @ a.T + np.eye(5)
    mu = rng.normal(size=5)
    h = rng.normal(size=(3, 5))
    v = np.diag([0.5, 1.0, 2.0])
    z = rng.normal(size=3)
    m1, c1 = kalman_update(mu, p, h, z, v)
    m2, c2 = kalman_update(mu, p, h, z, v, correlation=np.zeros((5, 3)))
    k = p @ h.T @ np.linalg.inv(h @ p @ h.T + v)
    np.testing.assert_allclose(m1, mu + k @ (z - h @ mu), atol=1e-12)
    np.testing.assert_allclose(c1, (np.eye(5) - k @ h) @ p, atol=1e-12)
    np.testing.assert_allclose(m2, m1, atol=1e-14)
    np.testing.assert_allclose(c2, c1, atol=1e-14)


def test_correlated_update_equals_conditioning_the_joint():
    """Eqs. 65–67 against brute-force conditioning of (s_t, z_t) built from (s_{t-1}, w, v)."""
    rng = np.random.default_rng(3)
    n, m = 4, 3
    a = rng.normal(size=(n, n))
    sigma = a @ a.T + np.eye(n)
    mu = rng.normal(size=n)
    f = rng.normal(size=(n, n)) * 0.5 + np.eye(n)
    h = rng.normal(size=(m, n))
    # a joint covariance of (w, v) with cross term S
    b = rng.normal(size=(n + m, n + m))
    noise = b @ b.T + 0.5 * np.eye(n + m)
    w, s, v = noise[:n, :n], noise[:n, n:], noise[n:, n:]
    u = rng.normal(size=n)
    # brute force: (s_{t-1}, w, v) ~ N, s_t = F s_{t-1} + u + w, z = H s_t + v
    big_cov = np.zeros((2 * n + m, 2 * n + m))
    big_cov[:n, :n] = sigma
    big_cov[n:, n:] = noise
    big_mean = np.concatenate([mu, np.zeros(n + m)])
    lin = np.zeros((n + m, 2 * n + m))
    lin[:n, :n] = f
    lin[:n, n : 2 * n] = np.eye(n)
    lin[n:, :n] = h @ f
    lin[n:, n : 2 * n] = h
    lin[n:, 2 * n :] = np.eye(m)
    offset = np.concatenate([u, h @ u])
    joint = Gaussian(lin @ big_mean + offset, lin @ big_cov @ lin.T)
    z = rng.normal(size=m)
    want = joint.conditional(np.arange(n, n + m), z)

    mp, pp = kalman_predict(mu, sigma, f, w, u)
    got_mean, got_cov = kalman_update(mp, pp, h, z, v, correlation=s)
    np.testing.assert_allclose(got_mean, want.mean, atol=1e-10)
    np.testing.assert_allclose(got_cov, want.cov, atol=1e-10)
    # and ignoring S would be wrong
    wrong_mean, _ = kalman_update(mp, pp, h, z, v)
    assert np.abs(wrong_mean - want.mean).max() > 1e-3


def test_consensus_between_two_agents_is_equation_19_by_hand():
    rng = np.random.default_rng(4)
    ga, gb = (Gaussian(rng.normal(size=5), np.diag(rng.uniform(1, 3, 5))) for _ in range(2))
    iy = np.array([3, 4])
    msg = dvi.NeighbourMarginal(1, gb.mean[iy], gb.cov[np.ix_(iy, iy)])
    mean, cov = average_common_marginal(ga.mean, ga.cov, iy, 0.5, [(0.5, msg.mean, msg.cov)])
    ia, ib = np.linalg.inv(ga.cov[3:, 3:]), np.linalg.inv(gb.cov[3:, 3:])
    cov_y = np.linalg.inv(0.5 * ia + 0.5 * ib)
    mean_y = cov_y @ (0.5 * ia @ ga.mean[3:] + 0.5 * ib @ gb.mean[3:])
    np.testing.assert_allclose(mean[iy], mean_y, atol=1e-12)
    np.testing.assert_allclose(cov[np.ix_(iy, iy)], cov_y, atol=1e-12)
    # with a block-diagonal joint the private part is untouched
    np.testing.assert_allclose(mean[:3], ga.mean[:3])


def test_distributed_without_edges_equals_separate_and_consensus_helps():
    p = dvi.tracking_problem(agents=4, landmarks=5, steps=30, seed=11)
    lonely = graph.from_edges(4, [])
    alone = dvi.run_distributed(p, graph.EdgeLoss(lonely, 0.0))
    separate = dvi.run_distributed(p, graph.EdgeLoss(graph.ring(4), 0.0), consensus=False)
    together = dvi.run_distributed(p, graph.EdgeLoss(graph.ring(4), 0.0))
    for a, b in zip(alone.means, separate.means, strict=True):
        np.testing.assert_array_equal(a, b)
    iy = p.agents[0].common_index
    truth = p.truth_common[-1]

    def spread(run):
        common = np.stack([m[-1, iy] for m in run.means])
        return np.linalg.norm(common - common.mean(0), axis=1).max()

    def error(run):
        return np.mean([np.linalg.norm(m[-1, iy] - truth) for m in run.means])

    assert spread(together) < 0.2 * spread(separate)
    assert error(together) < error(separate)


def _monte_carlo(runs: int, steps: int):
    central, distributed = [], []
    for seed in range(runs):
        p = dvi.tracking_problem(agents=3, landmarks=4, steps=steps, seed=1000 + seed)
        means, covs = dvi.run_centralized(p)
        truth = np.concatenate(
            [p.truth_private[i] for i in range(p.n_agents)] + [p.truth_common], axis=1
        )
        central.append([nees(means[t], covs[t], truth[t]) for t in range(steps + 1)])
        run = dvi.run_distributed(p, graph.EdgeLoss(graph.path(3), 0.2, seed=seed))
        distributed.append(
            [
                np.mean(
                    [nees(run.means[i][t], run.covs[i][t], p.truth_agent(i)[t]) for i in range(3)]
                )
                for t in range(steps + 1)
            ]
        )
    return np.array(central), np.array(distributed), p.centralized.dim, p.agents[0].dim


def test_nees_monte_carlo():
    """Centralised filter consistent (95% χ² band); distributed never above the upper bound."""
    runs, steps = 300, 12
    central, distributed, dim_c, dim_a = _monte_carlo(runs, steps)
    lo, hi = (dim_c * b for b in chi2_band(dim_c, runs))
    avg = central.mean(axis=0)
    assert lo <= avg[-1] <= hi, (lo, avg[-1], hi)
    assert np.mean((avg < lo) | (avg > hi)) <= 0.2  # 5% expected outside a 95% band
    # the distributed filter's per-agent NEES is averaged over agents too: 3 · runs samples
    upper = dim_a * chi2_band(dim_a, 3 * runs)[1]
    assert np.all(distributed.mean(axis=0) <= upper)
