"""The association between robots with appearance: fewer pairs, never chance look-alikes.

Two maps that share three objects answer from those three when the objects look alike and the
descriptors separate objects; a wrong but consistent triangle of look-alikes between two
unrelated places is refused. Without appearance, or with descriptors that are all equal, the
association and the estimates are those of the position-only rules, bit for bit. Summaries with
appearance survive the wire (a truncated one is refused) and per-object descriptors survive
storage and the renumbering of ids.
"""

from __future__ import annotations

import itertools
import json
from dataclasses import replace

import numpy as np
import pytest

from teamslam.association import (
    AssociationResult,
    AssociationSettings,
    CorrespondenceTable,
    ObjectSummary,
    associate,
)
from teamslam.association.answer import FrameHistory, identified_by_frame
from teamslam.association.appearance import (
    AppearanceModel,
    chance_tail,
    distance_counts,
    link_model,
    rarity,
    unit_rows,
)
from teamslam.association.gate import frame_allowed
from teamslam.association.summary import (
    BYTES_PER_OBJECT,
    descriptor_codes,
    descriptors_from_codes,
)
from teamslam.datasets import load_dataset, save_dataset
from teamslam.datasets.identity import strip_object_ids
from teamslam.datasets.storage import FORMAT_VERSION
from teamslam.geometry import so3
from teamslam.graph import ring
from teamslam.msckf import config_for, run_team
from teamslam.msckf.consensus.messages import MapIdsMessage
from teamslam.runtime.wire import WireError, decode, encode, team_id
from teamslam.sim import lissajous_team

DIM = 16
NOISE = 0.1


def _transform(yaw: float, shift: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = so3.exp(np.array([0.0, 0.0, yaw]))
    t[:3, 3] = shift
    return t


def _same_counts(rng: np.random.Generator, looks: np.ndarray, n: int = 60) -> np.ndarray:
    """Samples of the distance between two noisy copies of one descriptor (held pairs)."""
    k = rng.integers(0, len(looks), n)
    a = looks[k] + NOISE * rng.standard_normal((n, DIM)) / np.sqrt(DIM)
    b = looks[k] + NOISE * rng.standard_normal((n, DIM)) / np.sqrt(DIM)
    return distance_counts(1.0 - np.einsum("pd,pd->p", unit_rows(a), unit_rows(b)))


def _looks(rng, n: int, types: int | None) -> tuple[np.ndarray, np.ndarray]:
    """Unit descriptors of two maps' ``n`` objects: each its own, or drawn from ``types``
    look-alike types."""
    if types is None:
        return unit_rows(rng.standard_normal((n, DIM))), unit_rows(rng.standard_normal((n, DIM)))
    kinds = unit_rows(rng.standard_normal((types, DIM)))
    return kinds[rng.integers(0, types, n)], kinds[rng.integers(0, types, n)]


def _maps(seed: int, types: int | None, shared_geometry: bool, shared_objects: bool):
    """Two maps of 30 objects each, small covariances, in the second robot's frame turned and
    shifted. The second map holds a triangle congruent to three objects of the first. With
    ``shared_objects`` they are the same objects (descriptors noisy copies of the first's);
    otherwise the two maps are unrelated places and the triangle's descriptors match the
    first's by chance: each object's descriptor is one of ``types`` look-alike types."""
    rng = np.random.default_rng(seed)
    n = 30
    # objects spread far apart, so that only the triangle (20 m across) is a consistent set
    a_means = rng.uniform(0.0, 400.0, (n, 3)) * [1, 1, 0.01]
    a_means[:3] = rng.uniform(0.0, 20.0, (3, 3)) * [1, 1, 0.1]
    looks_a, looks_b = _looks(rng, n, types)
    b_local = rng.uniform(0.0, 400.0, (n, 3)) * [1, 1, 0.01] + [1000.0, 0.0, 0.0]
    triangle = [0, 1, 2]
    if shared_geometry:
        b_local[:3] = a_means[triangle]
        looks_b[:3] = looks_a[triangle]
    looks_b = looks_b + NOISE * rng.standard_normal((n, DIM)) / np.sqrt(DIM)
    looks_a = looks_a + NOISE * rng.standard_normal((n, DIM)) / np.sqrt(DIM)
    t = _transform(0.7, np.array([5.0, -3.0, 0.0]))
    b_means = b_local @ t[:3, :3].T + t[:3, 3]
    covs = np.tile(0.01**2 * np.eye(3), (n, 1, 1))
    ids_a = np.arange(100, 100 + n)
    ids_b = np.arange(500, 500 + n)
    same = _same_counts(rng, np.concatenate([looks_a, looks_b]))
    a = ObjectSummary(0, ids_a, a_means, covs, appearance=looks_a, same_counts=same)
    b = ObjectSummary(1, ids_b, b_means, covs, appearance=looks_b, same_counts=same)
    truth = np.column_stack([ids_a[:3], ids_b[:3]]) if shared_objects else np.zeros((0, 2))
    return a, b, truth


def _without(summary: ObjectSummary) -> ObjectSummary:
    return replace(summary, appearance=None, same_counts=None)


def test_three_shared_objects_answer_with_appearance_and_not_without():
    a, b, truth = _maps(seed=1, types=None, shared_geometry=True, shared_objects=True)
    settings = AssociationSettings()
    assert settings.min_inliers > 3
    alone = associate(_without(a), _without(b), settings)
    assert not alone.matched  # three pairs: too few by position alone
    result = associate(a, b, settings)
    assert result.matched, result.status
    np.testing.assert_array_equal(result.pairs, truth)
    # seen from the other end: the same pairs
    back = associate(b, a, settings)
    np.testing.assert_array_equal(back.pairs, truth[:, ::-1])


def test_a_consistent_triangle_of_chance_lookalikes_is_refused(monkeypatch):
    """Two unrelated places whose objects come in three look-alike types: the second holds a
    triangle congruent to one of the first, of matching types. The descriptors match, but
    within each map look-alikes are common: the three pairs are not beyond chance."""
    a, b, _ = _maps(seed=2, types=3, shared_geometry=True, shared_objects=False)
    result = associate(a, b)
    assert not result.matched
    assert result.pairs.size == 0
    # it is the chance bound that refuses it: without it the triangle would be the answer
    monkeypatch.setattr("teamslam.association.answer.chance_tail", lambda *args: 0.0)
    wrong = associate(a, b)
    assert wrong.matched and len(wrong.pairs) == 3
    monkeypatch.undo()
    # the same triangle with objects that only the same object resembles is an answer
    a, b, truth = _maps(seed=2, types=None, shared_geometry=True, shared_objects=True)
    np.testing.assert_array_equal(associate(a, b).pairs, truth)


def test_unrelated_places_with_equal_looking_objects_give_no_answer():
    a, b, _ = _maps(seed=3, types=None, shared_geometry=False, shared_objects=False)
    equal = np.ones_like(a.appearance)
    result = associate(replace(a, appearance=equal), replace(b, appearance=equal))
    assert not result.matched


def test_useless_or_absent_appearance_gives_the_position_only_answer():
    a, b, _ = _maps(seed=4, types=None, shared_geometry=True, shared_objects=True)
    # a larger shared set, so that position alone answers
    rng = np.random.default_rng(4)
    means_b = b.means.copy()
    t = _transform(0.7, np.array([5.0, -3.0, 0.0]))
    means_b[3:9] = a.means[3:9] @ t[:3, :3].T + t[:3, 3] + 0.001 * rng.standard_normal((6, 3))
    b = replace(b, means=means_b)
    reference = associate(_without(a), _without(b))
    assert reference.matched and len(reference.pairs) >= 6
    equal = replace(a, appearance=np.ones_like(a.appearance))
    for first, second in ((equal, replace(b, appearance=np.ones_like(b.appearance))),):
        result = associate(first, second, held=reference.pairs)
        for name in ("status", "candidates", "clique", "rival", "exact", "flipped"):
            assert getattr(result, name) == getattr(reference, name)
        np.testing.assert_array_equal(result.pairs, reference.pairs)
        np.testing.assert_array_equal(result.T_first_second, reference.T_first_second)


def test_the_chance_bound_falls_with_evidence_and_grows_with_the_map():
    rng = np.random.default_rng(5)
    model = AppearanceModel(0.99)
    same = 1.0 - np.cos(0.2 * rng.random(200))
    different = 1.0 - np.cos(np.pi / 2 + 0.3 * rng.standard_normal(2000))
    model.add(same, different)
    assert model.informative
    strong = float(model.log_ratio(np.array([0.001]))[0])
    assert strong > 0
    tails = [chance_tail(model, s * strong, 3, 30) for s in (0.5, 1.0, 2.0, 3.0)]
    assert all(x >= y for x, y in itertools.pairwise(tails))
    assert chance_tail(model, -1e9, 3, 30) == 1.0
    # more objects to choose a look-alike from: a chance set gets further
    assert chance_tail(model, 3 * strong, 3, 300) >= chance_tail(model, 3 * strong, 3, 30)


def test_a_link_with_a_few_dozen_pairs_vetoes_a_pair_that_looks_nothing_alike():
    """A link holding 40 pairs (noisy copies of one descriptor) and maps of 60 objects each:
    most pairs of two unrelated objects (at distances common among different objects and never
    seen among the same ones) are below the veto's odds at ``gate_probability`` — with one
    pseudo-count per bin none was, the prior alone kept each above 1 : 99; every right pair is
    above even odds."""
    rng = np.random.default_rng(5)
    n, held = 60, 40
    looks = unit_rows(rng.standard_normal((n, 32)))
    looks_a = looks + NOISE * rng.standard_normal((n, 32)) / np.sqrt(32)
    looks_b = looks + NOISE * rng.standard_normal((n, 32)) / np.sqrt(32)
    covs = np.tile(0.01 * np.eye(3), (n, 1, 1))
    means = rng.uniform(0.0, 100.0, (n, 3))
    a = ObjectSummary(0, np.arange(n), means, covs, appearance=looks_a)
    b = ObjectSummary(1, np.arange(n) + 1000, means, covs, appearance=looks_b)
    pairs = np.column_stack([np.arange(held), np.arange(held) + 1000])
    settings = AssociationSettings()
    model = link_model(a, b, pairs, settings.consistency_probability)
    assert model.informative and model.same.sum() == held
    veto = np.log1p(-settings.gate_probability) - np.log(settings.gate_probability)
    d = 1.0 - unit_rows(looks_a) @ unit_rows(looks_b).T
    right = model.log_ratio(np.diag(d)[held:])
    wrong = model.log_ratio(d[held:, held:][~np.eye(n - held, dtype=bool)])
    assert np.all(right > 0)
    assert np.mean(wrong < veto) > 0.8, np.mean(wrong < veto)


def test_a_summary_with_appearance_crosses_the_wire():
    ids = np.array([3, 9, 40])
    rng = np.random.default_rng(6)
    summary = ObjectSummary(
        2,
        ids,
        np.arange(9.0).reshape(3, 3),
        np.stack([np.eye(3)] * 3),
        classes=np.array([1, 2, 1]),
        appearance=rng.standard_normal((3, 8)),
        same_counts=np.arange(40),
    )
    team = team_id("appearance")
    message = MapIdsMessage(2, 0, 7, ids, None, summary)
    data = encode(message, team)
    assert len(data) == message.nbytes()
    back = decode(data, team, 3).summary
    np.testing.assert_array_equal(back.appearance, summary.appearance)  # int8 codes both ends
    np.testing.assert_array_equal(back.same_counts, summary.same_counts)
    np.testing.assert_array_equal(back.classes, summary.classes)
    plain = replace(message, summary=replace(summary, classes=None))
    np.testing.assert_array_equal(
        decode(encode(plain, team), team, 3).summary.appearance, summary.appearance
    )
    for cut in (1, 2 * 8, len(data) - 100):
        with pytest.raises(WireError, match=r"truncated|length") as error:
            decode(data[:-cut], team, 3)
        assert "\n" not in str(error.value)
    # a dimension that disagrees with the length (the counts 0 … 39: one varint byte each)
    at = len(data) - 40 - 8 * 3 - 2
    bad = bytearray(data)
    bad[at : at + 2] = (9).to_bytes(2, "little")
    with pytest.raises(WireError, match=r"length|truncated"):
        decode(bytes(bad), team, 3)
    bad[at : at + 2] = (0).to_bytes(2, "little")
    with pytest.raises(WireError, match="dimensions"):
        decode(bytes(bad), team, 3)
    bad = bytearray(data)
    bad[at + 2] = 0x80  # the code -128: outside the symmetric range the sender writes
    with pytest.raises(WireError, match="out of range"):
        decode(bytes(bad), team, 3)


def test_large_same_counts_cross_the_wire_as_varints():
    """Counts of every size up to the wire's uint32 survive, and the bytes counted are the
    bytes encoded."""
    ids = np.array([1, 5])
    counts = np.zeros(40, np.int64)
    counts[[0, 1, 7, 39]] = [127, 128, 2**21, 2**32 - 1]
    summary = ObjectSummary(
        0,
        ids,
        np.zeros((2, 3)),
        np.stack([np.eye(3)] * 2),
        appearance=np.ones((2, 4)),
        same_counts=counts,
    )
    team = team_id("counts")
    message = MapIdsMessage(0, 1, 3, ids, None, summary)
    data = encode(message, team)
    assert len(data) == message.nbytes()
    np.testing.assert_array_equal(decode(data, team, 2).summary.same_counts, counts)
    # 36 zero counts of one byte, 127 in one, 128 in two, 2²¹ in four, 2³² − 1 in five
    assert summary.nbytes == 2 * (BYTES_PER_OBJECT + 4) + 2 + 36 + 1 + 2 + 4 + 5
    bad = bytearray(data)
    bad[-5:] = b"\xff\xff\xff\xff\x7f"  # a count past 32 bits
    with pytest.raises(WireError, match="32 bits"):
        decode(bytes(bad), team, 2)


def test_descriptor_codes_bound_the_direction_and_are_stable():
    """int8 codes move a descriptor's direction by at most √D · p / 127 (p its largest unit
    component), coding the decoded rows again gives the same codes, zero rows stay unknown
    and equal descriptors stay equal."""
    rng = np.random.default_rng(11)
    for dim in (1, 3, 32, 256):
        looks = rng.standard_normal((500, dim)) * rng.uniform(1e-3, 1e3, (500, 1))
        looks[:3] = 0.0
        looks[3:6] = 2.5
        unit = unit_rows(looks)
        back = descriptors_from_codes(descriptor_codes(looks))
        chord = np.linalg.norm(back - unit, axis=1)
        peak = np.max(np.abs(unit), axis=1)
        assert np.all(chord <= np.sqrt(dim) * peak / 127 + 1e-12)
        np.testing.assert_array_equal(descriptor_codes(back), descriptor_codes(looks))
        np.testing.assert_array_equal(back[:3], 0.0)
        np.testing.assert_array_equal(back[4], back[3])
        summary = ObjectSummary(
            0, np.arange(500), np.zeros((500, 3)), np.stack([np.eye(3)] * 500), appearance=looks
        )
        np.testing.assert_array_equal(summary.appearance, back)
        np.testing.assert_array_equal(
            ObjectSummary(
                0, np.arange(500), summary.means, summary.covs, appearance=summary.appearance
            ).appearance,
            back,
        )


def test_descriptor_codes_keep_the_learned_ratio():
    """Coded as the wire carries them, 32-dimensional descriptors seen with noise of their own
    norm (same against different objects: AUC about 0.99) keep the model's AUC within 0.001,
    and the log ratios at the samples move by 0.15 nats or less on average (a sample whose
    distance crosses a bin's edge)."""
    rng = np.random.default_rng(12)
    dim, n = 32, 400
    truth = rng.standard_normal((n, dim))

    def seen():
        size = np.linalg.norm(truth, axis=1, keepdims=True)
        return truth + size * rng.standard_normal((n, dim)) / np.sqrt(dim)

    a, b = seen(), seen()
    off = ~np.eye(n, dtype=bool)

    def model(x, y):
        d = 1.0 - unit_rows(x) @ unit_rows(y).T
        m = AppearanceModel(0.99, prior_weight=1.0)
        m.add(np.diag(d), d[off])
        return m, d

    exact, d = model(a, b)
    coded, d_coded = model(
        descriptors_from_codes(descriptor_codes(a)), descriptors_from_codes(descriptor_codes(b))
    )
    assert 0.95 < exact.auc() < 1.0
    assert abs(coded.auc() - exact.auc()) < 0.001
    for pick in (np.eye(n, dtype=bool), off):
        moved = np.abs(coded.log_ratio(d_coded[pick]) - exact.log_ratio(d[pick]))
        assert np.mean(moved) < 0.15


def test_per_object_appearance_is_stored_and_renumbered(tmp_path):
    team = lissajous_team(robots=2, steps=20, seed=3, landmarks=300, appearance=8)
    for robot in team.robots:
        seen = np.unique(robot.objects.ids)
        np.testing.assert_array_equal(robot.object_appearance_ids, seen)
        assert robot.object_appearance.shape == (seen.size, 8)
    stripped = strip_object_ids(team, seed=1)
    identity = stripped.object_identity  # (robot, new id, old id)
    for i, (before, after) in enumerate(zip(team.robots, stripped.robots, strict=True)):
        rows = identity[identity[:, 0] == i]
        new = after.appearance_of_objects(rows[:, 1])
        old = before.appearance_of_objects(rows[:, 2])
        np.testing.assert_array_equal(new, old)
    # two robots' descriptors of one object are nearer than of two objects
    a, b = team.robots
    common = np.intersect1d(a.object_appearance_ids, b.object_appearance_ids)
    assert common.size >= 3
    da, db = unit_rows(a.appearance_of_objects(common)), unit_rows(b.appearance_of_objects(common))
    cos = da @ db.T
    assert np.all(np.diag(cos) > np.max(cos - 2 * np.eye(common.size), axis=1))
    save_dataset(stripped, tmp_path / "d")
    back = load_dataset(tmp_path / "d")
    assert json.loads((tmp_path / "d" / "manifest.json").read_text())["version"] == FORMAT_VERSION
    for r0, r1 in zip(stripped.robots, back.robots, strict=True):
        np.testing.assert_array_equal(r0.object_appearance_ids, r1.object_appearance_ids)
        np.testing.assert_array_equal(r0.object_appearance, r1.object_appearance)
        assert r1.object_appearance.dtype == np.float32


def test_a_team_with_useless_appearance_runs_as_without_it():
    """Descriptors that are all equal separate nothing: estimates and tables as position-only."""
    team = strip_object_ids(
        lissajous_team(robots=3, steps=40, seed=4, landmarks=500, appearance=8), seed=2
    )
    equal = replace(
        team,
        robots=[
            replace(r, object_appearance=np.ones_like(r.object_appearance)) for r in team.robots
        ],
    )
    none = replace(
        team,
        robots=[
            replace(r, object_appearance=None, object_appearance_ids=None) for r in team.robots
        ],
    )
    settings = {"filter.window": 6, "association.mode": "own"}
    runs = [run_team(d, config_for(d, settings), ring(3), progress=False) for d in (none, equal)]
    for p, q in zip(runs[0].poses, runs[1].poses, strict=True):
        assert p.tobytes() == q.tobytes()
    for p, q in zip(runs[0].objects, runs[1].objects, strict=True):
        assert p.tobytes() == q.tobytes()


def test_a_team_with_appearance_holds_right_pairs_mirrored_at_both_ends():
    """With simulated appearance every link's two ends hold the same pairs, all right ones;
    the summaries carry the descriptors (more bytes than without, less than twice)."""
    from teamslam.eval.metrics import team_metrics

    team = strip_object_ids(
        lissajous_team(robots=4, steps=60, seed=4, landmarks=500, appearance=16), seed=2
    )
    none = replace(
        team,
        robots=[
            replace(r, object_appearance=None, object_appearance_ids=None) for r in team.robots
        ],
    )
    settings = {"filter.window": 6, "association.mode": "own"}
    metrics = {}
    for name, data in (("looks", team), ("none", none)):
        result = run_team(data, config_for(data, settings), ring(4), progress=False)
        metrics[name] = team_metrics(data, result)["association"]
    looks = metrics["looks"]
    assert looks["team"]["wrong"] == 0 and looks["team"]["accepted"] > 0
    assert all(link["ends_agree"] for link in looks["links"].values())
    sent = {k: m["team"]["summary_bytes_per_robot_step"] for k, m in metrics.items()}
    assert sent["none"] < sent["looks"] < 2 * sent["none"]


def _first_contact(summary: ObjectSummary) -> ObjectSummary:
    """The summary as on a link's first exchange with no sample yet of how one object looks
    to two robots (no held pair, no same-object histogram)."""
    return replace(summary, same_counts=None)


def test_a_first_answer_from_three_rare_resemblances():
    """Before a link knows how the same object looks, three consistent pairs whose
    resemblance different objects of either map never reach are an answer: the rarity of a
    resemblance among different objects is the evidence, bounded against chance look-alikes."""
    a, b, truth = _maps(seed=1, types=None, shared_geometry=True, shared_objects=True)
    a, b = _first_contact(a), _first_contact(b)
    settings = AssociationSettings()
    assert not link_model(a, b, None, settings.consistency_probability).informative
    assert not associate(_without(a), _without(b), settings).matched
    result = associate(a, b, settings)
    assert result.matched, result.status
    np.testing.assert_array_equal(result.pairs, truth)
    np.testing.assert_array_equal(associate(b, a, settings).pairs, truth[:, ::-1])


def test_a_first_contact_refuses_a_chance_triangle_of_lookalikes(monkeypatch):
    """Unrelated places whose objects come in three look-alike types, with no sample of the
    same object yet: a congruent triangle of matching types is no answer (look-alikes are
    common among different objects: the resemblance is not rare), and neither is one among
    descriptors that are all equal. It is the chance bound that refuses the first."""
    a, b, _ = _maps(seed=2, types=3, shared_geometry=True, shared_objects=False)
    a, b = _first_contact(a), _first_contact(b)
    result = associate(a, b)
    assert not result.matched and result.pairs.size == 0
    equal = [replace(s, appearance=np.ones_like(s.appearance)) for s in (a, b)]
    assert not associate(*equal).matched
    monkeypatch.setattr("teamslam.association.answer.chance_tail", lambda *args: 0.0)
    monkeypatch.setattr("teamslam.association.appearance.chance_tail", lambda *args: 0.0)
    monkeypatch.setattr("teamslam.association.appearance._tail", lambda *args: 0.0)
    wrong = associate(a, b)
    assert wrong.matched and len(wrong.pairs) == 3


def _one_shared_object(seed: int, types: int | None = None, offset: float = 0.0, shared: int = 1):
    """Two maps of 30 objects each in one world frame (σ 0.3 m), sharing one object (the first
    ``shared``), the others different objects scattered over the same 60 m square (some within
    the frame's gate of one another). The last shared object's second estimate lies ``offset``
    metres from its first. Descriptors as in :func:`_maps` (``types``: look-alike types)."""
    rng = np.random.default_rng(seed)
    n = 30
    a_means = rng.uniform(0.0, 60.0, (n, 3)) * [1, 1, 0.02]
    b_means = rng.uniform(0.0, 60.0, (n, 3)) * [1, 1, 0.02]
    b_means[:shared] = a_means[:shared] + np.array([0.3, -0.15, 0.0])
    b_means[shared - 1, 0] += offset
    looks_a, looks_b = _looks(rng, n, types)
    looks_b[:shared] = looks_a[:shared]
    looks_a = looks_a + NOISE * rng.standard_normal((n, DIM)) / np.sqrt(DIM)
    looks_b = looks_b + NOISE * rng.standard_normal((n, DIM)) / np.sqrt(DIM)
    covs = np.tile(0.3**2 * np.eye(3), (n, 1, 1))
    a = ObjectSummary(0, np.arange(100, 100 + n), a_means, covs, appearance=looks_a)
    b = ObjectSummary(1, np.arange(500, 500 + n), b_means, covs, appearance=looks_b)
    return a, b, np.column_stack([np.arange(100, 100 + shared), np.arange(500, 500 + shared)])


FRAME = AssociationSettings(frame_probability=0.99999)


def test_one_shared_object_that_looks_alike_beyond_chance_is_identified_by_the_shared_frame():
    """Two maps in one world frame share a single object: no consistent set of three exists,
    but the frame is a transform known before any pair. The one pair it allows that looks alike
    beyond what the best of every pair it allows gives by chance is the answer — with or
    without a sample of the same object yet; seen from either end alike."""
    a, b, truth = _one_shared_object(seed=11)
    assert np.count_nonzero(frame_allowed(a, b, FRAME)) > 3  # other hypotheses are in the gate
    for first, second in ((a, b), (_first_contact(a), _first_contact(b))):
        result = associate(first, second, FRAME)
        assert result.matched, result.status
        np.testing.assert_array_equal(result.pairs, truth)
        np.testing.assert_array_equal(result.T_first_second, np.eye(4))
        np.testing.assert_array_equal(associate(second, first, FRAME).pairs, truth[:, ::-1])
    # without appearance one pair is no answer
    assert not associate(_without(a), _without(b), FRAME).matched


def test_one_shared_object_whose_estimates_the_shared_frame_refuses_is_no_answer():
    """The same object with its second estimate 4 m from the first (thirteen σ of each): the
    frame refuses the pair, however alike the two look, and nothing else is taken for it."""
    a, b, _ = _one_shared_object(seed=11, offset=3.7)
    result = associate(a, b, FRAME)
    assert not np.isin(100, result.pairs[:, 0]) and not np.isin(500, result.pairs[:, 1])


def test_one_pair_of_common_lookalikes_in_the_shared_frame_is_no_answer(monkeypatch):
    """Unrelated places whose objects come in three look-alike types, two objects of one type
    in the frame's gate of each other (as alike as one object's two copies): the pair is not
    beyond chance among the pairs the frame allows (look-alikes are common), and is no answer;
    it is the chance bound that refuses it."""
    a, b, _ = _one_shared_object(seed=12, types=3)
    assert not associate(a, b, FRAME).matched
    monkeypatch.setattr("teamslam.association.appearance.chance_tail", lambda *args: 0.0)
    monkeypatch.setattr("teamslam.association.appearance._tail", lambda *args: 0.0)
    assert associate(a, b, FRAME).matched


@pytest.mark.parametrize("offset", [0.0, 3.7])
def test_a_link_takes_a_new_rare_pair_the_shared_frame_admits_and_refuses_one_it_does_not(offset):
    """A link holding two pairs (no transform of its own yet, nothing for an extension to gate
    under) whose maps, in one world frame, now share a third object that looks alike beyond
    chance: the extension takes it, at both ends alike. With the third object's second estimate
    4 m from its first (thirteen σ of each), the frame refuses it and nothing is added."""
    a, b, truth = _one_shared_object(seed=11, offset=offset, shared=3)
    tables = [CorrespondenceTable(0, 1, FRAME), CorrespondenceTable(1, 0, FRAME)]
    first_two = AssociationResult(0, 1, truth[:2], np.eye(4), "matched")
    tables[0].merge(first_two, a, b)
    tables[1].merge(first_two.swapped(), b, a)
    added = tables[0].extend(a, b), tables[1].extend(b, a)
    if offset == 0.0:
        np.testing.assert_array_equal(added[0], truth[2:])
        np.testing.assert_array_equal(tables[0].pairs(), truth)
    else:
        assert added[0].size == 0
        np.testing.assert_array_equal(tables[0].pairs(), truth[:2])
    np.testing.assert_array_equal(tables[1].pairs(), tables[0].pairs()[:, ::-1])


def _lookalike_link(seed: int, exchanges: int, history: bool, pool: int = 12) -> bool:
    """Whether a link ever takes a pair one by one in the shared frame over ``exchanges``
    decisions between two maps of different objects (none shared): ``pool`` places each
    holding an object of either map half a metre apart, 50 m from the next place, each
    object's descriptor its own (three dimensions: chance look-alikes are frequent). At the
    first exchange every estimate is young (σ 1 m): the frame allows the ``pool`` pairs. From
    then on the estimates are sure (σ 5 cm, the pairs beyond the frame's gate) but for one
    place drawn at each exchange whose estimates are young again: one hypothesis per decision,
    the same look-alikes considered again and again. ``history``: the link keeps its decisions
    over the run (:class:`~teamslam.association.answer.FrameHistory`); else each decision is
    held to the setting on its own."""
    rng = np.random.default_rng(seed)
    places = np.column_stack([50.0 * np.arange(pool), np.zeros(pool), np.zeros(pool)])
    looks_a = unit_rows(rng.standard_normal((pool, 3)))
    looks_b = unit_rows(rng.standard_normal((pool, 3)))
    settings = AssociationSettings(frame_probability=0.99999, consistency_probability=0.9)
    decided = FrameHistory() if history else None
    for k in range(exchanges):
        young = np.ones(pool, bool) if k == 0 else np.arange(pool) == rng.integers(pool)
        sigma = np.where(young, 1.0, 0.05)
        covs = sigma[:, None, None] ** 2 * np.eye(3)
        a = ObjectSummary(0, np.arange(pool), places, covs, appearance=looks_a)
        b = ObjectSummary(
            1,
            np.arange(100, 100 + pool),
            places + np.array([0.5, 0.0, 0.0]),
            covs,
            appearance=looks_b,
        )
        rows, _, _ = identified_by_frame(a, b, settings, _DIFFERENT, history=decided)
        if rows.size:
            return True
    return False


def _different_objects_model():
    """The rarity of a resemblance among different objects with three-dimensional descriptors
    of their own: a link's model learned from two maps of 300 objects each."""
    rng = np.random.default_rng(0)
    maps = [
        ObjectSummary(
            r,
            np.arange(300),
            np.zeros((300, 3)),
            np.tile(np.eye(3), (300, 1, 1)),
            appearance=unit_rows(rng.standard_normal((300, 3))),
        )
        for r in (0, 1)
    ]
    return rarity(link_model(maps[0], maps[1], None, 0.9))


_DIFFERENT = _different_objects_model()


def test_a_link_that_decides_again_and_again_takes_a_lookalike_no_more_often_than_the_setting():
    """Over a run of many exchanges between two maps of different objects, some of which look
    alike by chance, the share of runs in which the link ever takes a pair one by one stays
    under ``1 − consistency_probability`` (0.1) when the link spends that chance over its
    decisions on pairs new to it; judged decision by decision (each at the setting, with the
    one pair the frame then allows), the look-alikes get a new chance at every exchange and
    the share grows with the number of exchanges, far beyond the setting."""
    runs = 100
    # the binomial bound: 0.1 of 100 runs exceeds 21 with probability < 0.001
    limit = 21
    bounded = sum(_lookalike_link(s, 40, history=True) for s in range(runs))
    assert bounded <= limit
    once = sum(_lookalike_link(s, 1, history=False) for s in range(runs))
    often = sum(_lookalike_link(s, 40, history=False) for s in range(runs))
    assert once <= limit < often


def test_extensions_limited_to_new_objects_hold_what_full_extensions_hold(monkeypatch):
    """Between whole summaries a link's maps only gain objects (a partial summary carries the
    objects new to the link): an extension decides the pairs with a new object and keeps the
    other decisions. On a team with appearance the tables hold, at the end and step by step
    (the estimates are the same, bit for bit), what extensions deciding every pair again
    hold; and some extensions did have old objects left out."""
    team = strip_object_ids(
        lissajous_team(robots=3, steps=40, seed=4, landmarks=500, appearance=8), seed=2
    )
    settings = {"filter.window": 6, "association.mode": "own"}
    fresh = CorrespondenceTable._fresh
    limited = []

    def counted(self, own, their):
        masks = fresh(self, own, their)
        limited.append(masks is None or not (masks[0].all() and masks[1].all()))
        return masks

    monkeypatch.setattr(CorrespondenceTable, "_fresh", counted)
    runs = [run_team(team, config_for(team, settings), ring(3), progress=False)]
    assert any(limited)
    monkeypatch.setattr(
        CorrespondenceTable,
        "_fresh",
        lambda self, own, their: (np.ones(len(own), bool), np.ones(len(their), bool)),
    )
    runs.append(run_team(team, config_for(team, settings), ring(3), progress=False))
    pairs = [
        [{j: link["pairs"] for j, link in robot.items()} for robot in r.extra["association"]]
        for r in runs
    ]
    assert pairs[0] == pairs[1]
    assert any(link for robot in pairs[0] for link in robot.values())
    for p, q in zip(runs[0].poses, runs[1].poses, strict=True):
        assert p.tobytes() == q.tobytes()


def test_a_map_grown_by_a_partial_summary_counts_its_descriptor_distances_as_counted_whole():
    """The histogram of distances between a map's objects, grown by the objects of a partial
    summary (some without a descriptor), equals the one counted on the whole map anew."""
    from teamslam.association.appearance import _within, within_counts

    rng = np.random.default_rng(5)
    looks = unit_rows(rng.standard_normal((40, DIM)))
    looks[[3, 31]] = 0.0  # no descriptor yet
    means = rng.uniform(0.0, 50.0, (40, 3))
    covs = np.tile(0.1 * np.eye(3), (40, 1, 1))
    old = ObjectSummary(0, np.arange(30), means[:30], covs[:30], appearance=looks[:30])
    new = ObjectSummary(0, np.arange(30, 40), means[30:], covs[30:], appearance=looks[30:])
    within_counts(old)
    grown = old.updated(new)
    assert "_grown_from" in grown.__dict__  # counted from the old map's histogram
    whole = ObjectSummary(0, np.arange(40), means, covs, appearance=looks)
    expected = distance_counts(_within(whole.appearance))
    assert expected.sum() == 38 * 37 // 2
    np.testing.assert_array_equal(within_counts(grown), expected)
    assert "_grown_from" not in grown.__dict__


def test_a_whole_summary_grows_the_within_counts_of_the_last_one():
    """A summary that holds every object of its robot's last counted one, with the same
    descriptors, counts the pairs within its map as counting them all would; one that lacks an
    object, or whose descriptor changed, counts them all."""
    from teamslam.association.appearance import _within, within_counts

    rng = np.random.default_rng(22)
    looks = rng.standard_normal((50, DIM))
    looks[3] = 0.0  # not known: no pair

    def summary(rows, appearance=looks):
        rows = np.asarray(rows)
        n = rows.size
        return ObjectSummary(
            7,
            rows * 3,
            np.zeros((n, 3)),
            np.tile(np.eye(3), (n, 1, 1)),
            appearance=appearance[rows],
        )

    first = summary(np.arange(30))
    within_counts(first)
    changed = looks.copy()
    changed[5] += 1.0
    for later in (
        summary(np.arange(45)),
        summary(np.arange(1, 45)),
        summary(np.arange(45), changed),
    ):
        counted = within_counts(later)
        np.testing.assert_array_equal(counted, distance_counts(_within(later.appearance)))
