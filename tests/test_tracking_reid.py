"""Re-identification of a long-unseen object from several boxes of a new one: where one box is
ambiguous, the boxes together name the object that looks alike and fits; a look-alike at a
wrong place, or two equally likely candidates, give no merge; a merge keeps the estimate
consistent; the position's likelihood ratio is learned from the pairs of two objects every call
shows."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from teamslam.errors import InputError
from teamslam.gaussian import chi2_band, chi2_quantile
from teamslam.msckf.filter.box_noise import box_rows, box_variances
from teamslam.msckf.filter.models import observe
from teamslam.msckf.filter.state import MsckfState
from teamslam.msckf.objects.appearance import AppearanceMemory, AppearanceModel
from teamslam.msckf.objects.loop_closure import PositionRatio, difference_d2, revisit_posterior
from teamslam.msckf.objects.tracking import ObjectTracker
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.sim.lissajous import T_CAM_BODY, SimulationConfig

CAMERA = SimulationConfig().camera()
STD, SHARE = 0.5, 0.03
CONFIG = MsckfConfig.from_settings(
    {"filter.object_std": STD, "filter.object_size_share": SHARE, "filter.window": 10}
)
W = CONFIG.filter.odometry_cov()
SIZE = (20.0, 30.0)
DIM = 8
TRUE = np.array([10.0, 1.0, 0.0])  # the revisited object, in front of the camera
OLD_STD = 0.3  # the old objects' uncertainty after the robot drove away [m]


def _look(angle: float) -> np.ndarray:
    """A unit descriptor at ``angle`` from the first axis (in the plane of the first two)."""
    out = np.zeros(DIM)
    out[0], out[1] = np.cos(angle), np.sin(angle)
    return out


def _chord_angle(chord: float) -> float:
    """The angle between two unit vectors ``chord`` apart."""
    return 2.0 * np.arcsin(chord / 2.0)


def _tracker(old: dict[int, np.ndarray]) -> ObjectTracker:
    """A tracker that already learned what alike means: *same* at chords below 0.4, *different*
    at chords of 0.2 to 2 (so at a chord of 0.5 a box is unlike, yet not vetoed), with the old
    objects' summaries and their class 2."""
    tracker = ObjectTracker(0, CAMERA, T_CAM_BODY, CONFIG)
    tracker.appearance = AppearanceModel(CONFIG.tracking.gate_probability)
    same = np.linspace(0.0, 0.4, 400) ** 2 / 2.0  # d = chord² / 2
    different = np.linspace(0.2, 2.0, 1800) ** 2 / 2.0
    tracker.appearance.add(same, different)
    assert tracker.appearance.informative
    tracker.memory = AppearanceMemory(DIM)
    for oid, look in old.items():
        tracker.memory.add(oid, look)
    ids = np.array(sorted(old), np.int64)
    tracker._add_labels(ids, np.full(ids.size, 2))
    return tracker


def _state(old: dict[int, np.ndarray], rng) -> MsckfState:
    """One pose (the truth), the old objects last seen at frame 0, each estimate drawn from its
    covariance ``OLD_STD² I`` about the given position (a consistent filter's)."""
    state = MsckfState(np.eye(4), 0, np.eye(6) * 1e-8)
    for oid, p in old.items():
        estimate = p + rng.normal(scale=OLD_STD, size=3)
        state.add_object(oid, estimate, np.eye(3) * OLD_STD**2, np.zeros((3, state.dim)))
    return state


def _run(tracker, state, rng, look, frames=range(60, 75)):
    """The robot back at the old objects: each frame one box of the true object (noise of the
    box model), its descriptor ``look`` and class 2; a track confirmed enters the state with
    the tracker's point (as the filter's initialisation would), objects named are marked seen.
    Returns the ids given, frame by frame."""
    ids = []
    for t in frames:
        z = observe(CAMERA, T_CAM_BODY, state.current_pose, TRUE[None])
        row = box_rows(z, np.array([SIZE]), None, STD, SHARE)
        row[:, :4] += rng.normal(size=4) * np.sqrt(box_variances(row, STD, SHARE))
        frame = tracker.assign(t, row, np.array([2]), state, W, look[None])
        for tid, _, _ in frame.confirmed:
            k = int(np.flatnonzero(tracker.ids == tid)[0])
            cov = tracker.covs[k]
            state.add_object(tid, tracker.points[k], cov, np.zeros((3, state.dim)))
        named = frame.ids[frame.ids >= 0]
        slots = state.object_slots(named)
        state.mark_seen(slots[slots >= 0], t)
        ids.append(int(frame.ids[0]))
    return ids


def _beside(rng):
    """Object 8 beside the revisited 7 (both in one box's gate), same class, looking unlike it."""
    old = {7: TRUE, 8: TRUE + np.array([0.0, 0.4, 0.0])}
    looks = {7: _look(0.0), 8: _look(_chord_angle(0.5))}
    return _tracker(looks), _state(old, rng)


def test_one_box_is_ambiguous_and_the_boxes_together_name_the_object_that_looks_alike():
    rng = np.random.default_rng(1)
    tracker, state = _beside(rng)
    box_look = _look(_chord_angle(0.05))
    # one box against the old objects: both gated, neither vetoed by its look
    z = observe(CAMERA, T_CAM_BODY, state.current_pose, TRUE[None])
    ratio = tracker._looks(np.array([7, 8]), box_look[None])[1][:, 0]
    assert ratio[0] > 0 > ratio[1] > np.log1p(-0.99) - np.log(0.99)
    assert np.all(np.isfinite(z))
    ids = _run(tracker, state, rng, box_look)
    # the first box was refused (two objects not seen for long in its gate), a track was
    # confirmed, then merged into 7: from then on the boxes are 7's
    assert ids[0] == -1 and tracker.counters["revisits_refused"] >= 1
    assert tracker.counters["objects_merged_by_boxes"] == 1
    ((new, old_id),) = tracker.merged.items()
    assert old_id == 7 and new not in state.object_ids
    merged_at = ids.index(7)
    assert merged_at <= 5 and all(i == 7 for i in ids[merged_at:])
    # every box of the track, the ones before the merge too, is 7's in the record
    assert set(tracker.hypotheses().tolist()) == {7}


def test_two_look_alikes_that_both_fit_give_no_merge():
    rng = np.random.default_rng(2)
    old = {7: TRUE, 9: TRUE + np.array([0.0, 0.2, 0.0])}
    tracker, state = _tracker({7: _look(0.0), 9: _look(0.0)}), _state(old, rng)
    ids = _run(tracker, state, rng, _look(_chord_angle(0.05)))
    assert not tracker.merged and 7 not in ids and 9 not in ids


def test_a_look_alike_at_a_wrong_place_is_not_merged():
    rng = np.random.default_rng(3)
    old = {9: TRUE + np.array([0.0, 3.0, 0.0])}  # alike, same class, ten σ away
    tracker, state = _tracker({9: _look(0.0)}), _state(old, rng)
    ids = _run(tracker, state, rng, _look(_chord_angle(0.05)))
    assert not tracker.merged and 9 not in ids
    assert ids[-1] >= 0 and ids[-1] in state.object_ids  # a new object, kept


def test_a_merge_keeps_the_merged_object_consistent():
    """NEES of the merged object against the truth, over the seeds whose boxes were merged (most:
    in the others one box was alone in 7's gate, or in 8's and refused by its look), in the
    χ²(3) band."""
    nees = []
    for seed in range(40):
        rng = np.random.default_rng(100 + seed)
        tracker, state = _beside(rng)
        _run(tracker, state, rng, _look(_chord_angle(0.05)), frames=range(60, 66))
        if not tracker.merged:
            continue
        assert list(tracker.merged.values()) == [7]
        slot = state.object_slots(np.array([7]))
        e = state.objects[slot[0]] - TRUE
        cov = state.covariance(state.object_columns(slot))[0]
        nees.append(e @ np.linalg.solve(cov, e) / 3.0)
    assert len(nees) >= 20
    lo, hi = chi2_band(3, len(nees), 0.99)
    assert lo <= np.mean(nees) <= hi


def test_difference_d2_uses_the_cross_covariance_and_the_posterior_weighs_the_runner_up():
    # two objects sharing most of their uncertainty (through the pose): their difference is
    # known far better than either
    cov = np.eye(12) * 1e-6
    shared = np.zeros((12, 6))
    shared[6:9, :3] = shared[9:12, :3] = np.eye(3)
    cov += shared @ shared.T
    cov[6:, 6:] += np.eye(6) * 0.01
    state = MsckfState.from_arrays(
        np.eye(4)[None],
        np.array([0]),
        np.array([1, 2]),
        np.array([[5.0, 0.0, 0.0], [5.0, 0.3, 0.0]]),
        cov,
    )
    d2 = difference_d2(state, 1, np.array([2]))
    np.testing.assert_allclose(d2, 0.3**2 / (0.02 + 2e-6))
    # two equal candidates share the revisit; one decisive candidate takes it
    p = revisit_posterior(np.array([5.0, 5.0]), 0.5)
    assert p[0] == p[1] < 0.5
    p = revisit_posterior(np.array([12.0, -3.0]), 0.5)
    assert p[0] > 0.99 > p[1]


def test_revisit_probability_must_be_a_probability():
    with pytest.raises(InputError, match="revisit_probability"):
        MsckfConfig.from_settings({"tracking.revisit_probability": 1.0})


def test_a_checkpoint_mid_revisit_continues_to_the_same_merge():
    rng = np.random.default_rng(1)
    tracker, state = _beside(rng)
    look = _look(_chord_angle(0.05))
    _run(tracker, state, rng, look, frames=range(60, 62))  # a tentative track holds boxes
    resumed = ObjectTracker(0, CAMERA, T_CAM_BODY, CONFIG)
    resumed.load_state(tracker.state_dict())
    assert resumed._boxes.keys() == tracker._boxes.keys() and resumed._boxes
    copy_state = copy.deepcopy(state)
    ids = _run(tracker, state, np.random.default_rng(5), look, frames=range(62, 70))
    again = _run(resumed, copy_state, np.random.default_rng(5), look, frames=range(62, 70))
    assert again == ids and resumed.merged == tracker.merged
    assert list(tracker.merged.values()) == [7]


def test_a_pair_appearance_alone_names_is_a_sample_of_d2_the_gate_does_not_cut():
    """The look-alike ten σ away: not merged, yet appearance and class alone name it, so its
    ``d²`` — far beyond the gate — is a sample of how overconfident the objects are; two
    look-alikes give none (appearance alone does not choose between them)."""
    rng = np.random.default_rng(3)
    old = {9: TRUE + np.array([0.0, 3.0, 0.0])}
    tracker, state = _tracker({9: _look(0.0)}), _state(old, rng)
    seen = {}
    for frames in (range(60, 65), range(65, 70), range(70, 75)):
        _run(tracker, state, rng, _look(_chord_angle(0.05)), frames)
        seen.update(tracker.revisit_d2)
    assert not tracker.merged
    assert seen and {o for _, o in seen} == {9}
    assert min(seen.values()) > tracker.revisit_gate
    off = MsckfConfig.from_settings(
        {
            "filter.object_std": STD,
            "filter.object_size_share": SHARE,
            "filter.window": 10,
            "filter.object_overconfidence": False,
        }
    )
    quiet, state = _tracker({9: _look(0.0)}), _state(old, np.random.default_rng(3))
    quiet.config = off
    _run(quiet, state, np.random.default_rng(3), _look(_chord_angle(0.05)))
    assert not quiet.revisit_d2
    rng = np.random.default_rng(2)
    twins = {7: TRUE, 9: TRUE + np.array([0.0, 0.2, 0.0])}
    tracker, state = _tracker({7: _look(0.0), 9: _look(0.0)}), _state(twins, rng)
    _run(tracker, state, rng, _look(_chord_angle(0.05)))
    assert not tracker.revisit_d2


def test_an_old_object_formed_before_the_factor_is_widened_and_merged():
    """An old object whose covariance is ten times too small (its boxes came before the box
    noise's overconfidence factor of 10 was learned; its error drawn from the covariance it
    should have): as held, its estimate lies beyond the re-identification gate and the
    revisit starts a new object; widened by the factor, it is merged — and an old object
    whose error is beyond even the widened covariance is not."""
    kappa, drawn = 10.0, np.array([0.0, 4.5, 0.0]) * OLD_STD  # 4.5 σ of the held covariance

    def run(widening, offset=drawn):
        state = MsckfState(np.eye(4), 0, np.eye(6) * 1e-8)
        state.add_object(7, TRUE + offset, np.eye(3) * OLD_STD**2, np.zeros((3, state.dim)))
        tracker = _tracker({7: _look(0.0)})
        tracker.widening = widening
        rng = np.random.default_rng(4)
        return tracker, _run(tracker, state, rng, _look(_chord_angle(0.05)), range(60, 70))

    held, _ = run(None)
    assert 7 not in held.hypotheses()
    widened, ids = run(lambda ids: np.where(np.asarray(ids) == 7, kappa, 1.0))
    assert ids[-1] == 7 and set(widened.hypotheses()[-5:].tolist()) == {7}
    # the same widening does not let in an object 4.5 σ off the widened covariance
    far, _ = run(lambda ids: np.where(np.asarray(ids) == 7, kappa, 1.0), drawn * np.sqrt(kappa))
    assert 7 not in far.hypotheses()


def test_difference_d2_widens_each_object_and_their_cross_term_consistently():
    """``D P D`` with ``√r`` on each object: equal factors divide ``d²`` by the factor; unequal
    ones give the congruence's difference covariance, which stays positive definite."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=(12, 12))
    cov = a @ a.T * 1e-3 + np.eye(12) * 1e-4
    state = MsckfState.from_arrays(
        np.eye(4)[None],
        np.array([0]),
        np.array([1, 2]),
        np.array([[5.0, 0.0, 0.0], [5.0, 0.3, 0.1]]),
        cov,
    )
    d2 = difference_d2(state, 1, np.array([2]))
    widened = difference_d2(state, 1, np.array([2]), (4.0, np.array([4.0])))
    np.testing.assert_allclose(widened, d2 / 4)
    r_n, r_o = 2.0, 9.0
    scale = np.sqrt(np.array([r_n] * 3 + [r_o] * 3))
    block = cov[6:, 6:] * scale[:, None] * scale[None, :]
    diff = block[:3, :3] + block[3:, 3:] - block[:3, 3:] - block[3:, :3]
    r = np.array([0.0, -0.3, -0.1])
    expected = r @ np.linalg.solve(diff, r)
    np.testing.assert_allclose(
        difference_d2(state, 1, np.array([2]), (r_n, np.array([r_o]))), expected, rtol=1e-10
    )
    assert expected < d2  # widened: nearer


def test_a_revisit_refused_before_the_factor_was_learned_is_taken_once_it_is():
    """The old object 4.5 σ off its held covariance: while no factor is known the new object
    stays apart (appearance named the old one, the position gate refused it); once the learner
    finds the covariances ten times too small, the pair is taken — after the new object's
    window, its earlier boxes renamed too. A pair whose old object was seen after the new one
    appeared, never in one frame with it, is still one object and taken; a pair the tracker
    named in one frame lapses (one detection per object and frame: two objects)."""
    state = MsckfState(np.eye(4), 0, np.eye(6) * 1e-8)
    offset = np.array([0.0, 4.5, 0.0]) * OLD_STD
    state.add_object(7, TRUE + offset, np.eye(3) * OLD_STD**2, np.zeros((3, state.dim)))
    tracker = _tracker({7: _look(0.0)})
    rng = np.random.default_rng(4)
    _run(tracker, state, rng, _look(_chord_angle(0.05)), range(60, 70))
    assert not tracker.merged and 7 not in tracker.hypotheses()
    ((new, old_id),) = tracker._pending.items()
    assert old_id == 7
    lapsed = copy.deepcopy((tracker, state))
    # 7 seen again while the new object was around, in a frame the new one was not: the new
    # object's track broke and 7's continued, one object under two ids
    state.mark_seen(state.object_slots(np.array([7])), 65)
    tracker._note_together(np.array([7]))
    tracker.widening = lambda ids: np.where(np.asarray(ids) == 7, 10.0, 1.0)
    merged = tracker.reidentify(85, state)  # beyond the new object's window
    assert merged.tolist() == [[new, 7]] and set(tracker.hypotheses().tolist()) == {7}
    assert not tracker._pending
    # the same pair after the tracker named 7 and the new object in one frame: two objects
    other, other_state = lapsed
    other.widening = tracker.widening
    other_state.mark_seen(other_state.object_slots(np.array([7])), 65)
    other._note_together(np.array([new, 7, -1]))
    assert other.reidentify(85, other_state).size == 0 and not other._pending


def test_a_widened_merge_carries_the_offset_the_held_covariances_lack_as_noise():
    """Merging two estimates 4.5 σ apart as if exact moves the pose they share by the whole
    offset's pull; with the factors that widened the gate, the constraint's noise is the part of
    the widened difference covariance the held one lacks, so the update is the Kalman update
    with ``S = D'`` — the pose moves less."""
    from teamslam.msckf.objects.loop_closure import merge_objects

    rng = np.random.default_rng(2)
    a = rng.normal(size=(12, 12))
    cov = a @ a.T * 1e-4 + np.eye(12) * 1e-4
    means = np.array([[5.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    d = cov[6:9, 6:9] + cov[9:, 9:] - cov[6:9, 9:] - cov[9:, 6:9]
    means[0] += np.linalg.cholesky(d) @ np.array([0.0, 4.5, 0.0])

    def merged(factors):
        state = MsckfState.from_arrays(
            np.eye(4)[None], np.array([0]), np.array([1, 2]), means.copy(), cov.copy()
        )
        return merge_objects(state, np.array([[1, 2]]), 5, factors)

    exact, widened = merged(None), merged(np.array([[1.0, 10.0]]))
    scale = np.sqrt(np.r_[np.ones(9), np.full(3, 10.0)])
    wide = (cov * scale[:, None] * scale[None, :])[6:, 6:]
    d_wide = wide[:3, :3] + wide[3:, 3:] - wide[:3, 3:] - wide[3:, :3]
    values, vectors = np.linalg.eigh(d_wide - d)
    noise = (vectors * np.maximum(values, 0)) @ vectors.T
    h = np.zeros((3, 12))
    h[:, 6:9], h[:, 9:] = np.eye(3), -np.eye(3)
    residual = means[1] - means[0]
    expected = cov @ h.T @ np.linalg.solve(d + noise, residual)
    np.testing.assert_allclose(widened, expected, rtol=1e-5, atol=1e-12)
    assert np.linalg.norm(widened[:6]) < np.linalg.norm(exact[:6])


def test_a_merge_carries_the_part_of_the_views_offset_the_pair_shows_as_noise():
    """Two estimates of one object from different views differ by the offset of the points
    their boxes showed. Merged, the constraint's noise on every axis is what of their difference
    their covariance does not explain, ``(|r|² − tr D) / 3``, within the view's bound: the
    update is the Kalman update with ``S = D + v̂ I`` (the tiny relative noise aside), and the
    pose moves less than merged as if exact. Under a smaller bound the bound is the noise; two
    estimates that agree within their covariance merge exactly as without it."""
    from teamslam.msckf.objects.loop_closure import merge_objects

    rng = np.random.default_rng(4)
    a = rng.normal(size=(12, 12))
    cov = a @ a.T * 1e-4 + np.eye(12) * 1e-4
    d = cov[6:9, 6:9] + cov[9:, 9:] - cov[6:9, 9:] - cov[9:, 6:9]
    h = np.zeros((3, 12))
    h[:, 6:9], h[:, 9:] = np.eye(3), -np.eye(3)

    def merged(means, offsets):
        state = MsckfState.from_arrays(
            np.eye(4)[None], np.array([0]), np.array([1, 2]), means.copy(), cov.copy()
        )
        return merge_objects(state, np.array([[1, 2]]), 5, None, offsets)

    apart = np.array([[5.0, 0.3, 0.0], [5.0, 0.0, 0.0]])
    r = apart[0] - apart[1]
    shown = (r @ r - np.trace(d)) / 3.0
    assert shown > 0
    for bound, v in ((1.0, shown), (0.5 * shown, 0.5 * shown)):
        expected = cov @ h.T @ np.linalg.solve(d + v * np.eye(3), -r)
        np.testing.assert_allclose(merged(apart, np.array([bound])), expected, rtol=1e-4)
    exact = merged(apart, None)
    assert np.linalg.norm(merged(apart, np.array([1.0]))[:6]) < 0.5 * np.linalg.norm(exact[:6])
    agree = np.array([[5.0, 0.0, 0.0], [5.0, 0.0, 0.0]])
    agree[0] += np.linalg.cholesky(d) @ np.array([0.5, -0.5, 0.5])  # |r|² < tr D
    np.testing.assert_array_equal(merged(agree, np.array([1.0])), merged(agree, None))


@pytest.mark.parametrize(("off", "merged"), [(0.3, True), (1.5, False)])
def test_an_estimate_off_by_part_of_its_objects_size_is_merged_and_one_beyond_it_is_not(
    off, merged
):
    """The old object's estimate converged on the point its views showed, ``off`` metres from
    the object's centre along y, with a covariance of 2 cm (its boxes' errors persisting, the
    covariance does not show it: 15 σ and 75 σ away). Its boxes and the new ones are 20 × 30 px
    at a disparity of 20 px — an object 0.75 m tall. Off by 0.3 m, within the object, the new
    object's boxes name it and it is merged (the record names them 7); off by 1.5 m, twice the
    object's size, it is not: a look-alike elsewhere."""
    rng = np.random.default_rng(5)
    tracker = _tracker({7: _look(0.0)})
    row = box_rows(
        observe(CAMERA, T_CAM_BODY, np.eye(4), TRUE[None]), np.array([SIZE]), None, STD, SHARE
    )
    disparity = row[:, 0] - row[:, 2]
    tracker.extents.add(np.array([7]), disparity, row)
    state = MsckfState(np.eye(4), 0, np.eye(6) * 1e-8)
    estimate = TRUE + np.array([0.0, off, 0.0])
    state.add_object(7, estimate, np.eye(3) * 0.02**2, np.zeros((3, state.dim)))
    ids = _run(tracker, state, rng, _look(_chord_angle(0.05)))
    size = CAMERA.baseline * SIZE[1] / disparity[0]
    assert np.isclose(size, 0.75)
    assert (set(tracker.merged.values()) == {7}) is merged
    assert (7 in tracker.hypotheses().tolist()) is merged
    assert ids[-1] >= 0  # the boxes named all along


def test_a_pass_goes_on_under_the_old_id_from_the_point_its_own_boxes_show():
    """The old estimate is 0.3 m off the object's centre (its views showed another part), with
    a 2 cm covariance. Once the new object's boxes name it, the boxes still to come show the
    point the new object had (where the filter's old estimate would put them 15 σ off): they
    keep the old id, and no track starts again. A checkpoint taken mid-pass goes on alike."""
    rng = np.random.default_rng(6)
    tracker = _tracker({7: _look(0.0)})
    row = box_rows(
        observe(CAMERA, T_CAM_BODY, np.eye(4), TRUE[None]), np.array([SIZE]), None, STD, SHARE
    )
    tracker.extents.add(np.array([7]), row[:, 0] - row[:, 2], row)
    state = MsckfState(np.eye(4), 0, np.eye(6) * 1e-8)
    state.add_object(7, TRUE + np.array([0.0, 0.3, 0.0]), np.eye(3) * 0.02**2, np.zeros((3, 6)))
    look = _look(_chord_angle(0.05))
    ids = _run(tracker, state, rng, look, frames=range(60, 75))
    merged_at = ids.index(7)
    assert set(tracker.merged.values()) == {7} and 7 in tracker.passes
    resumed = ObjectTracker(0, CAMERA, T_CAM_BODY, CONFIG)
    resumed.load_state(tracker.state_dict())
    assert tracker.shape.same.sum() > 0  # the boxes' shapes: their samples and summaries too
    np.testing.assert_array_equal(resumed.shape.same, tracker.shape.same)
    known = np.array(list(tracker.shape_memory._sums), np.int64)
    np.testing.assert_array_equal(
        resumed.shape_memory.summaries(known), tracker.shape_memory.summaries(known)
    )
    copy_state = copy.deepcopy(state)
    ids += _run(tracker, state, np.random.default_rng(7), look, frames=range(75, 90))
    again = _run(resumed, copy_state, np.random.default_rng(7), look, frames=range(75, 90))
    assert ids[merged_at:] == [7] * (len(ids) - merged_at)
    assert tracker.counters["tracks_started"] == 1
    assert again == ids[15:] and tracker.passes[7][2] == 89
    np.testing.assert_array_equal(resumed.passes[7][0], tracker.passes[7][0])


def _two_objects(rng, size=4000):
    """``d²`` of pairs of two objects: log-uniform from 30 to 10⁵ (objects metres apart)."""
    return np.exp(rng.uniform(np.log(30.0), np.log(1e5), size))


def test_the_position_ratio_favours_a_near_pair_when_two_objects_lie_far_apart():
    ratio = PositionRatio()
    assert np.all(ratio.log_ratio([0.5, 3.0, 50.0]) == 0.0)  # nothing learned: no evidence
    ratio.add(_two_objects(np.random.default_rng(4)))
    near, edge, far = ratio.log_ratio([1.0, chi2_quantile(0.99, 3), 200.0])
    assert near > 5.0 and near > edge and far < -10.0
    # N pairs of two objects testify at most N + 1 to one object
    few = PositionRatio()
    few.add(_two_objects(np.random.default_rng(5), size=3))
    assert np.all(few.log_ratio(np.linspace(0.1, 10.0, 50)) <= np.log(4.0) + 1e-12)


def test_the_position_ratio_is_near_zero_when_two_objects_look_like_one():
    ratio = PositionRatio()
    ratio.add(np.random.default_rng(6).chisquare(3, 20000))
    assert np.all(np.abs(ratio.log_ratio([0.5, 1.0, 3.0, 8.0])) < 0.7)


def test_the_position_ratio_round_trips_and_refuses_malformed_counts():
    ratio = PositionRatio()
    ratio.add(_two_objects(np.random.default_rng(7), size=500))
    ratio.add(np.array([np.nan, -1.0, 0.0, np.inf]))  # not pairs: not counted
    assert len(ratio) == 500
    back = PositionRatio.from_arrays(ratio.arrays())
    d2 = np.array([0.3, 2.0, 9.0, 40.0])
    assert np.array_equal(back.log_ratio(d2), ratio.log_ratio(d2))
    for bad in (ratio.arrays()[:-1], np.where(ratio.arrays() > 0, -1.0, 0.0)):
        with pytest.raises(ValueError, match="position ratio"):
            PositionRatio.from_arrays(bad)


def test_the_tracker_learns_the_position_ratio_from_every_calls_old_objects():
    """Each re-identification call counts the gate's d² of the new object against every old
    object (7 and 8 here), and a checkpoint keeps the counts."""
    rng = np.random.default_rng(1)
    tracker, state = _beside(rng)
    _run(tracker, state, rng, _look(_chord_angle(0.05)))
    calls = len(tracker.position)
    assert calls >= 2 and calls % 2 == 0
    restored = ObjectTracker(0, CAMERA, T_CAM_BODY, CONFIG)
    restored.load_state(tracker.state_dict())
    assert np.array_equal(restored.position.arrays(), tracker.position.arrays())
