"""How overconfident own-tracked objects are, learned from two robots' estimates of one object.

Simulated pairs whose squared Mahalanobis distances are ``κ · χ²(3)`` give back ``κ`` within the
sampling error of a median, also when the samples were taken under other factors; consistent
pairs give 1; the factor multiplies only the box's own part of the variance; the agent learns it
from its links' tables, uses it for new boxes, keeps it in its snapshot, and leaves rows
computed exactly as before while it is 1 or switched off.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import stats

from teamslam.association import CorrespondenceTable
from teamslam.gaussian import chi2_quantile
from teamslam.msckf.filter.box_noise import (
    FormedUnder,
    Overconfidence,
    box_rows,
    box_variances,
    mixture_factor,
    overconfidence_factor,
)

MEDIAN = chi2_quantile(0.5, 3)


def _median_sd(kappa: float, n: int) -> float:
    """Asymptotic standard deviation of ``median(κ χ²₃ samples) / median(χ²₃)`` for ``n``."""
    density = stats.chi2.pdf(MEDIAN, 3)
    return kappa / (MEDIAN * 2.0 * density * np.sqrt(n))


def _pairs(d2: np.ndarray, start: int = 0) -> dict[tuple[int, int], float]:
    return {(start + i, 1000 + start + i): float(v) for i, v in enumerate(d2)}


@pytest.mark.parametrize("kappa", [4.0, 30.0, 150.0])
def test_a_known_factor_is_recovered_within_its_sampling_error(kappa):
    n = 150
    errors = []
    for seed in range(20):
        d2 = kappa * np.random.default_rng(seed).chisquare(3, n)
        learner = Overconfidence()
        assert learner.add(1, _pairs(d2), 1.0) == n
        errors.append((learner.kappa - kappa) / _median_sd(kappa, n))
    errors = np.array(errors)
    assert np.all(np.abs(errors) < 4.0)
    assert abs(errors.mean()) < 4.0 / np.sqrt(errors.size)  # no bias beyond sampling


def test_consistent_pairs_give_one():
    learned = []
    for seed in range(100):
        d2 = np.random.default_rng(seed).chisquare(3, 60)
        learned.append(overconfidence_factor(d2))
    learned = np.array(learned)
    assert np.all(learned >= 1.0)
    # the sign test at 0.99: the covariances are taken as right in all but about 1 in 100
    assert np.mean(learned > 1.0) <= 0.05
    assert overconfidence_factor(np.zeros(0)) == 1.0


def test_few_samples_do_not_depart_from_one():
    # even six distances far beyond χ²(3): a sign test at 0.99 needs seven
    assert overconfidence_factor(np.full(6, 500.0)) == 1.0
    assert overconfidence_factor(np.full(7, 500.0)) == pytest.approx(500.0 / MEDIAN)


def test_samples_taken_under_another_factor_count_at_the_true_one():
    rng = np.random.default_rng(3)
    kappa, n = 40.0, 300
    learner = Overconfidence()
    for part, in_force in enumerate((1.0, 10.0, 40.0)):
        # covariances formed under `in_force` are that many times larger: d² shrinks by it
        d2 = kappa / in_force * rng.chisquare(3, n // 3)
        learner.add(part, _pairs(d2), in_force)
    assert abs(learner.kappa - kappa) < 4.0 * _median_sd(kappa, n)


def test_a_pair_keeps_its_first_sample_and_a_minority_of_wrong_pairs_moves_little():
    rng = np.random.default_rng(5)
    kappa, n = 20.0, 200
    d2 = kappa * rng.chisquare(3, n)
    d2[:20] = 1e6  # a tenth of the pairs wrong
    learner = Overconfidence()
    learner.add(2, _pairs(d2), 1.0)
    first = learner.kappa
    # the same pairs again (after consensus averaged them: tiny distances) change nothing
    assert learner.add(2, _pairs(np.full(n, 0.01)), 1.0) == 0
    assert learner.kappa == first
    # a tenth wrong moves the median to the clean samples' 0.5 / 0.9 quantile, within the
    # sampling error
    shifted = kappa * stats.chi2.ppf(0.5 / 0.9, 3) / MEDIAN
    sd = _median_sd(kappa, n - 20)
    assert kappa - 4.0 * sd <= first <= shifted + 4.0 * sd
    # the same pair ids on another link are other samples
    assert learner.add(3, _pairs(d2[:5]), 1.0) == 5


def _own_samples(rng, kappa, n_right, n_wrong, n_others=12):
    """A robot's own re-identifications: ``n_right`` pairs of one object (``κ χ²(3)``) and
    ``n_wrong`` look-alikes far from it, each with its call's other candidates (objects
    elsewhere, ``d²`` spread over two orders of magnitude around 10⁵)."""

    def elsewhere(size):
        return np.exp(rng.normal(np.log(1e5), 1.2, size))

    d2 = np.concatenate([kappa * rng.chisquare(3, n_right), elsewhere(n_wrong)])
    others = [elsewhere(n_others) for _ in range(d2.size)]
    pairs = _pairs(d2)
    return pairs, dict(zip(pairs, others, strict=True))


@pytest.mark.parametrize("kappa", [1.0, 30.0, 300.0])
def test_own_reidentifications_learn_the_factor_when_most_pair_two_objects(kappa):
    """Two in three samples pair look-alikes: the median is theirs, the mixture finds the
    right pairs' factor (and 1 when they are consistent)."""
    learned = []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        pairs, others = _own_samples(rng, kappa, 15, 30)
        learner = Overconfidence()
        assert learner.add(-1, pairs, 1.0, others) == 45
        learned.append(learner.kappa)
        assert overconfidence_factor(np.array(list(pairs.values()))) > 10.0 * kappa
    learned = np.array(learned)
    if kappa == 1.0:
        assert np.mean(learned > 1.0) <= 0.2
        assert np.all(learned < 5.0)
    else:
        # 15 right samples: the scale of χ²(3) within a factor of two, every seed
        assert np.all((learned > kappa / 2.0) & (learned < 2.0 * kappa)), learned
        assert abs(np.log(np.median(learned) / kappa)) < np.log(1.3)


def test_own_samples_without_alternatives_must_be_right_and_links_keep_the_median():
    rng = np.random.default_rng(9)
    d2 = 40.0 * rng.chisquare(3, 60)
    learner = Overconfidence()
    learner.add(-1, _pairs(d2), 1.0, {})  # no call had another candidate
    assert abs(learner.kappa - 40.0) < 4.0 * _median_sd(40.0, 60) + 10.0
    links = Overconfidence()
    links.add(2, _pairs(d2), 1.0, _own_samples(rng, 1.0, 60, 0)[1])  # ignored for links
    assert not links.alternatives
    assert links.kappa == overconfidence_factor(d2)


def test_samples_added_one_by_one_give_the_mixture_of_all_of_them():
    """The learner keeps each own sample's kernel sum as samples come: after every addition,
    one pair at a time (some without alternatives, some from the links, each under its own
    factor), and after a snapshot, its factor is the one :func:`mixture_factor` finds from all
    the samples at once."""
    for seed in range(4):
        rng = np.random.default_rng(seed)
        learner = Overconfidence()
        for i in range(25):
            key = (i, 1000 + i)
            if rng.random() < 0.2:
                learner.add(1, {key: float(rng.chisquare(3))}, 1.0)
                continue
            d2 = 30.0 * rng.chisquare(3) if rng.random() < 0.5 else np.exp(rng.uniform(2, 11))
            others = np.exp(rng.uniform(2.0, 11.0, rng.integers(0, 30)))
            given = None if rng.random() < 0.1 else {key: others}
            learner.add(-1, {key: float(d2)}, float(rng.uniform(1.0, 3.0)), given)
            own = np.array([v for k, v in learner.samples.items() if k[0] < 0])
            links = np.array([v for k, v in learner.samples.items() if k[0] >= 0])
            alternatives = list(learner.alternatives.values())
            expected = max(overconfidence_factor(links), mixture_factor(own, alternatives))
            assert learner.kappa == expected
        assert Overconfidence.from_arrays(learner.arrays()).kappa == learner.kappa


def test_arrays_round_trip():
    learner = Overconfidence()
    learner.add(1, _pairs(np.arange(1.0, 30.0) * 10.0), 2.0)
    again = Overconfidence.from_arrays(learner.arrays())
    assert again.samples == learner.samples
    assert again.kappa == learner.kappa > 1.0
    with pytest.raises(ValueError, match="pairs"):
        Overconfidence.from_arrays({"keys": np.zeros((2, 3)), "values": np.zeros(1)})
    own = Overconfidence()
    pairs, others = _own_samples(np.random.default_rng(4), 30.0, 15, 30)
    own.add(-1, pairs, 2.0, others)
    again = Overconfidence.from_arrays(own.arrays())
    assert again.kappa == own.kappa > 1.0
    assert again.alternatives.keys() == own.alternatives.keys()
    for key, values in own.alternatives.items():
        np.testing.assert_array_equal(again.alternatives[key], values)
    broken = own.arrays()
    broken["alternative_counts"] = broken["alternative_counts"][1:]
    with pytest.raises(ValueError, match="alternative"):
        Overconfidence.from_arrays(broken)


def test_the_factor_multiplies_only_the_boxs_own_part():
    z = np.array([[5.0, 240.0, -3.0, 240.0], [320.0, 240.0, 300.0, 240.0]])
    sizes = np.array([[20.0, 10.0], [30.0, 40.0]])
    rows = box_rows(z, sizes, (640, 480), 0.5, 0.05)
    assert rows[0, 6:10].any() and not rows[1, 6:10].any()
    std, share = 0.5, 0.05
    plain = box_variances(rows, std, share)
    own = std**2 + share**2 * np.concatenate([sizes, sizes], axis=1) ** 2
    scaled = box_variances(rows, std, share, 7.0)
    np.testing.assert_allclose(scaled - plain, 6.0 * own, rtol=1e-12)
    np.testing.assert_allclose(box_variances(rows, std, share, 1.0), plain, rtol=1e-15)


def test_an_association_table_shows_its_frame_samples_read_only():
    table = CorrespondenceTable(0, 1)
    samples = table.frame_samples()
    assert dict(samples) == {}
    with pytest.raises(TypeError):
        samples[(1, 2)] = 3.0  # type: ignore[index]


class _Table:
    def __init__(self, samples):
        self._samples = samples

    def frame_samples(self):
        return self._samples


def test_the_agent_learns_from_its_links_and_scales_new_boxes():
    from teamslam.datasets.identity import strip_object_ids
    from teamslam.msckf.agent import MsckfAgent
    from teamslam.msckf.configure import build_settings
    from teamslam.sim.lissajous import lissajous_team

    team = lissajous_team(robots=2, steps=30, objects=60, seed=1)
    stripped = strip_object_ids(team, to="none")
    robots = []
    for robot in stripped.robots:  # boxes of 40 × 30 pixels
        det = robot.detections
        sizes = np.tile([40.0, 30.0], (det.measurements.shape[0], 1))
        robots.append(replace(robot, detections=replace(det, sizes=sizes)))
    stripped = replace(stripped, robots=robots)
    settings = build_settings(stripped, calibrate="never")
    config = settings.config
    config = replace(config, filter=replace(config.filter, object_size_share=0.01))
    agent = MsckfAgent(0, stripped.calibration, stripped.robots[0], config)
    plain = MsckfAgent(0, stripped.calibration, stripped.robots[0], config)
    assert agent.tracker is not None and agent._kappa is None
    rng = np.random.default_rng(0)
    agent.learn_overconfidence({1: _Table(_pairs(25.0 * rng.chisquare(3, 80)))})
    assert agent._kappa is not None and agent._kappa > 5.0
    kappa = agent._kappa
    plain.learn_overconfidence({1: _Table(_pairs(rng.chisquare(3, 80)))})
    assert plain._kappa is None  # consistent pairs: the calibrated noise
    # new boxes count κ times the box part: the objects' covariances grow by about κ
    for t in range(stripped.robots[0].frames):
        agent.step(t)
        plain.step(t)
    common = np.intersect1d(agent.state.object_ids, plain.state.object_ids)
    assert common.size >= 5
    a_covs = agent.state.object_covs()[agent.state.object_slots(common)]
    p_covs = plain.state.object_covs()[plain.state.object_slots(common)]
    grown = np.trace(a_covs, axis1=1, axis2=2) / np.trace(p_covs, axis1=1, axis2=2)
    assert np.median(grown) > 0.5 * kappa
    # the snapshot keeps it
    other = MsckfAgent(0, stripped.calibration, stripped.robots[0], config)
    other.restore(agent.snapshot())
    assert other._kappa == kappa
    assert other.overconfidence.samples == agent.overconfidence.samples
    # switched off: nothing learned, boxes keep the calibrated noise
    off = replace(config, filter=replace(config.filter, object_overconfidence=False))
    quiet = MsckfAgent(0, stripped.calibration, stripped.robots[0], off)
    quiet.learn_overconfidence({1: _Table(_pairs(25.0 * rng.chisquare(3, 80)))})
    assert quiet._kappa is None and len(quiet.overconfidence) == 0
    # with ids given (no tracker) nothing is learned either
    given = MsckfAgent(0, team.calibration, team.robots[0], config)
    given.learn_overconfidence({1: _Table(_pairs(25.0 * rng.chisquare(3, 80)))})
    assert given._kappa is None


def test_an_objects_widening_is_kappa_times_the_mean_inverse_factor_of_its_boxes():
    formed = FormedUnder()
    formed.add(np.array([1, 2]), 1.0, boxes=3)  # both initialised before any factor
    formed.add(np.array([2, 3]), 50.0, boxes=1)
    formed.add(np.array([3]), 100.0, boxes=1)
    r = formed.widening(np.array([1, 2, 3, 4]), 100.0)
    # 1: all boxes under 1 → κ; 2: (3/1 + 1/50) / 4 boxes; 3: (1/50 + 1/100) / 2; 4: unknown
    np.testing.assert_allclose(r, [100.0, 100 * (3 + 1 / 50) / 4, 100 * (1 / 50 + 1 / 100) / 2, 1])
    # formed entirely under the factor in force: not widened; never below 1
    assert formed.widening(np.array([3]), 50.0)[0] == 1.0
    formed.merge(3, 1)  # 3 is 1 seen again: its boxes are 1's
    assert 3 not in formed.boxes and formed.boxes[1] == [5.0, 3.0 + 1 / 50 + 1 / 100]
    back = FormedUnder.from_arrays(formed.arrays())
    assert back.boxes == formed.boxes
