"""Each robot's own object tracker: detections without ids in, object ids out.

:meth:`ObjectTracker.assign` predicts every target (state objects, persistent-map objects, the
tracker's own tracks) into the current stereo pair, gates each detection with the filter's
innovation covariance at the ``tracking.gate_probability`` quantile of χ²(4), assigns one-to-one
by global nearest neighbour with miss and birth costs, and names the detections: an object's id,
or a tentative track confirmed after ``M`` detections within ``N`` frames. A false detection no
other confirms never reaches the filter. With ``tracking.loop_closure`` revisits are merged first
(:mod:`teamslam.msckf.objects.loop_closure`); with boxes and appearance, a new object whose boxes
show it to be a long-unseen one is merged into it (:meth:`ObjectTracker.reidentify`), and the
rest of that pass is predicted from the point its own boxes showed (:attr:`ObjectTracker.passes`).
A box's shape (its width to its height) is a cue as its appearance is, its ratio learned alike.
The rules and why: the concept page *Tracking* (``docs/concepts/tracking.md``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numba
import numpy as np
from scipy.optimize import linear_sum_assignment

from teamslam.gaussian import Gaussian, chi2_quantile
from teamslam.geometry.camera import StereoCamera, in_image
from teamslam.msckf.filter.box_noise import (
    ObjectExtents,
    box_variances,
    is_box,
    occlusion_shift,
    occlusion_sigmas,
)
from teamslam.msckf.filter.models import observe_jacobians, points_in_camera
from teamslam.msckf.filter.update import stereo_point
from teamslam.msckf.objects.appearance import (
    AppearanceMemory,
    AppearanceModel,
    cosine_distances,
    unit_rows,
)
from teamslam.msckf.objects.hindsight import UnnamedBoxes, chance_in_gate, hindsight_horizon
from teamslam.msckf.objects.loop_closure import (
    LoopClosure,
    PositionRatio,
    difference_d2,
    merge_objects,
    revisit_posterior,
)
from teamslam.msckf.settings.values import MsckfConfig

__all__ = ["LabelModel", "ObjectTracker", "TrackerFrame", "track_id_base"]


def track_id_base(robot: int) -> int:
    """The first object id robot ``robot``'s tracker gives: ids of different robots never meet
    (equal ids of two robots' own tracks would say nothing)."""
    return (int(robot) + 1) * 10**9


@dataclass
class TrackerFrame:
    """What the tracker decided for one frame.

    Attributes
    ----------
    ids
        ``(D,)`` object id given to each detection, ``-1`` for one the filter does not get
        (a tentative track's, or a rejected one); a box seen in the left image only is named
        too, for the record (the filter's object update needs both images).
    confirmed
        Tracks confirmed this frame: ``(id, frames, measurements)`` of their earlier
        detections, to go into the filter's object history before this frame's.
    merged
        ``(k, 2)`` objects ``(new id, old id)`` merged by loop closure this frame (the new one
        left the state; it is the old one seen again).
    """

    ids: np.ndarray
    confirmed: list[tuple[int, np.ndarray, np.ndarray]] = field(default_factory=list)
    merged: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))


class ObjectTracker:
    """One robot's tracker of its object detections (concept page *Tracking*).

    Parameters
    ----------
    robot
        The robot (its ids start at :func:`track_id_base`).
    camera, T_cam_body
        The stereo rig.
    config
        The filter settings (noise, gate, depth range, ``track_*`` settings).
    views
        ``callable(ids) -> (n, 3)``: from where the robot's cameras saw each object
        (:meth:`ObjectViews.of <teamslam.msckf.filter.views.ObjectViews.of>`), for loop closure to
        refuse the mirror image of a group; ``None``: no views (zeros).
    """

    def __init__(
        self,
        robot: int,
        camera: StereoCamera,
        T_cam_body: np.ndarray,
        config: MsckfConfig,
        views: Callable[[np.ndarray], np.ndarray] | None = None,
        image_size: tuple[int, int] | None = None,
    ) -> None:
        self.camera = camera
        #: ``(width, height)`` of the images in pixels, or ``None`` when the data does not say
        self.image_size = image_size
        self.views = views
        self.T_cam_body = T_cam_body
        self.config = config
        self.hits_needed = config.tracking.confirm_hits or config.objects.init_observations
        self.frames_allowed = config.tracking.confirm_frames or self.hits_needed + 2
        self.gate = chi2_quantile(config.tracking.gate_probability, 4)
        # the rig for the compiled prediction: T_cam_body, K, T_left_right stacked (3 × 4 × 4)
        self._camera_block = np.zeros((3, 4, 4))
        self._camera_block[0] = T_cam_body
        self._camera_block[1, :3, :3] = camera.intrinsics
        self._camera_block[2] = camera.T_left_right
        self.birth_gate = chi2_quantile(config.tracking.birth_probability, 4)
        # a target no deeper than this is behind the camera (not predicted)
        self._min_depth = max(config.objects.min_depth, 1e-3 * camera.baseline) * 0.5
        self.next_id = track_id_base(robot)
        # tracks, as arrays (one row per track)
        self.ids = np.zeros(0, np.int64)
        self.points = np.zeros((0, 3))
        self.covs = np.zeros((0, 3, 3))
        self.first = np.zeros(0, np.int64)
        self.last = np.zeros(0, np.int64)
        self.hits = np.zeros(0, np.int64)
        self.classes = np.zeros(0, np.int64)
        self.confirmed = np.zeros(0, bool)
        # per track the object not seen for N frames its detections were alone in the gate of
        # (-1: none yet, -2: two different ones) and how many of them were
        self.revisit_of = np.zeros(0, np.int64)
        self.revisit_hits = np.zeros(0, np.int64)
        # per track its detections: (frame, measurement, row of the frame's detections)
        self.history: dict[int, list[tuple[int, np.ndarray, int]]] = {}
        # class label of every confirmed id (sorted by id)
        self._label_ids = np.zeros(0, np.int64)
        self._labels = np.zeros(0, np.int64)
        # per id the labels of its detections (box rows): an object's label is their majority
        self._votes: dict[int, dict[int, int]] = {}
        #: how often the detector gives an object's detection another class (box rows)
        self.label_model = LabelModel()
        self.counters: dict[str, int] = {
            "tracks_started": 0,
            "tracks_confirmed": 0,
            "tracks_dropped": 0,
            "detections_assigned": 0,
            "detections_rejected_depth": 0,
            "detections_near_object": 0,
            "revisits_refused": 0,
            "revisits_taken": 0,
            "detections_monocular_named": 0,
        }
        #: per frame the id the filter used each detection as (``-1``: none; a box in the left
        #: image only: its object's, not used); a track's detections before its confirmation
        #: are named when it is confirmed
        self.log: list[np.ndarray] = []
        self._first_logged: int | None = None
        #: every re-identification: ``(frame, row of the frame's detections, object id)`` of a
        #: detection given to an object not seen for ``N`` frames
        self.revisits: list[tuple[int, int, int]] = []
        # every id the tracker created (confirmed) and the frame of its first detection
        self._created_ids: list[int] = []
        self._created_frames: list[int] = []
        #: loop closure in the robot's own map (:mod:`teamslam.msckf.objects.loop_closure`), or None
        self.loop: LoopClosure | None = (
            LoopClosure(gap=config.filter.window) if config.tracking.loop_closure else None
        )
        #: every merged object and the object it continues (new id -> old id)
        self.merged: dict[int, int] = {}
        #: the likelihood ratio of appearance learned so far and every object's and track's
        #: appearance summary (created with the first descriptors, when the data has them)
        self.appearance: AppearanceModel | None = None
        self.memory: AppearanceMemory | None = None
        # a pair whose appearance ratio is below this is refused (the gate's odds)
        p = config.tracking.gate_probability
        self._veto = float(np.log((1.0 - p) / p))
        self._descriptors: np.ndarray | None = None  # this frame's, unit rows
        #: box rows with ``tracking.appearance``: the boxes' shape, as appearance is learned
        #: and used — the unit vector ``(w, h)`` of each box and each object's mean of them
        self.shape = AppearanceModel(config.tracking.gate_probability)
        self.shape_memory = AppearanceMemory(2)
        self._shapes: np.ndarray | None = None  # this frame's, unit rows (a cut box's: zero)
        self._noise: np.ndarray | None = None  # this frame's detections' variances (box rows)
        self._row_width = 4
        # re-identification by several boxes (boxes with appearance): the unit descriptors of
        # every track's boxes and of objects confirmed within the last ``filter.window``
        # frames, and the frame each of those was confirmed
        self._boxes: dict[int, list[np.ndarray]] = {}
        self._confirmed_at: dict[int, int] = {}
        self.revisit_gate = chi2_quantile(config.tracking.gate_probability, 3)
        #: the position difference's likelihood ratio in a re-identification's posterior, its
        #: density for two objects learned from every call's pairs (:meth:`reidentify`)
        self.position = PositionRatio()
        #: with ``filter.object_overconfidence``: ``(new id, old id)`` → ``d²`` of the
        #: re-identifications that appearance and class alone would make, before the position
        #: gate (samples of how overconfident the objects are, not cut by that gate; the agent
        #: takes them each frame, :meth:`reidentify`)
        self.revisit_d2: dict[tuple[int, int], float] = {}
        #: per pair of :attr:`revisit_d2`, the ``d²`` of the other old objects of its call, of
        #: every class (what the pair's looks like when appearance named another object)
        self.revisit_alternatives: dict[tuple[int, int], np.ndarray] = {}
        #: ``callable(ids) -> (len(ids),)`` factors ``r ≥ 1`` by which the covariances of the
        #: state's and the persistent map's objects are too small for the box noise now in
        #: force (:class:`~teamslam.msckf.filter.box_noise.FormedUnder`, set by the agent once
        #: it has learned an overconfidence factor); their covariances are widened by them
        #: in the re-identification's gate (:meth:`reidentify`; ``None``: as held)
        self.widening: Callable[[np.ndarray], np.ndarray] | None = None
        # new object → the long-unseen one appearance and class alone named, refused by the
        # position gate (:meth:`_pending_pairs`)
        self._pending: dict[int, int] = {}
        # per object confirmed within the last ``filter.window`` frames or pending, the ids
        # named in a frame where it was named too since its first box: two objects at once,
        # never one (one detection per object and frame; :meth:`_seen_together`)
        self._together: dict[int, set[int]] = {}
        # the boxes seen in the left image only that no target took, for a track confirmed
        # later to name in hindsight (:meth:`_name_in_hindsight`)
        self.unnamed = UnnamedBoxes()
        #: every target's size over its disparity, from the uncut stereo boxes it took (a box
        #: short of it is taken at the edge an occluder left,
        #: :func:`~teamslam.msckf.filter.box_noise.occlusion_shift`)
        self.extents = ObjectExtents()
        self._occlusion_sigmas = occlusion_sigmas(config.tracking.gate_probability)
        #: per object re-identified in its current pass: the point that pass's boxes show, its
        #: covariance given the pose then and the frame it last took a box (the tracker's
        #: prediction of the object while the pass lasts; :meth:`_follow_passes`)
        self.passes: dict[int, tuple[np.ndarray, np.ndarray, int]] = {}

    # ------------------------------------------------------------------ public
    def assign(
        self,
        t: int,
        z: np.ndarray,
        classes: np.ndarray | None,
        state,
        odometry_cov: np.ndarray,
        appearance: np.ndarray | None = None,
    ) -> TrackerFrame:
        """Name the detections ``z`` (``(D, 4)``; non-finite rows get no id) of frame ``t``.

        Parameters
        ----------
        t
            The frame (after propagation to it).
        z, classes
            The detections and their class labels (``None``: no classes). Box rows
            (:mod:`~teamslam.msckf.filter.box_noise`, ``(D, 10)``) carry each detection's own
            noise; plain rows ``(D, 4)`` share ``filter.object_std``.
        state
            The robot's filter state (:class:`~teamslam.msckf.filter.state.MsckfState` or its
            window).
        odometry_cov
            ``W``, the odometry noise per frame (6×6).
        appearance
            ``(D, K)`` appearance descriptors of the detections, or ``None``; used with
            ``tracking.appearance`` (:mod:`~teamslam.msckf.objects.appearance`).
        """
        self._descriptors = None
        if appearance is not None and self.config.tracking.appearance:
            if self.appearance is None:
                self.appearance = AppearanceModel(self.config.tracking.gate_probability)
                self.memory = AppearanceMemory(np.shape(appearance)[1])
            self._descriptors = unit_rows(appearance)
        self._shapes = None
        if is_box(z) and self.config.tracking.appearance:
            # a box the left image's border cut has the shape of its visible part only
            self._shapes = unit_rows(z[:, 4:6]) * ~z[:, 6:8].any(axis=1)[:, None]
        if self._first_logged is None:
            self._first_logged = t
        self._forget_mapped(state)  # before a loop closure takes a mapped object out
        merged = np.zeros((0, 2), np.int64)
        if self.loop is not None:
            self.loop.travel(t, state.current_pose[:3, 3])
            if self._created_ids and hasattr(state, "retire_objects"):
                merged = self._close_loops(t, state)
        if self._descriptors is not None and is_box(z) and hasattr(state, "retire_objects"):
            merged = np.concatenate([merged, self.reidentify(t, state)])
        # the kept boxes' poses as the state holds them now (merges above may have moved them)
        self.unnamed.update_poses(t, state)
        every = np.full(z.shape[0], -1, np.int64)
        finite = np.all(np.isfinite(z), axis=1)
        index = np.flatnonzero(finite)
        monocular = np.flatnonzero(~finite & np.all(np.isfinite(z[:, :2]), axis=1))
        z_monocular = z[monocular]
        z = z[index]
        d = z.shape[0]
        # per detection the variance of its four coordinates (box rows), else one σ² for all
        self._noise = None
        if is_box(z):
            f = self.config.filter
            self._noise = box_variances(z, f.object_std, f.object_size_share)
        self._row_width = z.shape[1]
        labels = np.full(d, -1, np.int64) if classes is None else np.asarray(classes, np.int64)
        labels = labels[index] if classes is not None else labels
        out = np.full(d, -1, np.int64)
        kinds, target_ids, seen, pred, s, h_point, in_front, target_labels = self._predict(
            t, state, odometry_cov, with_noise=self._noise is None
        )
        n_targets = target_ids.size
        assigned_target = np.full(d, -1, np.int64)
        near_target = np.zeros(d, bool)
        lone_stale = np.full(d, -1, np.int64)  # the long-unseen object a detection is alone for
        looks = None  # (T, D) appearance distances and log-ratios, where both have descriptors
        shapes = None  # the same of the boxes' shapes (SORT keeps a box's w / h too)
        if n_targets and d:
            centres = np.ascontiguousarray(z[:, :4], dtype=float)
            if self._noise is None:
                d2 = _squared_distances(s, pred, centres)  # (T, D)
            else:  # S = H P Hᵀ + R of each detection; a box short of its target: its edge
                r = centres[None] - pred[:, None]  # (T, D, 4)
                expected = [e[:, None] for e in self.extents.expected(target_ids, pred, s)]
                shift, noise = occlusion_shift(
                    expected,
                    z[None],
                    r,
                    self._noise[None],
                    self._noise[None],
                    self._occlusion_sigmas,
                )
                occluded = (shift != 0).any(axis=2)  # (T, D)
                r = r + shift
                # a cut box's centre bounds its object's from one side only
                d2 = _pair_d2(s, _censor(r, self._cut_sides(z)[None]), noise)
            cost = d2 - self.gate
            if classes is None:  # no labels: every pair of a target in front agrees
                agree = in_front[:, None]
            elif self._noise is not None:
                # a detector's boxes: a label is evidence (a detector confuses classes), its
                # −2 log likelihood ratio learned in the run added to the cost; refused at the
                # gate's odds, as appearance
                label_ratio = self.label_model.log_ratio(target_labels, labels)
                agree = in_front[:, None] & (label_ratio >= self._veto)
                cost = cost - 2.0 * label_ratio
            else:
                agree = in_front[:, None] & (
                    (target_labels[:, None] < 0)
                    | (labels[None, :] < 0)
                    | (target_labels[:, None] == labels[None, :])
                )
            if self._descriptors is not None:
                _add_frame_pairs(self.appearance, self._descriptors[index])
                looks = self._looks(target_ids, self._descriptors[index])
                if self.appearance.informative:  # else position alone, as without descriptors
                    agree = agree & (looks[1] >= self._veto)
                    cost = cost - 2.0 * looks[1]
            # the targets seen within the last N frames: tracks, and objects followed frame to frame
            fresh = (kinds == 2) | ((kinds == 0) & (t - seen <= self.frames_allowed))
            if self._shapes is not None:
                _add_frame_pairs(self.shape, self._shapes[index])
                shapes = _compare(self.shape, self.shape_memory, target_ids, self._shapes[index])
                if self.shape.informative:  # frame to frame only: seen again from elsewhere,
                    # a box-shaped object has another width
                    agree = agree & ((shapes[1] >= self._veto) | ~fresh[:, None])
                    cost = cost - 2.0 * np.where(fresh[:, None], shapes[1], 0.0)
            allowed = (d2 <= self.gate) & agree
            inside_birth = d2 <= self.birth_gate
            # pass 1: the targets seen within the last N frames (tracks, and objects followed
            # frame to frame) by global nearest neighbour, a pair kept only when it costs less
            # than leaving the detection to a new track and the target missed (appearance
            # adds −2 log of its likelihood ratio to the cost)
            _nearest_neighbour(allowed & fresh[:, None], cost, assigned_target)
            # pass 1b: a fresh target left without a detection and a detection left outside
            # every gate, inside each other's outer gate (a heavy-tailed detector error) and
            # alone there: the detection is that object's
            left = assigned_target < 0
            if left.any():
                taken = np.zeros(n_targets, bool)
                taken[assigned_target[~left]] = True
                outer = inside_birth & agree & (fresh & ~taken)[:, None] & left[None, :]
                outer &= ~allowed.any(axis=0)[None, :]
                _take_unambiguous(outer, assigned_target)
            # pass 2: the detections left against the objects not seen for N frames (the
            # state's or the persistent map's), each pair only when unambiguous: no other
            # detection in the object's gate, no other target in the detection's (a wrong
            # revisit would pull the whole map; a second object for the same one is safe)
            # (none of it when no object not seen for N frames has a detection in its gate)
            # (appearance may refuse such a pair, at the gate's odds, as any other: its
            # *same* samples are of one pass, the object is seen again from elsewhere)
            stale_pairs = allowed & ~fresh[:, None] & self._can_be_detected(pred)[:, None]
            if stale_pairs.any():
                left = assigned_target < 0
                lone = _alone(stale_pairs, allowed) & left[None, :]
                stale_hits = _take_unambiguous(lone, assigned_target)
                for j in np.flatnonzero(stale_hits).tolist():
                    oid = int(target_ids[assigned_target[j]])
                    self.revisits.append((t, int(index[j]), oid))
                    self._name_in_hindsight(
                        t,
                        self._map_target(t, state, oid, target_labels[assigned_target[j]]),
                        oid,
                        state,
                        odometry_cov,
                    )
                self.counters["revisits_taken"] += int(stale_hits.sum())
                # objects not seen for N frames that had a detection in their gate and took none
                wanted = (stale_pairs & left[None, :]).any(axis=1)
                wanted[assigned_target[stale_hits]] = False
                self.counters["revisits_refused"] += int(wanted.sum())
                # each detection the only one in the gate of an object not seen for N frames, that
                # object alone (of those) in the detection's gate, and no object followed frame to
                # frame holding it in its outer gate: evidence for a track to continue that object
                stale = _alone(stale_pairs)
                owned = inside_birth & agree & (fresh & (kinds < 2))[:, None]
                stale &= ~owned.any(axis=0)[None, :]
                has = stale.any(axis=0)
                lone_stale[has] = target_ids[np.argmax(stale[:, has], axis=0)]
            # a detection in the outer gate of an object followed frame to frame that took no
            # detection, and not given to it (ambiguous), starts no track (one object, one id);
            # a detection near an object that took another one is another object (one
            # detection per object and frame), and objects not seen for N frames block nothing
            blocking = in_front & fresh & (kinds < 2)
            blocking[assigned_target[assigned_target >= 0]] = False
            near_target = np.any(inside_birth & blocking[:, None], axis=0)
        hit = assigned_target >= 0
        self.counters["detections_assigned"] += int(hit.sum())
        if self._noise is not None and hit.any():  # sizes of whole boxes (not cut short)
            whole = hit.copy()
            whole[hit] = ~occluded[assigned_target[hit], np.flatnonzero(hit)]
            taken = assigned_target[whole]
            self.extents.add(target_ids[taken], pred[taken, 0] - pred[taken, 2], z[whole])
        if classes is not None and self._noise is not None and hit.any():
            self._learn_labels(hit, assigned_target, kinds, target_ids, target_labels, labels)
        if self._descriptors is not None and hit.any():
            self._learn(looks, assigned_target, kinds, target_ids, index)
        if self._shapes is not None and hit.any():
            samples = (self.shape, self.shape_memory, self._shapes)
            self._learn_cue(samples, shapes, assigned_target, kinds, target_ids, index)
        mapped = hit & (kinds[np.maximum(assigned_target, 0)] < 2) if n_targets else hit
        out[mapped] = target_ids[assigned_target[mapped]]
        if self.passes and mapped.any():
            self._follow_passes(
                t, z, np.flatnonzero(mapped), assigned_target, target_ids, kinds, (pred, s, h_point)
            )
        frame = TrackerFrame(out, merged=merged)
        self.log.append(every)
        on_track = np.flatnonzero(hit & ~mapped)
        if on_track.size:
            self._update_tracks(
                t,
                z,
                index,
                on_track,
                assigned_target,
                (kinds, pred, s, h_point),
                frame,
                lone_stale,
                (state, odometry_cov),
            )
        self.counters["detections_near_object"] += int((~hit & near_target).sum())
        new = np.flatnonzero(~hit & ~near_target)
        if new.size:
            self._start_tracks(t, z[new], index[new], labels[new], state, lone_stale[new])
        mono_labels = None if classes is None else np.asarray(classes, np.int64)[monocular]
        if monocular.size and n_targets:
            every[monocular] = self._name_monocular(
                t,
                z_monocular,
                mono_labels,
                frame.ids,
                (kinds, target_ids, seen, pred, s, in_front, target_labels),
            )
        self._drop_stale(t)
        every[index] = frame.ids
        frame.ids = every
        self._note_together(every)
        self._keep_unnamed(
            t, monocular, z_monocular, mono_labels, every[monocular], state, odometry_cov
        )
        return frame

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, np.ndarray]:
        """What the tracker learned so far, as arrays (for a checkpoint): its tracks and their
        detections, the next id, the log of ids given, the ids it created, merges and loop
        closure, the class labels' votes and model, the appearance and shape ratios' samples,
        the objects' appearance and shape summaries and the points their passes show.
        :meth:`load_state` continues from it exactly."""
        out = {name: getattr(self, name).copy() for name in _TRACK_ARRAYS}
        out["next_id"] = np.array(self.next_id, np.int64)
        out["first_logged"] = np.array(-1 if self._first_logged is None else self._first_logged)
        out["counter_names"] = np.array(list(self.counters), dtype=str)
        out["counter_values"] = np.array(list(self.counters.values()), np.int64)
        rows = [(tid, f, z, j) for tid, hist in self.history.items() for f, z, j in hist]
        out["history_keys"] = np.array([[r[0], r[1], r[3]] for r in rows], np.int64).reshape(-1, 3)
        width = rows[0][2].size if rows else self._row_width
        out["history_z"] = np.array([r[2] for r in rows], float).reshape(len(rows), width)
        out["log_sizes"] = np.array([a.size for a in self.log], np.int64)
        out["log"] = self.first_ids()
        out["revisits"] = np.array(self.revisits, np.int64).reshape(-1, 3)
        out["created"] = np.array([self._created_ids, self._created_frames], np.int64)
        out["merged"] = self.merges()
        votes = [(o, c, n) for o, counts in self._votes.items() for c, n in counts.items()]
        out["votes"] = np.array(votes, np.int64).reshape(-1, 3)
        out["label_counts"] = np.array(
            [self.label_model.pairs, self.label_model.disagreeing], np.int64
        )
        out["label_frequency"] = self.label_model.frequency.copy()
        if self.loop is not None:
            out.update({f"loop_{k}": v for k, v in self.loop.state_dict().items()})
        if self.appearance is not None:
            out["appearance_counts"] = np.stack([self.appearance.same, self.appearance.different])
            ids, sums = self.memory.arrays()
            out["memory_ids"], out["memory_sums"] = ids, sums
            boxes = [(i, d) for i, rows in self._boxes.items() for d in rows]
            out["boxes_ids"] = np.array([i for i, _ in boxes], np.int64)
            out["boxes_descriptors"] = np.array([d for _, d in boxes], float).reshape(
                len(boxes), self.memory.dimension
            )
            out["confirmed_at"] = np.array(list(self._confirmed_at.items()), np.int64).reshape(
                -1, 2
            )
            out["pending"] = np.array(list(self._pending.items()), np.int64).reshape(-1, 2)
            out["position_counts"] = self.position.arrays()
            out["together_ids"] = np.array(list(self._together), np.int64)
            pairs = [(n, i) for n, ids in self._together.items() for i in sorted(ids)]
            out["together"] = np.array(pairs, np.int64).reshape(-1, 2)
        out.update(self.unnamed.arrays())
        out["extents"] = self.extents.arrays()
        out["shape_counts"] = np.stack([self.shape.same, self.shape.different])
        out["shape_ids"], out["shape_sums"] = self.shape_memory.arrays()
        passes = list(self.passes.items())
        out["passes_ids"] = np.array([[o, v[2]] for o, v in passes], np.int64).reshape(-1, 2)
        out["passes_points"] = np.array([v[0] for _, v in passes], float).reshape(-1, 3)
        out["passes_covs"] = np.array([v[1] for _, v in passes], float).reshape(-1, 3, 3)
        return out

    def load_state(self, state: dict[str, np.ndarray]) -> None:
        """Continue from a :meth:`state_dict` of a tracker with the same settings.

        Raises
        ------
        KeyError
            A state without a part this tracker needs.
        """
        for name in _TRACK_ARRAYS:
            setattr(self, name, np.array(state[name], dtype=getattr(self, name).dtype))
        self.next_id = int(state["next_id"])
        first = int(state["first_logged"])
        self._first_logged = None if first < 0 else first
        names, values = state["counter_names"].tolist(), state["counter_values"].tolist()
        self.counters = dict(zip(names, values, strict=True))
        self.history = {}
        for (tid, f, j), z in zip(state["history_keys"].tolist(), state["history_z"], strict=True):
            self.history.setdefault(tid, []).append((f, z.copy(), j))
        self.log = np.split(np.asarray(state["log"], np.int64), np.cumsum(state["log_sizes"])[:-1])
        self.log = self.log if state["log_sizes"].size else []
        self.revisits = [tuple(r) for r in state["revisits"].tolist()]
        self._created_ids, self._created_frames = (list(r) for r in state["created"].tolist())
        self.merged = dict(state["merged"].tolist())
        self._votes = {}
        for o, c, n in state["votes"].tolist():
            self._votes.setdefault(o, {})[c] = n
        self.label_model = LabelModel()
        self.label_model.pairs, self.label_model.disagreeing = state["label_counts"].tolist()
        self.label_model.frequency = np.array(state["label_frequency"], float)
        self.unnamed = UnnamedBoxes.from_arrays(state, self.config.filter.window)
        self.extents = ObjectExtents.from_arrays(state.get("extents", np.zeros((0, 3))))
        self.shape = AppearanceModel(self.config.tracking.gate_probability)
        self.shape_memory = AppearanceMemory(2)
        if "shape_counts" in state:  # a checkpoint from before shapes has none
            self.shape.add_counts(*np.asarray(state["shape_counts"], float))
            self.shape_memory = AppearanceMemory.from_arrays(
                state["shape_ids"], state["shape_sums"]
            )
        self.passes = {
            int(o): (point.copy(), cov.copy(), int(last))
            for (o, last), point, cov in zip(
                np.asarray(state.get("passes_ids", np.zeros((0, 2))), np.int64).tolist(),
                np.asarray(state.get("passes_points", np.zeros((0, 3))), float),
                np.asarray(state.get("passes_covs", np.zeros((0, 3, 3))), float),
                strict=True,
            )
        }
        if self.loop is not None:
            self.loop.load_state({k[5:]: v for k, v in state.items() if k.startswith("loop_")})
        if "appearance_counts" in state:
            same, different = np.asarray(state["appearance_counts"], float)
            self.appearance = AppearanceModel(self.config.tracking.gate_probability)
            self.appearance.add_counts(same, different)
            self.memory = AppearanceMemory.from_arrays(state["memory_ids"], state["memory_sums"])
            self._boxes = {}
            for i, d in zip(state["boxes_ids"].tolist(), state["boxes_descriptors"], strict=True):
                self._boxes.setdefault(i, []).append(d.copy())
            self._confirmed_at = dict(state["confirmed_at"].tolist())
            self._pending = dict(np.asarray(state.get("pending", np.zeros((0, 2)))).tolist())
            self.position = PositionRatio()
            if "position_counts" in state:  # a checkpoint from before has none
                self.position = PositionRatio.from_arrays(state["position_counts"])
            self._together = {int(n): set() for n in state.get("together_ids", [])}
            for n, i in np.asarray(state.get("together", np.zeros((0, 2)))).tolist():
                self._together[int(n)].add(int(i))

    def _name_monocular(self, t, z, labels, taken, targets) -> np.ndarray:
        """Ids of the boxes seen in the left image only (``z`` ``(M, ·)``, right columns NaN):
        each one the object or confirmed track seen within the last ``N`` frames that took no
        detection this frame (``taken``), by its left-image distance
        ``d² = rᵀ (S + R)⁻¹ r`` over ``(u_l, v_l)`` gated at the ``tracking.gate_probability``
        quantile of χ²(2) and global nearest neighbour, as stereo boxes (labels as there); ``-1``
        for none. Named for the record (:attr:`log`): the filter's object update needs both
        images."""
        kinds, target_ids, seen, pred, s, in_front, target_labels = targets
        confirmed_tracks = self.ids[self.confirmed]
        known = ((kinds == 0) & (t - seen <= self.frames_allowed)) | (
            (kinds == 2) & np.isin(target_ids, confirmed_tracks)
        )
        known &= in_front & ~np.isin(target_ids, taken[taken >= 0])
        out = np.full(z.shape[0], -1, np.int64)
        if not known.any():
            return out
        rows = np.flatnonzero(known)
        if is_box(z):
            noise, cut = self._left_image_noise(z)
        else:
            noise = np.full((z.shape[0], 2), self.config.filter.object_std**2)
        r = z[None, :, :2] - pred[rows, None, :2]  # (T, M, 2)
        if is_box(z):  # a box short of its target: its edge; a cut one bounds it from a side
            predicted = self.extents.expected(target_ids[rows], pred[rows], s[rows])
            expected = [e[:, None] for e in predicted]
            shift, noise = occlusion_shift(
                expected, z[None], r, noise[None], noise[None], self._occlusion_sigmas
            )
            r = _censor(r + shift, cut[None])
        else:
            noise = np.broadcast_to(noise, r.shape)
        cov = s[rows, None, :2, :2] + _diagonal(noise)  # (T, M, 2, 2)
        d2 = np.einsum("tmi,tmi->tm", r, np.linalg.solve(cov, r[..., None])[..., 0])
        gate = chi2_quantile(self.config.tracking.gate_probability, 2)
        cost = d2 - gate
        agree = np.ones_like(d2, bool)
        if labels is not None:
            a, b = target_labels[rows], labels
            if is_box(z):
                ratio = self.label_model.log_ratio(a, b)
                agree = ratio >= self._veto
                cost = cost - 2.0 * ratio
            else:
                agree = (a[:, None] < 0) | (b[None, :] < 0) | (a[:, None] == b[None, :])
        assigned = np.full(z.shape[0], -1, np.int64)
        _nearest_neighbour((d2 <= gate) & agree, cost, assigned)
        hit = assigned >= 0
        out[hit] = target_ids[rows[assigned[hit]]]
        self.counters["detections_monocular_named"] += int(hit.sum())
        return out

    def _left_image_noise(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(M, 2)`` variances of ``(u_l, v_l)`` of box rows seen in the left image only, and
        ``(M, 2)`` the border that cut each (:meth:`_cut_sides`): no right box, so no disparity
        in a clipped box's variance."""
        left = z.copy()
        left[:, 2:4] = z[:, :2]
        f = self.config.filter
        noise = box_variances(left, f.object_std, f.object_size_share)[:, :2]
        return noise, self._cut_sides(left)[:, :2]

    def _cut_sides(self, rows: np.ndarray) -> np.ndarray:
        """``(D, 4)`` per centre coordinate of box rows the border that cut it: ``-1`` the low
        one (left, top), ``+1`` the high one, ``0`` not cut (the clipped flags of
        :func:`~teamslam.msckf.filter.box_noise.box_rows`; the side: the half of the image the
        centre lies in, and for ``u_r`` of a box whose ``u_l`` is cut that of ``u_l`` — both
        images cut it on one side, and the right centre lies up to the disparity left of the
        left one)."""
        if self.image_size is None:
            return np.zeros((rows.shape[0], 4), np.int64)
        extent = np.array([self.image_size[0], self.image_size[1]] * 2, float)
        side = np.where(rows[:, :4] < 0.5 * (extent - 1.0), -1, 1)
        side[:, 2] = np.where(rows[:, 6] > 0, side[:, 0], side[:, 2])
        return np.where(rows[:, 6:10] > 0, side, 0)

    def first_ids(self) -> np.ndarray:
        """The id given to every detection so far when it was named, in frame order (``-1``:
        none): :meth:`hypotheses` before any merge renamed them (what
        :func:`~teamslam.eval.tracking.merge_audit` judges merges by)."""
        if not self.log:
            return np.zeros(0, np.int64)
        return np.concatenate(self.log).astype(np.int64)

    def merges(self) -> np.ndarray:
        """``(k, 2)`` ``(new id, old id)`` of every merge so far (loop closure,
        re-identification), in the order made."""
        return np.array(list(self.merged.items()), np.int64).reshape(-1, 2)

    def hypotheses(self) -> np.ndarray:
        """The id given to every detection so far, in frame order (``-1``: none); a merged
        object's detections carry the id of the object it continues (loop closure)."""
        out = self.first_ids()
        if self.merged:
            new = np.fromiter(self.merged, np.int64)
            old = np.array([self._continued(i) for i in new.tolist()], np.int64)
            order = np.argsort(new)
            new, old = new[order], old[order]
            pos = np.clip(np.searchsorted(new, out), 0, new.size - 1)
            out = np.where(new[pos] == out, old[pos], out)
        return out

    def _can_be_detected(self, pred: np.ndarray) -> np.ndarray:
        """Which targets a detector could report now, for re-identifying long-unseen objects:
        those predicted inside the image, where the data gives its size (all of them where it
        does not). Outside the image the detection probability is zero, however wide the gate
        of an uncertain target beside the camera that covers the whole image."""
        if self.image_size is None:
            return np.ones(pred.shape[0], bool)
        return in_image(pred, *self.image_size)

    def _continued(self, object_id: int) -> int:
        """The object a merged object continues (through merges of merges)."""
        while object_id in self.merged:
            object_id = self.merged[object_id]
        return object_id

    def _close_loops(self, t: int, state) -> np.ndarray:
        """Merge the recent objects that are old ones seen again (:mod:`~teamslam.msckf.
        loop_closure`); the pairs ``(new id, old id)`` merged."""
        pairs = self.loop.step(
            t,
            state,
            np.array(self._created_ids, np.int64),
            np.array(self._created_frames, np.int64),
            self._labels_of if self._label_ids.size else None,
            self.views,
        )
        for n, o in pairs.tolist():
            self.merged[n] = o
            self._merge_summaries(n, o)
        self.counters["loop_closures"] = len(self.loop.closures)
        return pairs

    def _merge_summaries(self, new: int, old: int) -> None:
        """Object ``new`` is ``old`` seen again: its sizes, appearance and shape summaries
        join ``old``'s."""
        self.extents.merge(new, old)
        if self.memory is not None:
            self.memory.merge(new, old)
        self.shape_memory.merge(new, old)

    def reidentify(self, t: int, state) -> np.ndarray:
        """Merge each object confirmed within the last ``filter.window`` frames into the
        long-unseen object its boxes show it to be; the pairs ``(new id, old id)`` merged.

        Candidates: the objects of the state never named in one frame with the new object since
        its first box (last seen before it, or since only in frames the new one was not: its
        track broke while the old one's continued) and those of the persistent map, of its
        class where both have one. Each is gated by the
        squared Mahalanobis distance of ``x_n − x_o`` under its covariance from the joint state
        and the offset two views of the objects allow (:meth:`_view_offset`;
        :func:`~teamslam.msckf.objects.loop_closure.difference_d2`, the
        ``tracking.gate_probability`` quantile of χ²(3)); the gated ones are weighed by the
        log likelihood ratios of the appearance and the class of every box of the new object,
        summed, and of the position difference's ``d²`` (:class:`~teamslam.msckf.objects.
        loop_closure.PositionRatio`, learned from the ``d²`` of every old object of every
        call), against a new object whose prior is the share of confirmed tracks found to be
        revisits so far (Beta(1, 1)), and against each other
        (:func:`~teamslam.msckf.objects.loop_closure.revisit_posterior`). The best is merged
        (:func:`~teamslam.msckf.objects.loop_closure.merge_objects`) when its posterior reaches
        ``tracking.revisit_probability``; from then on its boxes carry the old id, and
        :meth:`hypotheses` names the earlier ones so too.
        """
        none = np.zeros((0, 2), np.int64)
        gap = self.config.filter.window
        self._confirmed_at = {i: f for i, f in self._confirmed_at.items() if t - f <= gap}
        keep = set(self.ids.tolist()) | set(self._confirmed_at)
        for i in [i for i in self._boxes if i not in keep]:
            del self._boxes[i]
        self._together = {
            i: ids
            for i, ids in self._together.items()
            if i in self._confirmed_at or i in self._pending
        }
        if not self.appearance.informative:
            return none
        created = dict(zip(self._created_ids, self._created_frames, strict=True))
        pairs = self._pending_pairs(state)
        young = np.array(sorted(self._confirmed_at), np.int64)
        young = young[state.object_slots(young) >= 0]
        young = young[~np.isin(young, pairs)]
        retired = state.retired.arrays()["ids"] if len(state.retired) else np.zeros(0, np.int64)
        confirmed = self.counters["tracks_confirmed"]
        prior = (self.counters.get("tracks_reidentified", 0) + 1.0) / (confirmed + 2.0)
        for n in young.tolist():
            seen_apart = ~self._seen_together(n, state.object_ids)
            old = state.object_ids[(state.object_last_seen < created[n]) | seen_apart]
            old = np.concatenate([old, retired])
            old = old[~np.isin(old, young) & ~np.isin(old, pairs)]
            if not old.size:
                continue
            everyone = old  # of every class: where a look-alike appearance named may lie
            label = int(self.labels_of(np.array([n]))[0])
            of_class = np.ones(old.size, bool)
            if label >= 0:
                labels = self.labels_of(old)
                of_class = (labels < 0) | (labels == label)
            # the gate's d² of every old object: pairs of two objects but for one at most, what
            # the position ratio learns a pair of two objects from
            factors = None
            if self.widening is not None:
                r = self.widening(np.concatenate([[n], everyone]))
                factors = (float(r[0]), r[1:]) if (r > 1.0).any() else None
            d2 = difference_d2(state, n, everyone, factors, self._view_offset(n, everyone))
            self.position.add(d2)
            old, d2 = old[of_class], d2[of_class]
            if not old.size:
                continue
            held = difference_d2(state, n, old)
            ratio = self._revisit_ratio(n, old)
            if self.config.filter.object_overconfidence:
                # the sample: what appearance and class alone name, not cut by the gate (and
                # under the covariances as held: the learner weighs each by its own factor)
                best = self._revisit_choice(ratio, prior)
                if best is not None:
                    key = (n, int(old[best]))
                    if key not in self.revisit_d2:
                        self.revisit_d2[key] = float(held[best])
                        others = everyone[everyone != key[1]]
                        self.revisit_alternatives[key] = difference_d2(state, n, others)
                    self._pending[n] = key[1]
            inside = d2 <= self.revisit_gate
            if not inside.any():
                continue
            evidence = ratio[inside] + self.position.log_ratio(d2[inside])
            best = self._revisit_choice(evidence, prior)
            if best is not None:
                pairs.append((n, int(old[inside][best])))
        if not pairs:
            return none
        for n, _ in pairs:
            self._pending.pop(n, None)
        merged = np.array(pairs, np.int64)
        factors = None
        if self.widening is not None:  # the offset the held covariances lack: constraint noise
            factors = self.widening(merged.ravel()).reshape(-1, 2)
            factors = factors if (factors > 1.0).any() else None
        offsets = np.array([self._view_offset(n, np.array([o]))[0] for n, o in pairs])
        for n, o in pairs:  # the pass goes on from the point its own boxes showed
            slot = state.object_slots(np.array([n]))[0]
            columns = np.concatenate(
                [state.newest_pose().columns, state.object(np.array([slot])).columns[0]]
            )
            joint = Gaussian(np.zeros(9), state.covariance(columns))
            # held against the current pose, as a track's point: its covariance given the pose
            given_pose = joint.conditional(np.arange(6), np.zeros(6)).cov
            self.passes[o] = (state.objects[slot].copy(), 0.5 * (given_pose + given_pose.T), t)
            self.passes.pop(n, None)
        merge_objects(state, merged, t, factors, offsets)
        for n, o in pairs:
            self.merged[n] = o
            self._merge_summaries(n, o)
            for label, count in self._votes.pop(n, {}).items():
                votes = self._votes.setdefault(o, {})
                votes[label] = votes.get(label, 0) + count
            self._boxes.pop(n, None)
            self._confirmed_at.pop(n, None)
            self._count("tracks_reidentified")
            self._count("objects_merged_by_boxes")
        return merged

    def _pending_pairs(self, state) -> list[tuple[int, int]]:
        """The pairs ``(n, o)`` that appearance and class alone named (:meth:`reidentify`'s
        gate-free choice) but the position gate refused, taken once the objects' covariances,
        widened by the factor learned since (:attr:`widening`), let them in: the refusal was the
        overconfidence the factor measures. A pair lapses when either object left the state and
        the persistent map or was merged, or when the tracker named ``o`` and ``n`` in one
        frame (one detection per object and frame: two objects)."""
        pairs: list[tuple[int, int]] = []
        if not self._pending or self.widening is None:
            return pairs
        known = np.concatenate([state.object_ids, state.retired.arrays()["ids"]])
        for n, o in list(self._pending.items()):
            if (
                n in self.merged
                or o in self.merged
                or state.object_slots(np.array([n]))[0] < 0
                or not np.isin(o, known)
                or self._seen_together(n, np.array([o]))[0]
            ):
                del self._pending[n]
                continue
            if n in self._confirmed_at or np.isin([n, o], pairs).any():
                continue  # a young object: chosen again below
            r = self.widening(np.array([n, o]))
            if r.max() <= 1.0:
                continue
            d2 = difference_d2(
                state, n, np.array([o]), (float(r[0]), r[1:]), self._view_offset(n, np.array([o]))
            )
            if d2[0] <= self.revisit_gate:
                pairs.append((n, o))
        return pairs

    def _note_together(self, named: np.ndarray) -> None:
        """Record the ids ``named`` in this frame with each object :attr:`_together` follows."""
        if not self._together:
            return
        names = set(named[named >= 0].tolist())
        for n in names & self._together.keys():
            self._together[n] |= names - {n}

    def _seen_together(self, n: int, ids: np.ndarray) -> np.ndarray:
        """``(len(ids),)`` whether each of ``ids`` (or an object merged into it since) was
        named in a frame where ``n`` was named too, since ``n``'s first box."""
        together = {self._continued(i) for i in self._together.get(n, ())}
        return np.array([i in together for i in np.asarray(ids).tolist()], bool)

    def _view_offset(self, n: int, old: np.ndarray) -> np.ndarray:
        """``(len(old),)`` the variance per axis by which object ``n``'s and each old object's
        estimates may differ beyond their covariances: a box's centre shows the visible part of
        its object, and each estimate converged on the point its own views showed — anywhere on
        the object, taken uniform over its size ``s`` (the larger of its width and height over
        the disparity, times the baseline), ``s² / 12`` each: ``(s_n² + s_o²) / 12``; 0
        for an object without a size yet."""
        ratio = self.extents.of(np.concatenate([[n], np.asarray(old, np.int64)]))
        k = self.camera.intrinsics
        ratio[:, 1] *= k[0, 0] / k[1, 1]  # a height over the baseline in the width's pixels
        size = self.camera.baseline * np.nan_to_num(np.max(ratio, axis=1), nan=0.0)
        return (size[0] ** 2 + size[1:] ** 2) / 12.0

    def _revisit_ratio(self, n: int, old: np.ndarray) -> np.ndarray:
        """``(len(old),)`` log likelihood ratio of the appearance and class of every box of
        ``n`` that it is each object of ``old`` (summed over the boxes)."""
        boxes = unit_rows(np.array(self._boxes[n]))
        looks = self.appearance.log_ratio(cosine_distances(self.memory.summaries(old), boxes))
        ratio = np.nansum(looks, axis=1)
        votes = self._votes.get(n, {})
        if votes:
            seen = np.array(sorted(votes), np.int64)
            counts = np.array([votes[c] for c in seen.tolist()], float)
            ratio = ratio + self.label_model.log_ratio(self.labels_of(old), seen) @ counts
        return ratio

    def _revisit_choice(self, ratio: np.ndarray, prior: float) -> int | None:
        """Index of the candidate whose :func:`revisit_posterior` from ``ratio`` (its log
        ratios) reaches ``tracking.revisit_probability``, or ``None``."""
        posterior = revisit_posterior(ratio, prior)
        best = int(np.argmax(posterior))
        return best if posterior[best] >= self.config.tracking.revisit_probability else None

    def _count(self, name: str, n: int = 1) -> None:
        self.counters[name] = self.counters.get(name, 0) + n

    def _looks(self, target_ids: np.ndarray, descriptors: np.ndarray):
        """``(distance, log ratio)``, each ``(T, D)``, between the targets' appearance summaries
        and the detections' descriptors (:func:`_compare`)."""
        return _compare(self.appearance, self.memory, target_ids, descriptors)

    def _learn(self, looks, assigned_target, kinds, target_ids, index) -> None:
        """Samples for the appearance ratio and the summaries (:meth:`_learn_cue`), and the
        descriptors of the young objects' boxes (re-identification)."""
        samples = (self.appearance, self.memory, self._descriptors)
        self._learn_cue(samples, looks, assigned_target, kinds, target_ids, index)
        hit = assigned_target >= 0
        for j, target in zip(index[hit].tolist(), assigned_target[hit].tolist(), strict=True):
            boxes = self._boxes.get(int(target_ids[target]))
            if boxes is not None:
                boxes.append(self._descriptors[j])

    def _learn_cue(self, samples, looks, assigned_target, kinds, target_ids, index) -> None:
        """Samples for a cue's ratio (``samples``: its model, its summaries and this frame's
        unit rows; ``looks`` the distances and ratios of :meth:`_looks`, ``None``: no target),
        then the summaries: a detection against the confirmed target that took it (*same*) and
        against the other confirmed targets that took one this frame (*different*: one
        detection per object and frame)."""
        model, memory, rows = samples
        hit = np.flatnonzero(assigned_target >= 0)
        targets = assigned_target[hit]
        if looks is not None:
            confirmed = kinds < 2
            confirmed[kinds == 2] = self.confirmed  # tracks come last, in row order
            sure = confirmed[targets] & np.isfinite(looks[0][targets, hit])
            same = looks[0][targets[sure], hit[sure]]
            block = looks[0][np.ix_(targets[sure], hit[sure])]
            off = ~np.eye(block.shape[0], dtype=bool) & np.isfinite(block)
            if same.size:
                model.add(same, block[off])
        for j, target in zip(index[hit].tolist(), targets.tolist(), strict=True):
            memory.add(int(target_ids[target]), rows[j])

    def _learn_labels(self, hit, assigned_target, kinds, target_ids, target_labels, labels):
        """Box rows with labels: count each assigned detection's label against its confirmed
        target's (:class:`LabelModel`), and label each object and track by the majority of its
        detections' labels (a confused first label does not stick)."""
        cols = np.flatnonzero(hit & (labels >= 0))
        rows = assigned_target[cols]
        confirmed = kinds < 2
        if (kinds == 2).any():
            confirmed[kinds == 2] = self.confirmed  # tracks come last, in row order
        sure = confirmed[rows] & (target_labels[rows] >= 0)
        self.label_model.add(target_labels[rows[sure]], labels[cols[sure]])
        self.label_model.count(labels[labels >= 0])
        first_track = int(np.flatnonzero(kinds == 2)[0]) if (kinds == 2).any() else rows.size
        for j, r in zip(cols.tolist(), rows.tolist(), strict=True):
            oid = int(target_ids[r])
            votes = self._votes.setdefault(oid, {})
            votes[int(labels[j])] = votes.get(int(labels[j]), 0) + 1
            best = max(sorted(votes), key=votes.__getitem__)
            if best == target_labels[r]:
                continue
            if kinds[r] == 2:
                self.classes[r - first_track] = best
            else:
                self._set_label(oid, best)

    def _set_label(self, object_id: int, label: int) -> None:
        pos = int(np.searchsorted(self._label_ids, object_id))
        if pos < self._label_ids.size and self._label_ids[pos] == object_id:
            self._labels[pos] = label
        else:
            self._add_labels(np.array([object_id]), np.array([label]))

    def _labels_of(self, ids: np.ndarray) -> np.ndarray:
        """Class label of each id (``-1``: none)."""
        pos = np.clip(np.searchsorted(self._label_ids, ids), 0, self._label_ids.size - 1)
        return np.where(self._label_ids[pos] == ids, self._labels[pos], -1)

    def labels_of(self, ids: np.ndarray) -> np.ndarray:
        """The class label the detections of each confirmed object id voted for (``-1``: none
        known, e.g. an id of another robot or without labels)."""
        ids = np.asarray(ids, np.int64)
        if not self._label_ids.size:
            return np.full(ids.shape, -1, np.int64)
        return self._labels_of(ids)

    @property
    def n_tracks(self) -> int:
        """Tracks held (tentative and confirmed not yet in the state)."""
        return int(self.ids.size)

    # ------------------------------------------------------------------ steps
    def _forget_mapped(self, state) -> None:
        """Tracks whose ids the filter took into its state (or retired) are its, not ours."""
        if not self.ids.size:
            return
        held = (self.ids[:, None] == state.object_ids[None, :]).any(axis=1)
        if len(state.retired):
            held |= state.retired.contains(self.ids)
        if held.any():
            for i in self.ids[held].tolist():
                self.history.pop(i, None)
            self._keep(~held)

    def _predict(self, t: int, state, odometry_cov: np.ndarray, with_noise: bool = True):
        """Every target's predicted measurement, innovation covariance and point Jacobian.

        ``S = H P Hᵀ + σ² I`` with ``filter.object_std`` (``with_noise``), else ``H P Hᵀ`` (box
        rows: each detection adds its own noise). An object in a pass (:attr:`passes`) is
        predicted from the pass's point, held as a track's.

        Only targets in front of the camera and nearer than twice ``objects.max_depth``.
        Returns kinds (0 state, 1 persistent map, 2 track), ids, frame last seen, predictions
        ``(T, 4)``,
        ``S`` ``(T, 4, 4)``, ``∂z/∂p`` ``(T, 4, 3)``, in front of the camera ``(T,)`` and class
        labels ``(T,)``.
        """
        cfg = self.config
        pose = state.current_pose
        parts_ids, parts_points, parts_p, kinds = [], [], [], []
        seen = []
        reach = 2.0 * cfg.objects.max_depth  # farther or behind: no detection can be theirs
        if state.n_objects:
            depth = (state.objects - pose[:3, 3]) @ self._depth_axis(pose) + self.T_cam_body[2, 3]
            slots = np.flatnonzero((depth > 0) & (depth < reach))
            k = slots.size
            cols = np.empty((k, 9), np.int64)
            cols[:, :6] = state.newest_pose().columns
            cols[:, 6:] = state.object(slots).columns
            parts_ids.append(state.object_ids[slots])
            parts_points.append(state.objects[slots])
            parts_p.append(state.covariance(cols))
            kinds.append(np.zeros(k, np.int64))
            seen.append(state.object_last_seen[slots])
        if len(state.retired):
            arrays = state.retired.arrays()
            _, p_cam = points_in_camera(pose, arrays["means"], self.T_cam_body)
            near = (p_cam[:, 2] > 0) & (p_cam[:, 2] < reach)
            arrays = {key: value[near] for key, value in arrays.items()}
            k = arrays["ids"].size
            seen.append(np.zeros(k, np.int64))
            p = np.zeros((k, 9, 9))
            p[:, :6, :6] = state.current_pose_cov()
            p[:, 6:, 6:] = arrays["covs"]
            parts_ids.append(arrays["ids"])
            parts_points.append(arrays["means"])
            parts_p.append(p)
            kinds.append(np.ones(k, np.int64))
        if self.ids.size:
            k = self.ids.size
            p = np.zeros((k, 9, 9))
            gap = np.maximum(t - self.last, 1).astype(float)
            p[:, :6, :6] = gap[:, None, None] * odometry_cov
            p[:, 6:, 6:] = self.covs
            parts_ids.append(self.ids)
            parts_points.append(self.points)
            parts_p.append(p)
            kinds.append(np.full(k, 2, np.int64))
            seen.append(self.last.copy())
        if not parts_ids or sum(ids.size for ids in parts_ids) == 0:
            empty = np.zeros(0, np.int64)
            return (
                empty,
                empty,
                empty,
                np.zeros((0, 4)),
                np.zeros((0, 4, 4)),
                np.zeros((0, 4, 3)),
                np.zeros(0, bool),
                empty,
            )
        ids = np.concatenate(parts_ids)
        points = np.concatenate(parts_points)
        p = np.concatenate(parts_p)
        kind = np.concatenate(kinds)
        self.passes = {o: v for o, v in self.passes.items() if t - v[2] <= self.frames_allowed}
        for o, (point, cov, last) in self.passes.items():  # the point the object's pass shows
            at = np.flatnonzero((ids == o) & (kind == 0))  # held as a track's
            points[at], p[at, 6:, 6:] = point, cov
            p[at, :6, :6] = max(t - last, 1) * odometry_cov
            p[at, :6, 6:], p[at, 6:, :6] = 0.0, 0.0
        # a point behind the camera has no projection: evaluate it anywhere harmless
        pred, s, d_point, in_front = _predict_targets(
            np.ascontiguousarray(pose, dtype=float),
            self._camera_block,
            np.ascontiguousarray(points, dtype=float),
            np.ascontiguousarray(p, dtype=float),
            self._min_depth,
            float(cfg.filter.object_std) ** 2 if with_noise else 0.0,
        )
        labels = np.full(ids.size, -1, np.int64)
        if self._label_ids.size and (kind < 2).any():
            pos = np.clip(np.searchsorted(self._label_ids, ids), 0, self._label_ids.size - 1)
            found = (self._label_ids[pos] == ids) & (kind < 2)
            labels[found] = self._labels[pos[found]]
        if self.ids.size:
            labels[kind == 2] = self.classes
        return kind, ids, np.concatenate(seen), pred, s, d_point, in_front, labels

    def _depth_axis(self, pose: np.ndarray) -> np.ndarray:
        """The camera's optical axis in the world at ``pose``: a point's depth is its offset from
        the body along it, plus the camera's depth offset in the body frame."""
        return pose[:3, :3] @ self.T_cam_body[2, :3]

    def _update_tracks(
        self, t, z, index, detections, assigned, predicted, frame, lone_stale, window
    ) -> None:
        """Kalman update of each assigned track's point; confirm the tracks with enough hits
        (their earlier detections named in the log as the filter then uses them), or continue
        the long-unseen object a track revisits (:meth:`_note_revisit`; its earlier detections
        named so in the log, for the record); either names the boxes of the window's earlier
        frames seen in the left image only that are the track's (:meth:`_name_in_hindsight`)."""
        kinds, pred, s, h_point = predicted
        targets = assigned[detections]
        rows = targets - int(np.flatnonzero(kinds == 2)[0])  # tracks come last
        self.points[rows], self.covs[rows] = self._point_update(
            self.ids[rows],
            self.points[rows],
            self.covs[rows],
            z[detections],
            self._noise[detections] if self._noise is not None else None,
            (pred[targets], s[targets], h_point[targets]),
        )
        self.last[rows] = t
        self.hits[rows] += 1
        self._note_revisit(rows, lone_stale[detections])
        confirmed_before = self.confirmed[rows].copy()
        newly = ~confirmed_before & (self.hits[rows] >= self.hits_needed)
        newly &= t - self.first[rows] < self.frames_allowed
        # a track confirmed now whose detections were mostly alone in the gate of one object not
        # seen for N frames, this one too, continues that object: a re-identification
        revisit = (
            newly & (self.revisit_of[rows] >= 0) & (lone_stale[detections] == self.revisit_of[rows])
        )
        revisit &= 2 * self.revisit_hits[rows] > self.hits[rows]
        taken = set(frame.ids[frame.ids >= 0].tolist())
        gone = np.zeros(self.ids.size, bool)
        for det, row in zip(detections[revisit].tolist(), rows[revisit].tolist(), strict=True):
            oid = int(self.revisit_of[row])
            if oid in taken:
                continue
            taken.add(oid)
            self._merge_summaries(int(self.ids[row]), oid)
            if self.memory is not None:
                self._count("tracks_reidentified")
            for f, _, j in self.history.get(int(self.ids[row]), []):
                self._name_in_log(f, j, oid)
            self._name_in_hindsight(t, self._track_target(row), oid, *window)
            frame.ids[det] = oid
            self.revisits.append((t, int(index[det]), oid))
            self.counters["revisits_taken"] += 1
            gone[row] = True
        newly &= ~gone[rows]
        self.confirmed[rows[newly]] = True
        for det, row, new in zip(detections.tolist(), rows.tolist(), newly.tolist(), strict=True):
            if gone[row]:
                continue
            tid = int(self.ids[row])
            past = self.history.setdefault(tid, [])
            if new:
                frames = np.array([f for f, _, _ in past], dtype=np.int64)
                zs = np.array([zz for _, zz, _ in past]).reshape(-1, self._row_width)
                for f, _, j in past:
                    self.log[f - self._first_logged][j] = tid
                self._name_in_hindsight(t, self._track_target(row), tid, *window)
                frame.confirmed.append((tid, frames, zs))
                self.counters["tracks_confirmed"] += 1
                self._created_ids.append(tid)
                self._created_frames.append(int(frames[0]) if frames.size else t)
                if tid in self._boxes:
                    self._confirmed_at[tid] = t
                    self._together[tid] = {
                        int(i) for f, _, _ in past for i in self.log[f - self._first_logged]
                    } - {-1, tid}
                self._add_labels(np.array([tid]), self.classes[row : row + 1])
            if self.confirmed[row]:
                frame.ids[det] = tid
            past.append((t, z[det].copy(), int(index[det])))
        if gone.any():
            for i in self.ids[gone].tolist():
                self.history.pop(i, None)
            self._keep(~gone)

    def _follow_passes(self, t, z, detections, assigned, target_ids, kinds, predicted) -> None:
        """Kalman update of the point each re-identified object's pass shows (:attr:`passes`)
        with the box it took, as a track's (:meth:`_update_tracks`): the boxes of the pass go on
        showing the part of the object its views see, which the filter's estimate (formed from
        other views) may miss by a share of the object's size."""
        pred, s, h_point = predicted
        targets = assigned[detections]
        follow = (kinds[targets] == 0) & np.isin(target_ids[targets], list(self.passes))
        if not follow.any():
            return
        detections, targets = detections[follow], targets[follow]
        ids = target_ids[targets]
        points, cov = self._point_update(
            ids,
            np.array([self.passes[o][0] for o in ids.tolist()]),
            np.array([self.passes[o][1] for o in ids.tolist()]),
            z[detections],
            self._noise[detections] if self._noise is not None else None,
            (pred[targets], s[targets], h_point[targets]),
        )
        for k, o in enumerate(ids.tolist()):
            self.passes[o] = (points[k], cov[k], t)

    def _point_update(self, ids, points, cov, z, own, predicted):
        """Kalman update of points ``(k, 3)`` with covariances ``cov`` by one box each (rows
        ``z``, their variances ``own`` or ``None``; the points' predictions, ``S`` and ``∂z/∂p``
        in ``predicted``); a box short of its object's size taken at the edge an occluder left.
        Returns the points and covariances."""
        pred, s_pair, hp = predicted
        cross = hp @ cov  # (k, 4, 3) = H C
        r = z[:, :4] - pred
        if own is not None:
            expected = self.extents.expected(ids, pred, s_pair)
            shift, noise = occlusion_shift(expected, z, r, own, own, self._occlusion_sigmas)
            r = r + shift
            s_pair = s_pair + _diagonal(noise)
        gain_t = np.linalg.solve(s_pair, cross)  # (k, 4, 3) = S⁻¹ H C = Kᵀ
        points = points + np.einsum("kij,ki->kj", gain_t, r)
        cov = cov - np.swapaxes(cross, 1, 2) @ gain_t
        return points, 0.5 * (cov + np.swapaxes(cov, 1, 2))

    def _keep_unnamed(self, t, rows, z, labels, named, state, odometry_cov) -> None:
        """Keep frame ``t``'s boxes seen in the left image only (``rows`` of the frame's
        detections, box rows ``z``) that got no id (``named``), with the frame's pose, for
        :meth:`_name_in_hindsight`: as long as an object could tell them from chance
        (:func:`~teamslam.msckf.objects.hindsight.hindsight_horizon`), or while their frame is
        in the window where the images' size is not known."""
        left = named < 0
        if not left.any() or not is_box(z) or not hasattr(state, "window_index"):
            return
        z = z[left]
        kept = np.empty((z.shape[0], 7))
        kept[:, :2] = z[:, :2]
        kept[:, 2:4], kept[:, 4:6] = self._left_image_noise(z)
        kept[:, 6] = -1 if labels is None else labels[left]
        if self.image_size is None:
            horizon = np.full(z.shape[0], self.config.filter.window - 1.0)
        else:
            horizon = hindsight_horizon(
                self.camera,
                self.T_cam_body,
                z[:, :2],
                odometry_cov,
                z.shape[0],
                self.image_size,
                self.config.tracking.gate_probability,
            )
        self.unnamed.keep(t, rows[left], kept, t + np.floor(horizon), state.current_pose)

    def _map_target(self, t: int, state, object_id: int, label: int) -> tuple:
        """Object ``object_id`` of the state or the persistent map, seen again at the current
        frame, as :meth:`_name_in_hindsight` takes a target: held against the current pose."""
        slot = state.object_slots(np.array([object_id]))[0]
        if slot >= 0:
            point = state.objects[slot]
            cov = state.covariance(state.object(np.array([slot])).columns[0])
        else:
            point, cov, _ = state.retired.get(np.array([object_id]))
            point, cov = point[0], cov[0]
        return point, cov, t, int(label), state.current_pose_cov()

    def _track_target(self, row: int) -> tuple:
        """Track ``row`` as :meth:`_name_in_hindsight` takes a target."""
        return self.points[row], self.covs[row], int(self.last[row]), int(self.classes[row]), None

    def _name_in_hindsight(
        self, t: int, target: tuple, object_id: int, state, odometry_cov: np.ndarray
    ) -> None:
        """Name in the log the boxes of earlier frames seen in the left image only and left
        unnamed (:meth:`_keep_unnamed`) that are ``target``'s (now ``object_id``'s): its point
        projected into each frame's left image from that frame's pose estimate, gated as
        :meth:`_name_monocular` gates (``d²`` over ``(u_l, v_l)`` under the point's covariance,
        the relative pose's odometry noise since the frame the point was last seen in and the
        box's own, cut sides censored, the label's ratio at the gate's odds), where the gate would
        hold fewer of the frame's boxes by chance than it misses; the nearest box of a frame in
        which the object has no box yet. ``target``: the point, its covariance, the frame it was
        last seen in, its label and the covariance of the pose it is held against (``None``: its
        own track's, in the point's). For the record, as every box seen in one image: the filter
        never gets them."""
        point, point_cov, last, label, pose_cov = target
        kept = self.unnamed
        if not len(kept):
            return
        frames = kept.keys[:, 0]
        at = kept.frame_of(np.arange(len(kept)))
        posed = np.isfinite(kept.poses[at, 0, 0])
        rows = np.flatnonzero(posed & (frames < t))
        if not rows.size:
            return
        pose = kept.poses[at[rows]]
        point = np.broadcast_to(point, (rows.size, 3))
        pred, d_pose, d_point = observe_jacobians(self.camera, self.T_cam_body, pose, point)
        gap = np.abs(last - frames[rows]).astype(float)
        s = d_point[:, :2] @ point_cov @ np.swapaxes(d_point[:, :2], 1, 2)
        pose_noise = gap[:, None, None] * odometry_cov
        if pose_cov is not None:  # a map's point: the pose it is held against is uncertain too
            pose_noise = pose_noise + pose_cov
        s += d_pose[:, :2] @ pose_noise @ np.swapaxes(d_pose[:, :2], 1, 2)
        boxes = kept.boxes[rows]
        s += _diagonal(boxes[:, 2:4])
        r = _censor(boxes[:, :2] - pred[:, :2], boxes[:, 4:6])
        d2 = np.einsum("ki,ki->k", r, np.linalg.solve(s, r[..., None])[..., 0])
        ratio = self.label_model.log_ratio(np.array([label]), boxes[:, 6].astype(int))[0]
        cost = d2 - 2.0 * ratio
        _, p_cam = points_in_camera(pose, point, self.T_cam_body)
        probability = self.config.tracking.gate_probability
        allowed = (d2 <= chi2_quantile(probability, 2)) & (ratio >= self._veto)
        allowed &= p_cam[:, 2] > self._min_depth
        if self.image_size is not None:
            chance = chance_in_gate(kept.counts[at[rows]], s, self.image_size, probability)
            allowed &= chance < 1.0 - probability
        named = np.zeros(rows.size, bool)
        for f in np.unique(frames[rows]).tolist():
            mine = np.flatnonzero((frames[rows] == f) & allowed)
            if mine.size:
                best = mine[np.argmin(cost[mine])]
                named[best] = self._name_in_log(f, int(kept.keys[rows[best], 1]), object_id)
        if named.any():
            self._count("detections_named_in_hindsight", int(named.sum()))
            gone = np.zeros(len(kept), bool)
            gone[rows[named]] = True
            kept.drop(gone)

    def _name_in_log(self, f: int, j: int, object_id: int) -> bool:
        """Name detection ``j`` of frame ``f`` ``object_id`` in the log, unless it has an id or
        the object has a box in that frame already (one box per object and frame); whether it
        was named."""
        logged = self.log[f - self._first_logged]
        if logged[j] >= 0 or np.any(logged == object_id):
            return False
        logged[j] = object_id
        return True

    def _note_revisit(self, rows: np.ndarray, lone_stale: np.ndarray) -> None:
        """Tracks ``rows`` took detections alone in the gate of long-unseen objects
        ``lone_stale`` (``-1``: none): count each for the object it first named, spoil it
        (``-2``) on a different one."""
        alone = lone_stale >= 0
        first = alone & (self.revisit_of[rows] == -1)
        self.revisit_of[rows[first]] = lone_stale[first]
        same = alone & (self.revisit_of[rows] == lone_stale)
        self.revisit_hits[rows[same]] += 1
        self.revisit_of[rows[alone & ~same]] = -2

    def _start_tracks(
        self,
        t: int,
        z: np.ndarray,
        index: np.ndarray,
        labels: np.ndarray,
        state,
        lone_stale: np.ndarray,
    ) -> None:
        """Tentative tracks from unassigned detections, stereo-triangulated at the current pose."""
        cfg = self.config
        pose = state.current_pose
        points, ok = stereo_point(self.camera, self.T_cam_body, pose, z[:, :4])
        depth = np.linalg.norm(points - pose[:3, 3], axis=1)
        ok &= np.all(np.isfinite(points), axis=1)
        ok &= (depth > cfg.objects.min_depth) & (depth < cfg.objects.max_depth)
        self.counters["detections_rejected_depth"] += int((~ok).sum())
        if not ok.any():
            return
        points, z, labels, index = points[ok], z[ok], labels[ok], index[ok]
        lone_stale = lone_stale[ok]
        _, _, d_point = observe_jacobians(self.camera, self.T_cam_body, pose, points)
        if self._noise is None:
            info = np.swapaxes(d_point, 1, 2) @ d_point / cfg.filter.object_std**2
        else:  # Jᵀ R⁻¹ J with each detection's own R
            noise = box_variances(z, cfg.filter.object_std, cfg.filter.object_size_share)
            weighted = d_point / noise[:, :, None]
            info = np.swapaxes(d_point, 1, 2) @ weighted
        covs = np.linalg.solve(info, np.broadcast_to(np.eye(3), info.shape))
        k = points.shape[0]
        ids = np.arange(self.next_id, self.next_id + k, dtype=np.int64)
        self.next_id += k
        self.ids = np.concatenate([self.ids, ids])
        self.points = np.concatenate([self.points, points])
        self.covs = np.concatenate([self.covs, 0.5 * (covs + np.swapaxes(covs, 1, 2))])
        self.first = np.concatenate([self.first, np.full(k, t, np.int64)])
        self.last = np.concatenate([self.last, np.full(k, t, np.int64)])
        self.hits = np.concatenate([self.hits, np.ones(k, np.int64)])
        self.classes = np.concatenate([self.classes, labels])
        self.confirmed = np.concatenate([self.confirmed, np.zeros(k, bool)])
        self.revisit_of = np.concatenate([self.revisit_of, lone_stale])
        self.revisit_hits = np.concatenate([self.revisit_hits, (lone_stale >= 0).astype(np.int64)])
        if self._noise is not None:  # the first box's size, over its own disparity
            self.extents.add(ids, z[:, 0] - z[:, 2], z)
        for tid, row, j in zip(ids.tolist(), z, index.tolist(), strict=True):
            self.history[tid] = [(t, row.copy(), j)]
            if self._descriptors is not None:
                self.memory.add(tid, self._descriptors[j])
                self._boxes[tid] = [self._descriptors[j]]
            if self._shapes is not None:
                self.shape_memory.add(tid, self._shapes[j])
        self.counters["tracks_started"] += k
        if self.hits_needed <= 1:  # confirmed by its first detection
            self.confirmed[-k:] = True

    def _drop_stale(self, t: int) -> None:
        """Drop tentative tracks past their ``N`` frames, confirmed ones unseen for ``N``."""
        if not self.ids.size:
            return
        expired = ~self.confirmed & (t - self.first >= self.frames_allowed - 1)
        expired &= self.hits < self.hits_needed
        lost = self.confirmed & (t - self.last >= self.frames_allowed)
        drop = expired | lost
        if drop.any():
            self.counters["tracks_dropped"] += int(drop.sum())
            for i in self.ids[drop].tolist():
                self.history.pop(i, None)
            for i in self.ids[expired].tolist():  # a tentative track's id never reached the filter
                self.shape_memory.forget(i)
                if self.memory is not None:
                    self.memory.forget(i)
            self._keep(~drop)

    def _keep(self, mask: np.ndarray) -> None:
        for name in _PER_TRACK:
            setattr(self, name, getattr(self, name)[mask])

    def _add_labels(self, ids: np.ndarray, labels: np.ndarray) -> None:
        if (labels < 0).all():
            return
        ids = np.concatenate([self._label_ids, ids[labels >= 0]])
        labels = np.concatenate([self._labels, labels[labels >= 0]])
        order = np.argsort(ids)
        self._label_ids, self._labels = ids[order], labels[order]


#: the per-track arrays of a tracker (one row per track)
_PER_TRACK = (
    "ids",
    "points",
    "covs",
    "first",
    "last",
    "hits",
    "classes",
    "confirmed",
    "revisit_of",
    "revisit_hits",
)
#: the per-track arrays and the class labels of objects (in :meth:`ObjectTracker.state_dict`)
_TRACK_ARRAYS = (*_PER_TRACK, "_label_ids", "_labels")


class LabelModel:
    """The likelihood ratio of a detection's class label: *same object* against *another*.

    Same object: the object's label with probability ``1 − c``, each of the ``K − 1`` others with
    ``c / (K − 1)``, ``c`` the detector's confusion counted in the run (a Beta(1, 1) prior:
    ``c = (disagreeing + 1) / (pairs + 2)``); another object: the label's frequency among all
    detections (a Dirichlet(1) prior over the ``K`` labels seen). 0 where either label is
    unknown (``< 0``).
    """

    def __init__(self) -> None:
        self.pairs = 0
        self.disagreeing = 0
        self.frequency = np.zeros(0)

    def add(self, object_labels: np.ndarray, detection_labels: np.ndarray) -> None:
        """Count detections' labels against the labels of the objects they were assigned to."""
        self.pairs += int(object_labels.size)
        self.disagreeing += int(np.count_nonzero(object_labels != detection_labels))

    def count(self, labels: np.ndarray) -> None:
        """Count labels of detections (the label frequencies)."""
        if labels.size:
            k = max(self.frequency.size, int(labels.max()) + 1)
            self.frequency = np.pad(self.frequency, (0, k - self.frequency.size))
            self.frequency += np.bincount(labels, minlength=k)

    def log_ratio(self, object_labels: np.ndarray, detection_labels: np.ndarray) -> np.ndarray:
        """``(T, D)`` log ratio of each (object label, detection label) pair."""
        a, b = object_labels[:, None], detection_labels[None, :]
        known = (a >= 0) & (b >= 0)
        k = max(self.frequency.size, int(max(a.max(initial=-1), b.max(initial=-1))) + 1, 2)
        frequency = np.pad(self.frequency, (0, k - self.frequency.size)) + 1.0
        other = frequency / frequency.sum()
        c = (self.disagreeing + 1.0) / (self.pairs + 2.0)
        same = np.where(a == b, 1.0 - c, c / (k - 1))
        ratio = np.log(same) - np.log(other[np.maximum(b, 0)])
        return np.where(known, ratio, 0.0)


def _add_frame_pairs(model: AppearanceModel, rows: np.ndarray) -> None:
    """Count a cue's *different* samples of one frame: its detections (``rows``) two by two
    (one box per object and frame)."""
    pairs = cosine_distances(rows, rows)
    model.add(np.zeros(0), pairs[np.triu_indices(rows.shape[0], 1)])


def _compare(model: AppearanceModel, memory: AppearanceMemory, target_ids, rows):
    """``(distance, log ratio)``, each ``(T, D)``, between the targets' summaries of a cue
    and the detections' unit ``rows`` (distance NaN and ratio 0 where either has none)."""
    dist = cosine_distances(memory.summaries(target_ids), rows)
    return dist, model.log_ratio(dist)


def _nearest_neighbour(allowed: np.ndarray, cost: np.ndarray, assigned: np.ndarray) -> None:
    """One-to-one assignment of least total ``cost`` over the ``allowed`` (target, detection)
    pairs, leaving a detection or a target unassigned at cost 0 (so only pairs of negative
    cost are ever worth keeping); writes each assigned detection's target into ``assigned``."""
    rows_idx = np.flatnonzero(allowed.any(axis=1))
    if not rows_idx.size:
        return
    cols_idx = np.flatnonzero(allowed.any(axis=0))
    if rows_idx.size == 1 or cols_idx.size == 1:
        # one target or one detection (most frames): every pair is gated, and a unique least
        # cost below 0 is the solver's unique optimum
        c = cost[rows_idx[0], cols_idx] if rows_idx.size == 1 else cost[rows_idx, cols_idx[0]]
        best = int(np.argmin(c))
        if c[best] < 0 and np.count_nonzero(c == c[best]) == 1:
            if rows_idx.size == 1:
                assigned[cols_idx[best]] = rows_idx[0]
            else:
                assigned[cols_idx[0]] = rows_idx[best]
            return
    sub = allowed[np.ix_(rows_idx, cols_idx)]
    ra, ca = linear_sum_assignment(np.where(sub, cost[np.ix_(rows_idx, cols_idx)], 0.0))
    keep = sub[ra, ca]
    assigned[cols_idx[ca[keep]]] = rows_idx[ra[keep]]


def _diagonal(variances: np.ndarray) -> np.ndarray:
    """``(k, 4, 4)`` diagonal matrices of ``(k, 4)`` variances."""
    out = np.zeros(variances.shape + variances.shape[-1:])
    i = np.arange(variances.shape[-1])
    out[..., i, i] = variances
    return out


def _alone(pairs: np.ndarray, among: np.ndarray | None = None) -> np.ndarray:
    """The (target, detection) ``pairs`` whose target has no other detection and whose detection
    has no other target among ``among`` (boolean ``(T, D)``; default ``pairs`` itself)."""
    among = pairs if among is None else among
    return pairs & (among.sum(axis=1) == 1)[:, None] & (among.sum(axis=0) == 1)[None, :]


def _take_unambiguous(pairs: np.ndarray, assigned: np.ndarray) -> np.ndarray:
    """Assign each detection that is the only one of its target's ``pairs`` and whose target is
    the only one of its own; returns the detections assigned."""
    if not pairs.any():
        return np.zeros(pairs.shape[1], bool)
    lone = _alone(pairs)
    hits = lone.any(axis=0)
    assigned[hits] = np.argmax(lone[:, hits], axis=0)
    return hits


@numba.njit(cache=True)
def _predict_targets(pose, rig, points, p, min_depth, noise_var):
    """Every target's stereo prediction, ``S = H P Hᵀ + σ² I`` (symmetrised), ``∂z/∂p`` and
    whether it is in front of the camera (deeper than ``min_depth``), one target at a time:
    the arithmetic of :func:`~teamslam.msckf.filter.models.observe_jacobians` and the batched
    products
    it replaces, without their per-call overhead on a few dozen targets. A target behind the
    camera is evaluated 10 m ahead of the camera instead (no projection: harmless, never
    gated, but finite whatever the rig)."""
    n = points.shape[0]
    rot = pose[:3, :3]
    r_cb = np.ascontiguousarray(rig[0, :3, :3])
    t_cb = rig[0, :3, 3]
    fx, fy, cx, cy = rig[1, 0, 0], rig[1, 1, 1], rig[1, 0, 2], rig[1, 1, 2]
    r_rl = np.ascontiguousarray(rig[2, :3, :3].T)  # right from left
    t_rl = -(r_rl @ np.ascontiguousarray(rig[2, :3, 3]))
    pred = np.empty((n, 4))
    s = np.empty((n, 4, 4))
    d_point = np.empty((n, 4, 3))
    in_front = np.empty(n, np.bool_)
    p_body = np.empty(3)
    p_cam = np.empty(3)
    p_right = np.empty(3)
    point = np.empty(3)
    ahead = np.empty(3)
    j_cam = np.zeros((4, 3))
    h = np.empty((4, 9))
    hp = np.empty((4, 9))
    si = np.empty((4, 4))
    for i in range(n):
        for pass_ in range(2):
            if pass_ == 0:
                for a in range(3):
                    point[a] = points[i, a]
            else:  # behind the camera: evaluate 10 m ahead of the camera, on its optical axis
                for a in range(3):  # (body x for the usual rig; not so when the body is the
                    # optical frame, where body x has depth 0 and the projection divides by it)
                    ahead[a] = r_cb[2, a] * 10.0 - (
                        r_cb[0, a] * t_cb[0] + r_cb[1, a] * t_cb[1] + r_cb[2, a] * t_cb[2]
                    )
                for a in range(3):
                    point[a] = pose[a, 3] + (
                        rot[a, 0] * ahead[0] + rot[a, 1] * ahead[1] + rot[a, 2] * ahead[2]
                    )
            for a in range(3):
                p_body[a] = (
                    rot[0, a] * (point[0] - pose[0, 3])
                    + rot[1, a] * (point[1] - pose[1, 3])
                    + rot[2, a] * (point[2] - pose[2, 3])
                )
            for a in range(3):
                p_cam[a] = (
                    p_body[0] * r_cb[a, 0] + p_body[1] * r_cb[a, 1] + p_body[2] * r_cb[a, 2]
                ) + t_cb[a]
            if pass_ == 0:
                in_front[i] = p_cam[2] > min_depth
                if in_front[i]:
                    break
        for a in range(3):
            p_right[a] = (
                p_cam[0] * r_rl[a, 0] + p_cam[1] * r_rl[a, 1] + p_cam[2] * r_rl[a, 2]
            ) + t_rl[a]
        pred[i, 0] = p_cam[0] / p_cam[2] * fx + cx
        pred[i, 1] = p_cam[1] / p_cam[2] * fy + cy
        pred[i, 2] = p_right[0] / p_right[2] * fx + cx
        pred[i, 3] = p_right[1] / p_right[2] * fy + cy
        # ∂z/∂p_cam: the pinhole Jacobian of each camera (the right one rotated to the left)
        inv_z = 1.0 / p_cam[2]
        a_x, a_y = fx * inv_z, fy * inv_z
        b_x, b_y = -fx * p_cam[0] * inv_z**2, -fy * p_cam[1] * inv_z**2
        inv_z = 1.0 / p_right[2]
        c_x, c_y = fx * inv_z, fy * inv_z
        e_x, e_y = -fx * p_right[0] * inv_z**2, -fy * p_right[1] * inv_z**2
        for c in range(3):
            j_cam[0, c] = a_x if c == 0 else (b_x if c == 2 else 0.0)
            j_cam[1, c] = a_y if c == 1 else (b_y if c == 2 else 0.0)
            j_cam[2, c] = c_x * r_rl[0, c] + e_x * r_rl[2, c]
            j_cam[3, c] = c_y * r_rl[1, c] + e_y * r_rl[2, c]
        # H = [−∂z/∂p_body, ∂z/∂p_body p_body^, ∂z/∂p_body Rᵀ], ∂z/∂p_body = ∂z/∂p_cam R_cb
        for r in range(4):
            a0 = j_cam[r, 0] * r_cb[0, 0] + j_cam[r, 1] * r_cb[1, 0] + j_cam[r, 2] * r_cb[2, 0]
            a1 = j_cam[r, 0] * r_cb[0, 1] + j_cam[r, 1] * r_cb[1, 1] + j_cam[r, 2] * r_cb[2, 1]
            a2 = j_cam[r, 0] * r_cb[0, 2] + j_cam[r, 1] * r_cb[1, 2] + j_cam[r, 2] * r_cb[2, 2]
            h[r, 0], h[r, 1], h[r, 2] = -a0, -a1, -a2
            h[r, 3] = a1 * p_body[2] - a2 * p_body[1]
            h[r, 4] = -a0 * p_body[2] + a2 * p_body[0]
            h[r, 5] = a0 * p_body[1] - a1 * p_body[0]
            for c in range(3):
                v = a0 * rot[c, 0] + a1 * rot[c, 1] + a2 * rot[c, 2]
                h[r, 6 + c] = v
                d_point[i, r, c] = v
        # S = H P Hᵀ + σ² I, symmetrised
        for r in range(4):
            for c in range(9):
                acc = 0.0
                for k in range(9):
                    acc += h[r, k] * p[i, k, c]
                hp[r, c] = acc
        for r in range(4):
            for c in range(4):
                acc = 0.0
                for k in range(9):
                    acc += hp[r, k] * h[c, k]
                si[r, c] = acc
            si[r, r] += noise_var
        for r in range(4):
            for c in range(4):
                s[i, r, c] = 0.5 * (si[r, c] + si[c, r])
    return pred, s, d_point, in_front


@numba.njit(cache=True)
def _censor(r: np.ndarray, sides: np.ndarray) -> np.ndarray:
    """Residuals ``r = z − ẑ`` of box centres with the cut coordinates censored: a box cut by
    the low border (``sides`` ``-1``) shows the visible part, whose centre lies inward of the
    object's by half the hidden extent, unknown — an object predicted beyond the visible centre
    towards that border fits at any distance (residual 0), one predicted inward of it does
    not (residual as is); ``+1`` likewise for the high border."""
    low = (sides < 0) & (r > 0)
    high = (sides > 0) & (r < 0)
    return np.where(low | high, 0.0, r)


def _pair_d2(s: np.ndarray, r: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """``d²[t, j] = r_tjᵀ (S_t + R_tj)⁻¹ r_tj`` with ``R_tj = diag(noise[t, j])``: residuals
    ``r`` ``(T, D, 4)``, one Cholesky factorisation per pair."""
    cov = s[:, None] + _diagonal(noise)  # (T, D, 4, 4)
    factor = np.linalg.cholesky(cov)
    y = np.linalg.solve(factor, r[..., None])[..., 0]
    return np.einsum("tdi,tdi->td", y, y)


@numba.njit(cache=True)
def _squared_distances(s, pred, z):
    """``d²[t, j] = (z_j − ẑ_t)ᵀ S_t⁻¹ (z_j − ẑ_t)`` by one Cholesky factorisation of each
    ``S_t`` and a forward substitution per pair."""
    n, d = pred.shape[0], z.shape[0]
    out = np.empty((n, d))
    chol = np.zeros((4, 4))
    y = np.empty(4)
    for t in range(n):
        for a in range(4):
            for b in range(a + 1):
                acc = s[t, a, b]
                for k in range(b):
                    acc -= chol[a, k] * chol[b, k]
                if a == b:
                    if not acc > 0.0:
                        raise np.linalg.LinAlgError("innovation covariance not positive definite")
                    chol[a, a] = np.sqrt(acc)
                else:
                    chol[a, b] = acc / chol[b, b]
        for j in range(d):
            total = 0.0
            for a in range(4):
                acc = z[j, a] - pred[t, a]
                for k in range(a):
                    acc -= chol[a, k] * y[k]
                y[a] = acc / chol[a, a]
                total += y[a] * y[a]
            out[t, j] = total
    return out
