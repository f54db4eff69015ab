"""Consensus by intersection (``consensus.rule = ci`` / ``ici``): consistent, and less diluted
than the fixed-weight average.

Two robots share a common prior of the objects and measure them with independent noise, so the
error covariance of any fusion that is linear in their estimates is known exactly: the fused
covariance must contain it (Loewner order), be tighter than the equal-weight average (the
paper's rule for two robots) and stay close to the better marginal when one robot knows much
more. The plain sum of informations (independent fusion) fails the first check on the same
draws, so the check can fail.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest

from teamslam.errors import InputError
from teamslam.msckf.consensus.intersection import intersection_fusion
from teamslam.msckf.consensus.messages import CommonMarginalMessage, MapIdsMessage
from teamslam.msckf.consensus.protocol import ConsensusProtocol
from teamslam.msckf.consensus.rules import IntersectionRule, consensus_rule
from teamslam.msckf.filter.state import MsckfState
from teamslam.msckf.settings.values import MsckfConfig
from test_hybrid_consensus import consensus_agent

DIM = 6  # two objects


def _spd(rng, n, scale=1.0):
    a = rng.standard_normal((n, n))
    return scale * (a @ a.T / n + 0.2 * np.eye(n))


def _two_robots(rng):
    """A common prior ``N(m0, P0)`` of the objects and two independent measurements.

    Returns the two posteriors' informations and the joint covariance of their errors: with
    ``e0 = m0 − x`` and ``Ω_i = P0⁻¹ + H_iᵀ R_i⁻¹ H_i``, ``e_i = Σ_i (P0⁻¹ e0 + H_iᵀ R_i⁻¹ v_i)``.
    """
    p0 = _spd(rng, DIM, 4.0)
    info0 = np.linalg.inv(p0)
    maps, infos = [], []
    for _ in range(2):
        rows = int(rng.integers(3, DIM + 1))
        h = rng.standard_normal((rows, DIM))
        r = np.diag(rng.uniform(0.2, 1.0, rows))
        info = info0 + h.T @ np.linalg.solve(r, h)
        cov = np.linalg.inv(info)
        # e_i = [Σ_i P0⁻¹ | Σ_i Hᵀ R⁻¹] [e0; v_i]
        maps.append((cov @ info0, cov @ h.T @ np.linalg.inv(r), r))
        infos.append(info)
    (a0, av, ra), (b0, bv, rb) = maps
    cross = a0 @ p0 @ b0.T  # the common prior is all they share
    cov_a = a0 @ p0 @ a0.T + av @ ra @ av.T
    cov_b = b0 @ p0 @ b0.T + bv @ rb @ bv.T
    joint = np.block([[cov_a, cross], [cross.T, cov_b]])
    return infos[0], infos[1], joint


def _linear_map(info_a, info_b, kind):
    """``(G_a, G_b)`` with fused mean ``= G_a μ_a + G_b μ_b`` (the weight depends on the
    covariances only, so the fusion is linear in the means)."""
    eye = np.eye(DIM)
    g_a = np.column_stack(
        [intersection_fusion(e, info_a, info_b, np.zeros(DIM), kind)[0] for e in eye]
    )
    g_b = np.column_stack(
        [intersection_fusion(np.zeros(DIM), info_a, info_b, info_b @ e, kind)[0] for e in eye]
    )
    return g_a, g_b


def _error_covariance(g_a, g_b, joint):
    g = np.hstack([g_a, g_b])
    return g @ joint @ g.T


@pytest.mark.parametrize("kind", ["ci", "ici"])
@pytest.mark.parametrize("seed", range(6))
def test_fusion_contains_the_true_error_covariance_and_is_tighter_than_the_average(kind, seed):
    rng = np.random.default_rng(seed)
    info_a, info_b, joint = _two_robots(rng)
    _, cov, info, omega = intersection_fusion(np.zeros(DIM), info_a, info_b, np.zeros(DIM), kind)
    assert 0.0 <= omega <= 1.0
    np.testing.assert_allclose(cov @ info, np.eye(DIM), atol=1e-9)
    true = _error_covariance(*_linear_map(info_a, info_b, kind), joint)
    scale = np.abs(true).max()
    # consistent: the claimed covariance contains the actual error covariance
    assert np.linalg.eigvalsh(cov - true).min() > -1e-9 * scale
    # tighter than the equal-weight average (eq. 19 with A = 1/2) ...
    average = np.linalg.inv(0.5 * (info_a + info_b))
    assert np.linalg.slogdet(cov)[1] < np.linalg.slogdet(average)[1] - 1e-6
    # ... and never worse than either robot alone (the weight minimises the determinant)
    for own in (info_a, info_b):
        assert np.linalg.slogdet(info)[1] >= np.linalg.slogdet(own)[1] - 1e-9
    # the independent fusion double counts the common prior: it fails the same check
    naive = np.linalg.inv(info_a + info_b)
    g_a, g_b = naive @ info_a, naive @ info_b
    assert np.linalg.eigvalsh(naive - _error_covariance(g_a, g_b, joint)).min() < -1e-6 * scale


def test_inverse_intersection_is_tighter_than_covariance_intersection():
    for seed in range(6):
        info_a, info_b, _ = _two_robots(np.random.default_rng(seed))
        ci = intersection_fusion(np.zeros(DIM), info_a, info_b, np.zeros(DIM), "ci")[1]
        ici = intersection_fusion(np.zeros(DIM), info_a, info_b, np.zeros(DIM), "ici")[1]
        assert np.linalg.slogdet(ici)[1] < np.linalg.slogdet(ci)[1]


@pytest.mark.parametrize("kind", ["ci", "ici"])
def test_monte_carlo_nees_of_the_fusion_is_at_most_one(kind):
    """The same property by sampling: NEES per dimension over 4000 draws of the truth, the
    common prior and the measurements (the fused mean is linear in the two means)."""
    rng = np.random.default_rng(11)
    p0 = _spd(rng, DIM, 4.0)
    info0 = np.linalg.inv(p0)
    hs = [rng.standard_normal((4, DIM)) for _ in range(2)]
    rs = [np.diag(rng.uniform(0.2, 1.0, 4)) for _ in range(2)]
    infos = [info0 + h.T @ np.linalg.solve(r, h) for h, r in zip(hs, rs, strict=True)]
    draws = 4000
    x = rng.multivariate_normal(np.zeros(DIM), p0, draws)
    m0 = x + rng.multivariate_normal(np.zeros(DIM), p0, draws)  # the common prior's mean
    means = []
    for h, r, info in zip(hs, rs, infos, strict=True):
        z = x @ h.T + rng.multivariate_normal(np.zeros(4), r, draws)
        means.append(np.linalg.solve(info, (m0 @ info0 + z @ np.linalg.solve(r, h)).T).T)
    g_a, g_b = _linear_map(infos[0], infos[1], kind)
    cov = intersection_fusion(np.zeros(DIM), infos[0], infos[1], np.zeros(DIM), kind)[1]
    err = means[0] @ g_a.T + means[1] @ g_b.T - x
    nees = np.einsum("ki,ki->k", err, np.linalg.solve(cov, err.T).T) / DIM
    assert np.mean(nees) < 1.0 + 3 * np.sqrt(2.0 / (DIM * draws))
    # and not absurdly conservative either (the fusion uses what the robots know)
    assert np.mean(nees) > 0.3


@pytest.mark.parametrize("kind", ["ci", "ici"])
def test_a_far_better_marginal_is_kept_and_an_estimate_fused_with_itself_is_unchanged(kind):
    rng = np.random.default_rng(3)
    info_b = _spd(rng, DIM)
    info_a = 1e4 * _spd(rng, DIM)  # robot a knows every direction far better
    mean_a = rng.standard_normal(DIM)
    mean_b = rng.standard_normal(DIM)
    mean, _, info, _ = intersection_fusion(mean_a, info_a, info_b, info_b @ mean_b, kind)
    # within 2 % of the better robot's information in every direction
    relative = np.linalg.eigvals(np.linalg.solve(info_a, info))
    assert np.all(np.abs(relative.real - 1.0) < 0.02)
    assert np.linalg.norm(mean - mean_a) < 0.02 * np.linalg.norm(mean_b - mean_a)
    mean, _, info, _ = intersection_fusion(mean_a, info_a, info_a, info_a @ mean_a, kind)
    np.testing.assert_allclose(mean, mean_a, atol=1e-9)
    np.testing.assert_allclose(info, info_a, rtol=1e-9, atol=1e-9 * np.abs(info_a).max())


def _agent(robot, mean, cov, rule):
    ids = np.arange(10, 10 + DIM // 3, dtype=np.int64)
    full = np.zeros((6 + DIM, 6 + DIM))
    full[:6, :6] = 1e-2 * np.eye(6)
    full[6:, 6:] = cov
    state = MsckfState.from_arrays(np.eye(4), [0], ids, mean.reshape(-1, 3), full)
    return consensus_agent(robot, state, rule)


def _exchange(protocols, step):
    n = len(protocols)
    everyone = np.arange(n)
    boxes = defaultdict(list)
    for i in range(n):
        for m in protocols[i].requests(step, everyone[everyone != i]):
            boxes[m.receiver].append(m)
    replies = defaultdict(list)
    for i in range(n):
        for m in protocols[i].answer([m for m in boxes[i] if isinstance(m, MapIdsMessage)]):
            replies[m.receiver].append(m)
    for i in range(n):
        assert all(isinstance(m, CommonMarginalMessage) for m in replies[i])
        protocols[i].average(replies[i])


@pytest.mark.parametrize("rule", ["ci", "ici"])
def test_a_team_of_three_never_exceeds_the_centralised_information_and_beats_the_average(rule):
    """Three robots, a common prior, a direct measurement each per step, an exchange per step:
    every robot's information stays below the centralised fusion's (nothing counted twice)
    and above the plain average's."""
    rng = np.random.default_rng(5)
    truth = rng.standard_normal(DIM)
    prior_cov = np.diag(rng.uniform(0.5, 2.0, DIM))
    prior_mean = truth + rng.multivariate_normal(np.zeros(DIM), prior_cov)
    teams = {
        name: [_agent(i, prior_mean, prior_cov, name) for i in range(3)]
        for name in (rule, "average")
    }
    protocols = {
        name: [ConsensusProtocol(a, [j for j in range(3) if j != a.robot]) for a in agents]
        for name, agents in teams.items()
    }
    central = np.linalg.inv(prior_cov)
    for step in range(1, 7):
        for i in range(3):
            draw = np.random.default_rng([step, i])
            rows = int(draw.integers(2, DIM))
            h = draw.standard_normal((rows, DIM))
            noise = np.diag(draw.uniform(0.05, 0.5, rows))
            z = h @ truth + draw.multivariate_normal(np.zeros(rows), noise)
            central = central + h.T @ np.linalg.solve(noise, h)
            for agents in teams.values():
                state = agents[i].state
                jacobian = np.zeros((rows, state.dim))
                jacobian[:, 6:] = h
                state.update(jacobian, z - h @ state.objects.ravel(), noise)
        for team in protocols.values():
            _exchange(team, step)
        scale = np.abs(central).max()
        for a, b in zip(teams[rule], teams["average"], strict=True):
            info = np.linalg.inv(a.state.cov[6:, 6:])
            plain = np.linalg.inv(b.state.cov[6:, 6:])
            assert np.linalg.eigvalsh(central - info).min() > -1e-9 * scale
            assert np.linalg.slogdet(info)[1] > np.linalg.slogdet(plain)[1]
            assert a.counters["intersection_fusions"] > 0
            assert a.counters["intersection_fallbacks"] == 0


def test_the_rule_names_and_their_settings_are_checked():
    assert isinstance(consensus_rule("ici"), IntersectionRule)
    assert consensus_rule("ci").name == "ci"
    MsckfConfig.from_settings({"consensus.rule": "ici"})
    with pytest.raises(InputError, match="needs joint marginals"):
        MsckfConfig.from_settings({"consensus.rule": "ici", "consensus.per_object": True})
    with pytest.raises(InputError, match="ci, ici"):
        MsckfConfig.from_settings({"consensus.rule": "intersection"})
