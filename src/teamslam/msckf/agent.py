"""One robot running the distributed MSCKF (Algorithm 1 of the distributed MSCKF paper).

After the team runner's consensus (step 1, :mod:`teamslam.msckf.consensus`),
:meth:`MsckfAgent.step` propagates with the odometry (eqs. 22–23), updates with the finished
geometric features (null-space rows, eq. 24) and the objects in the map in one stacked,
χ²-gated Kalman update (eqs. 26–28), initialises objects seen often enough (eqs. 29–30) and
slides the window; objects may retire to and re-enter from the persistent map, and detections
without ids are named by the robot's own tracker first. Jacobians are evaluated where the
linearisation policy says. Bad inputs are rejected and counted, the estimate left as it was;
a numerical failure raises :class:`~teamslam.errors.EstimationError` naming robot and frame.
The same code serves a state of its own or a robot's window in a team state. See the concept
page *The filter* (``docs/concepts/filter.md``).
"""

from __future__ import annotations

import copy
import logging
import time
from collections import defaultdict
from collections.abc import Callable

import numpy as np

from teamslam.datasets.model import Calibration, RobotSequence
from teamslam.errors import EstimationError, InputError, InternalError
from teamslam.gaussian import NotPositiveDefiniteError, chi2_quantile
from teamslam.geometry import se3
from teamslam.msckf.filter.box_noise import (
    FormedUnder,
    ObjectExtents,
    Overconfidence,
    box_rows,
    box_size2,
    box_variances,
    is_box,
    occlusion_shift,
    occlusion_sigmas,
)
from teamslam.msckf.filter.linearization import (
    GroundTruth,
    first_estimate_distance,
    keeps_first_estimates,
    linearization_policy,
)
from teamslam.msckf.filter.models import (
    linearisation_reach,
    observe,
    observe_jacobians,
    points_in_camera,
)
from teamslam.msckf.filter.state import MsckfState, RobotWindow
from teamslam.msckf.filter.update import (
    MeasurementRows,
    compress,
    householder_project,
    null_space_rows,
    triangulate,
)
from teamslam.msckf.filter.views import ObjectViews
from teamslam.msckf.objects.tracking import ObjectTracker
from teamslam.msckf.settings.health import (
    SensorHealth,
    odometry_lag_residuals,
    odometry_step_residual,
)
from teamslam.msckf.settings.values import MsckfConfig

__all__ = ["MsckfAgent", "grown"]

log = logging.getLogger(__name__)

#: Gauss–Newton iterations of an object's triangulation before it enters the state: to
#: convergence, so that its first estimate is the least-squares point of its observations (a far
#: object seen from a few frames has a flat cost along its depth, where 8 iterations — enough
#: for geometric features, which are projected out — can stop metres short)
OBJECT_GAUSS_NEWTON_ITERATIONS = 32


def grown(array: np.ndarray, needed: int) -> np.ndarray:
    """``array`` with room for at least ``needed`` rows along its first axis (capacity doubled,
    the rows held kept, the new ones zero): per-frame records of a sequence that grows."""
    out = np.zeros((max(needed, 2 * array.shape[0]), *array.shape[1:]), dtype=array.dtype)
    out[: array.shape[0]] = array
    return out


class MsckfAgent:
    """One robot's filter over its own sequence.

    Parameters
    ----------
    robot
        Robot index in the team.
    calibration
        Stereo rig and body-to-camera transform.
    sequence
        The robot's recorded data (its first ground-truth pose is the known start).
    config
        Filter settings.
    record_innovations
        Keep every innovation for calibration (:attr:`health`); rejected inputs are then only
        counted, not logged.
    state
        The robot's window in a team state (the centralised filter); default: a state of its
        own starting at the robot's first ground-truth pose.
    truth
        Ground truth, needed by the ``ideal`` linearisation (simulation only).
    """

    def __init__(
        self,
        robot: int,
        calibration: Calibration,
        sequence: RobotSequence,
        config: MsckfConfig,
        record_innovations: bool = False,
        state: RobotWindow | None = None,
        truth: GroundTruth | None = None,
    ) -> None:
        self.robot = robot
        self.camera = calibration.camera
        self.T_cam_body = calibration.T_cam_body
        self.image_size = calibration.image_size
        self.sequence = sequence
        self.config = config
        self.policy = linearization_policy(config.filter.linearization)
        if self.policy.needs_truth and truth is None:
            raise ValueError(
                f"robot {robot}: the {config.filter.linearization} linearisation needs ground "
                "truth (simulated data only)"
            )
        self.truth = truth
        self.state: MsckfState | RobotWindow = (
            state
            if state is not None
            else MsckfState(
                sequence.T_world_body[0],
                0,
                np.eye(6) * config.filter.initial_pose_std**2,
                config.filter.debug,
                robot=robot,
            )
        )
        self.tracks: dict[int, list[tuple[int, np.ndarray]]] = defaultdict(list)
        self.object_history: dict[int, list[tuple[int, np.ndarray]]] = defaultdict(list)
        self.counters: dict[str, int] = defaultdict(int)
        #: whether the robot averages with neighbours (set by its driver): it then re-anchors
        #: objects only with ``objects.reanchor_with_consensus``
        self.with_consensus = False
        self.timings: dict[str, float] = defaultdict(float)
        self._warned: set[str] = set()
        self.health = SensorHealth(record=record_innovations)
        self._odometry_rejected: set[int] = set()
        self._frame_times = np.zeros((sequence.frames, 3))
        self.frame = -1
        #: the most objects of the state observed within one window so far (the budget of
        #: ``objects.active_windows`` is this many times that)
        self.window_objects_peak = 0
        # detections without ids: the robot names its objects itself (tracking.py)
        self.tracker: ObjectTracker | None = None
        self._tracked: tuple[np.ndarray, np.ndarray] | None = None
        #: with a tracker: the object id the tracker gave each detection of the last frame
        #: (``-1``: none, as :class:`~teamslam.msckf.objects.tracking.TrackerFrame` ``ids``)
        self.detection_ids: np.ndarray | None = None
        #: from where the cameras saw each object (:mod:`teamslam.msckf.filter.views`): recorded
        # each
        #: frame when a summary of the map needs it (association without shared ids, loop
        #: closure in the robot's own map)
        self.views = ObjectViews()
        #: how overconfident the objects are, learned from the pairs of the association
        #: (:meth:`learn_overconfidence`), and the factor of new boxes' variance (``None``: 1)
        self.overconfidence = Overconfidence()
        self._kappa: float | None = None
        #: the factor in force at each object's last update, where it was above 1
        self._object_kappa: dict[int, float] = {}
        #: under which factor each object's boxes were taken: how much its covariance is
        #: widened where the tracker gates once the factor grows
        self._formed = FormedUnder()
        # each object's size over its disparity, where no tracker learns it (ids given)
        self._extents = ObjectExtents()
        self._occlusion_sigmas = occlusion_sigmas(config.tracking.gate_probability)
        tracking = sequence.detections is not None and sequence.objects.ids.size == 0
        self._record_views = config.association.mode == "own" or (
            tracking and config.tracking.loop_closure
        )
        self._learns_overconfidence = (
            tracking
            and config.filter.object_overconfidence
            and sequence.detections.sizes is not None
        )
        if tracking:
            self.tracker = ObjectTracker(
                robot,
                self.camera,
                self.T_cam_body,
                config,
                views=self.views.of if self._record_views else None,
                image_size=calibration.image_size,
            )
            if self._learns_overconfidence:
                self.tracker.widening = self._widening

    @property
    def extents(self) -> ObjectExtents:
        """Each object's size over its disparity (box rows): the tracker's, which learns it
        from every box it names, or with ids given the robot's own, from the boxes its filter
        takes (:func:`~teamslam.msckf.filter.box_noise.occlusion_shift`)."""
        return self._extents if self.tracker is None else self.tracker.extents

    # ------------------------------------------------------------------ bookkeeping
    def reject(self, what: str, count: int = 1, reason: str = "") -> None:
        """Count ``count`` rejected inputs of kind ``what``; log the first one with its reason."""
        self.counters[f"rejected_{what}"] += count
        if what not in self._warned and not self.health.record:
            self._warned.add(what)
            log.warning(
                "robot %d: rejecting %s (%s); further ones are only counted",
                self.robot,
                what,
                reason or "invalid",
            )

    @property
    def frame_times(self) -> np.ndarray:
        """``(frame + 1, 3)`` seconds of each processed frame in propagation, update and
        initialisation (a view)."""
        return self._frame_times[: self.frame + 1]

    @property
    def n_frames(self) -> int:
        """Frames in the robot's sequence."""
        return self.sequence.frames

    # ------------------------------------------------------------------ snapshot
    def snapshot(self) -> dict[str, np.ndarray]:
        """Everything needed to continue from the last processed frame, as arrays only.

        The state (:meth:`MsckfState.snapshot`), the open feature tracks and object
        observation histories, the objects' views
        (:class:`~teamslam.msckf.filter.views.ObjectViews`),
        per-frame stage times, counters and timings; with a tracker of detections, its state
        (:meth:`~teamslam.msckf.objects.tracking.ObjectTracker.state_dict`, keys ``tracker_*``).
        """
        out = {f"state_{k}": v for k, v in self.state.snapshot().items()}
        for name, history in (("tracks", self.tracks), ("objhist", self.object_history)):
            ids, frames, zs = [], [], []
            for key, obs in history.items():
                for f, z in obs:
                    ids.append(key)
                    frames.append(f)
                    zs.append(z)
            out[f"{name}_ids"] = np.array(ids, dtype=np.int64)
            out[f"{name}_frames"] = np.array(frames, dtype=np.int64)
            width = len(zs[0]) if zs else 4  # box rows: filter/box_noise.py
            out[f"{name}_z"] = np.array(zs, dtype=float).reshape(-1, width)
        out.update({f"views_{k}": v for k, v in self.views.arrays().items()})
        if len(self.overconfidence):
            out.update({f"overconfidence_{k}": v for k, v in self.overconfidence.arrays().items()})
        if len(self._formed):
            out.update({f"formed_{k}": v for k, v in self._formed.arrays().items()})
        if self._object_kappa:
            out["overconfidence_object_ids"] = np.array(list(self._object_kappa), np.int64)
            out["overconfidence_object_kappa"] = np.array(list(self._object_kappa.values()))
        out["frame"] = np.array(self.frame, dtype=np.int64)
        out["window_objects_peak"] = np.array(self.window_objects_peak, dtype=np.int64)
        out["frame_times"] = np.array(self.frame_times, dtype=float).reshape(-1, 3)
        out["counter_names"] = np.array(sorted(self.counters), dtype=str)
        out["counter_values"] = np.array([self.counters[k] for k in sorted(self.counters)], int)
        out["timing_names"] = np.array(sorted(self.timings), dtype=str)
        out["timing_values"] = np.array([self.timings[k] for k in sorted(self.timings)], float)
        if self.tracker is not None:
            out.update({f"tracker_{k}": v for k, v in self.tracker.state_dict().items()})
        elif len(self._extents):
            out["extents"] = self._extents.arrays()
        return out

    def restore(self, snapshot: dict[str, np.ndarray]) -> None:
        """Continue from a :meth:`snapshot` (of this robot's filter on the same sequence).

        Raises
        ------
        ValueError
            A snapshot that is incomplete or inconsistent (named); the agent is unchanged.
        """
        try:
            frame = int(snapshot["frame"])
            frame_times = np.asarray(snapshot["frame_times"], dtype=float).reshape(-1, 3)
            histories = {}
            for name in ("tracks", "objhist"):
                ids, frames = snapshot[f"{name}_ids"], snapshot[f"{name}_frames"]
                zs = np.asarray(snapshot[f"{name}_z"], dtype=float)
                zs = zs.reshape(ids.size, -1) if ids.size else zs.reshape(0, 4)
                if not ids.shape == frames.shape == zs.shape[:1]:
                    raise InputError(f"snapshot {name}: {ids.shape} ids, {zs.shape} observations")
                history: dict[int, list[tuple[int, np.ndarray]]] = defaultdict(list)
                for key, f, z in zip(ids.tolist(), frames.tolist(), zs, strict=True):
                    history[key].append((f, z.copy()))
                histories[name] = history
            names = (snapshot["counter_names"].tolist(), snapshot["timing_names"].tolist())
            values = (snapshot["counter_values"].tolist(), snapshot["timing_values"].tolist())
            counters = dict(zip(names[0], values[0], strict=True))
            timings = dict(zip(names[1], values[1], strict=True))
            views = ObjectViews.from_arrays(snapshot["views_ids"], snapshot["views_sums"])
            overconfidence = Overconfidence.from_arrays(
                {
                    "keys": snapshot.get("overconfidence_keys", np.zeros((0, 3), np.int64)),
                    "values": snapshot.get("overconfidence_values", np.zeros(0)),
                    "alternative_counts": snapshot.get(
                        "overconfidence_alternative_counts", np.zeros(0, np.int64)
                    ),
                    "alternatives": snapshot.get("overconfidence_alternatives", np.zeros(0)),
                }
            )
            formed = FormedUnder.from_arrays(
                {
                    "ids": snapshot.get("formed_ids", np.zeros(0, np.int64)),
                    "values": snapshot.get("formed_values", np.zeros((0, 2))),
                }
            )
            extents = ObjectExtents.from_arrays(snapshot.get("extents", np.zeros((0, 3))))
            tracker = None
            if self.tracker is not None:  # its ids continue (a copy: unchanged on failure)
                tracker = copy.deepcopy(self.tracker)
                try:
                    tracker.load_state(
                        {k[8:]: v for k, v in snapshot.items() if k[:8] == "tracker_"}
                    )
                except KeyError as exc:
                    raise KeyError(f"tracker_{exc.args[0]}") from None
        except KeyError as exc:
            raise InputError(f"robot {self.robot}: snapshot lacks {exc.args[0]!r}") from None
        except ValueError as exc:
            raise InputError(f"robot {self.robot}: snapshot {exc}") from None
        if not -1 <= frame < self.sequence.frames or frame_times.shape[0] != frame + 1:
            raise InputError(
                f"robot {self.robot}: snapshot at frame {frame} with {frame_times.shape[0]} "
                f"frame times, sequence of {self.sequence.frames} frames"
            )
        self.state.restore({k[6:]: v for k, v in snapshot.items() if k.startswith("state_")})
        self.frame = frame
        self.window_objects_peak = int(snapshot.get("window_objects_peak", 0))
        self._frame_times = np.zeros((max(self.sequence.frames, frame + 1), 3))
        self._frame_times[: frame + 1] = frame_times
        self.tracks = histories["tracks"]
        self.object_history = histories["objhist"]
        self.counters = defaultdict(int, counters)
        self.timings = defaultdict(float, timings)
        self.views = views
        self.overconfidence = overconfidence
        self._formed = formed
        self._extents = extents
        self._kappa = self._learned_kappa()
        self._object_kappa = dict(
            zip(
                np.asarray(snapshot.get("overconfidence_object_ids", [])).tolist(),
                np.asarray(snapshot.get("overconfidence_object_kappa", []), float).tolist(),
                strict=True,
            )
        )
        if tracker is not None:
            self.tracker = tracker
            if tracker.views is not None:
                tracker.views = views.of

    # ------------------------------------------------------------------ overconfidence
    def learn_overconfidence(self, tables: dict) -> None:
        """Learn how overconfident the objects are from the association's links ``tables``
        (neighbour → :class:`~teamslam.association.CorrespondenceTable`): each pair a link
        identified by its held pairs' transform before holding it, with the squared Mahalanobis
        distance of the two robots' estimates it recorded then
        (:class:`~teamslam.msckf.filter.box_noise.Overconfidence`). The factor applies to the
        boxes of the frames after (``filter.object_overconfidence``; detections with a box
        size only: other rows never use it)."""
        if not self._learns_overconfidence:
            return
        for j, table in tables.items():
            self._learn_from(j, table.frame_samples())

    @property
    def overconfidence_factor(self) -> float:
        """``κ``: the factor by which the calibrated box noise was found too small so far (new
        boxes' variance is multiplied by it; 1.0 while none is learned,
        :meth:`learn_overconfidence`)."""
        return 1.0 if self._kappa is None else float(self._kappa)

    def _learn_from(
        self, source: int, pairs: dict, factors: dict | None = None, alternatives=None
    ) -> None:
        """Samples ``pairs`` (two ids → ``d²``) of ``source`` (a neighbour, or ``-1``: the
        robot's own re-identifications, with the ``d²`` of each one's ``alternatives``) taken
        under ``factors`` (per pair; default the factor in force now)."""
        kappa = 1.0 if self._kappa is None else self._kappa
        factors = kappa if factors is None else factors
        if self.overconfidence.add(source, pairs, factors, alternatives):
            self._kappa = self._learned_kappa()
            self.counters["overconfidence_samples"] = len(self.overconfidence)

    def _widening(self, ids: np.ndarray) -> np.ndarray:
        """Per object of ``ids`` the factor by which its covariance is too small for the box
        noise now in force (:class:`~teamslam.msckf.filter.box_noise.FormedUnder`; 1 while the
        factor is 1)."""
        if self._kappa is None:
            return np.ones(np.size(ids))
        return self._formed.widening(ids, self._kappa)

    def _learned_kappa(self) -> float | None:
        """The factor of new boxes' variance: ``None`` while it is 1 (the calibrated noise,
        computed exactly as without the learner)."""
        kappa = self.overconfidence.kappa
        return kappa if kappa > 1.0 and self.config.filter.object_overconfidence else None

    # ------------------------------------------------------------------ Algorithm 1, steps 2-4
    def step(self, t: int) -> None:
        """Process frame ``t``: propagate (``t > 0``), update, initialise objects, slide.

        Raises
        ------
        EstimationError
            The filter failed numerically (a covariance lost positive definiteness, a
            non-finite measurement row); the text names the robot and the frame.
        InternalError
            Frames out of order (a driver bug).
        """
        if t != self.frame + 1:
            raise InternalError(
                f"robot {self.robot}: frames must be processed in order (got {t} after "
                f"{self.frame})"
            )
        try:
            self._step(t)
        except (NotPositiveDefiniteError, np.linalg.LinAlgError, FloatingPointError) as exc:
            raise EstimationError(f"robot {self.robot}, frame {t}: {exc}") from exc

    def _step(self, t: int) -> None:
        begin = time.perf_counter()
        if t > 0:
            self._propagate(t)
        if self.tracker is not None and self.config.filter.use_objects:
            self._track(t)
        if self.config.filter.use_objects and len(self.state.retired):
            self._reenter_objects(t)
        after_propagation = time.perf_counter()
        rows = MeasurementRows.empty()
        if self.config.filter.use_geometric_features:
            rows = rows.extend(self._feature_rows(t))
        object_rows, object_rows_at = MeasurementRows.empty(), None
        if self.config.filter.use_objects:
            object_rows, object_rows_at = self._object_rows(t)
        iterated = self.config.objects.update_iterations > 1 and object_rows_at is not None
        if not iterated:
            rows = rows.extend(object_rows)
        if rows.rows:
            self.state.update_rows(compress(rows))
            self.counters["updates"] += 1
        if iterated:
            # features first (their null-space rows are linear in the error state), then the
            # objects by an iterated EKF from the updated estimate
            _, used = self.state.iterated_update(
                object_rows_at, self.config.objects.update_iterations
            )
            self.counters["object_linearizations"] += used
            self.counters["updates"] += 1
        after_update = time.perf_counter()
        if self.config.filter.use_objects:
            self._initialise_objects(t)
            objects = self.config.objects
            if objects.retire_after > 0 or objects.max_active > 0 or objects.active_windows > 0:
                self._retire_objects(t)
        while self.state.n_poses > self.config.filter.window:
            self._odometry_health(0)
            self.state.marginalize_oldest()
        if self._record_views and self.config.filter.use_objects:
            r_world_cam = self.state.current_pose[:3, :3] @ self.T_cam_body[:3, :3].T
            self.views.record(t, r_world_cam, self.camera.intrinsics, self.object_history)
        self._prune_histories()
        end = time.perf_counter()
        stages = (after_propagation - begin, after_update - after_propagation, end - after_update)
        self.timings["propagation"] += stages[0]
        self.timings["update"] += stages[1]
        self.timings["initialisation"] += stages[2]
        if t >= self._frame_times.shape[0]:  # a sequence that grows while it runs (live)
            self._frame_times = grown(self._frame_times, t + 1)
        self._frame_times[t] = stages
        self.frame = t

    def _propagate(self, t: int) -> None:
        odometry = self.sequence.odometry[t - 1]
        cov = self.config.filter.odometry_cov()
        # a sequence made while it is recorded may skip frames: an increment spanning k of
        # them has k steps' noise (a recorded sequence has no spans: every increment one step)
        spans = getattr(self.sequence, "odometry_spans", None)
        if spans is not None and spans[t - 1] != 1:
            cov = cov * spans[t - 1]
        if not np.all(np.isfinite(odometry)):
            self.reject("odometry", reason="non-finite relative pose")
            self._odometry_rejected.add(t - 1)
            odometry = np.eye(4)
            cov = cov * 1e4  # no motion information at all for this step
        state = self.state
        true_step = None
        if self.policy.needs_truth:
            true_step = se3.inverse(self.truth.T_world_body[t - 1]) @ self.truth.T_world_body[t]
        step = self.policy.propagation_step(
            state.pose_fe[-1], state.current_pose @ odometry, odometry, true_step
        )
        state.augment(odometry, t, cov, jacobian_step=step)

    def _true_poses(self, window_index: np.ndarray) -> np.ndarray | None:
        """True poses of window positions (``None`` unless the policy needs them)."""
        if not self.policy.needs_truth:
            return None
        return self.truth.T_world_body[self.state.frames[window_index]]

    def _linearization_poses(self, window_index: np.ndarray) -> np.ndarray:
        """Window poses at which the policy evaluates ``H``."""
        state = self.state
        return self.policy.poses(
            state.poses[window_index], state.pose_fe[window_index], self._true_poses(window_index)
        )

    def _odometry_health(self, index: int) -> None:
        """Smoothed residual of the odometry between window poses ``index`` and ``index + 1``."""
        state = self.state
        first = int(state.frames[index])
        if state.frames[index + 1] != first + 1 or first in self._odometry_rejected:
            return
        pair = state.pose(np.array([index, index + 1]))
        moment = odometry_step_residual(
            state.poses[index : index + 2], self.sequence.odometry[first], state.covariance(pair)
        )
        assumed = np.square(self.config.filter.odometry_std)
        self.health.odometry(moment, assumed)
        if self.health.record and index == 0:
            # every lag of the window (consecutive frames, no rejected step) for calibration
            frames = state.frames
            last = 1
            while (
                last < state.n_poses
                and frames[last] == first + last
                and int(frames[last - 1]) not in self._odometry_rejected
            ):
                last += 1
            if last > 2:
                moment, design = odometry_lag_residuals(
                    state.poses[:last],
                    self.sequence.odometry[first : first + last - 1],
                    state.covariance(state.pose(np.arange(last))),
                )
                self.health.odometry_lags(moment, design, assumed)

    def flush_odometry_health(self) -> None:
        """At the end of a run: add the odometry residuals of the poses still in the window."""
        for index in range(self.state.n_poses - 1):
            self._odometry_health(index)

    # ------------------------------------------------------------------ geometric features
    def _finite_observations(self, kind: str, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Frame ``t``'s ``features`` or ``objects``, rejecting (and counting) non-finite rows."""
        if kind == "objects" and self._tracked is not None:
            return self._tracked  # the tracker's, already finite
        ids, z = getattr(self.sequence, kind).frame(t)
        finite = np.all(np.isfinite(z), axis=1)
        if not finite.all():
            what = "feature_measurements" if kind == "features" else "object_measurements"
            self.reject(what, int((~finite).sum()), "non-finite")
            ids, z = ids[finite], z[finite]
        return ids, z

    def _feature_rows(self, t: int) -> MeasurementRows:
        ids, z = self._finite_observations("features", t)
        seen = set(ids.tolist())
        for i, row in zip(ids.tolist(), z, strict=True):
            self.tracks[i].append((t, row))
        ready = [i for i in self.tracks if i not in seen]
        window_full = self.state.n_poses > self.config.filter.window
        if window_full:
            oldest = self.state.frames[0]
            ready += [i for i in seen if self.tracks[i][0][0] == oldest]
        groups: dict[int, list[tuple[np.ndarray, np.ndarray, int]]] = defaultdict(list)
        for i in ready:
            obs = self.tracks.pop(i)
            frames = np.array([f for f, _ in obs])
            widx = self.state.window_index(frames)
            keep = widx >= 0
            if keep.sum() >= self.config.filter.min_track_length:
                groups[int(keep.sum())].append(
                    (
                        widx[keep],
                        np.stack([zz for (_, zz), k in zip(obs, keep, strict=True) if k]),
                        i,
                    )
                )
        rows = MeasurementRows.empty()
        variance = self.config.filter.feature_std**2
        block = self.state.window_columns  # the rows are compact over the window poses
        window = np.arange(block.start, block.stop)
        for n, members in groups.items():
            widx = np.stack([w for w, _, _ in members])
            zs = np.stack([zz for _, zz, _ in members])
            poses = self.state.poses[widx]
            points, ok, _ = triangulate(self.camera, self.T_cam_body, poses, zs)
            self.counters["features_used"] += int(ok.sum())
            if not ok.all():
                self.counters["rejected_triangulation"] += int((~ok).sum())
            if not ok.any():
                continue
            track_ids = np.array([i for _, _, i in members])[ok]
            true_points = self.truth.track_points(track_ids) if self.policy.needs_truth else None
            pred = observe(self.camera, self.T_cam_body, poses[ok], points[ok][:, None, :])
            _, d_pose, d_point = observe_jacobians(
                self.camera,
                self.T_cam_body,
                self._linearization_poses(widx[ok]),
                self.policy.feature_points(points[ok], true_points)[:, None, :],
            )
            r0, h0, s = null_space_rows(
                self.state.covariance(block),
                self.state.pose(widx[ok]).columns - block.start,
                window.size,
                pred,
                d_pose,
                d_point,
                zs[ok],
                variance,
            )
            accepted, _ = self.health.test(
                "features", r0, s, variance, float(self.config.filter.gate(4 * n - 3))
            )
            self.counters["rejected_features_gate"] += int((~accepted).sum())
            h0 = h0[accepted].reshape(-1, window.size)
            rows = rows.extend(
                MeasurementRows(h0, r0[accepted].ravel(), np.full(h0.shape[0], variance), window)
            )
        return rows

    # ------------------------------------------------------------------ objects
    def _track(self, t: int) -> None:
        """Name frame ``t``'s detections (:class:`ObjectTracker`): what the filter then reads as
        this frame's object observations; the earlier detections of tracks confirmed now go
        into the object histories first."""
        begin = time.perf_counter()
        z, classes = self.sequence.detections.frame(t)
        finite = np.all(np.isfinite(z), axis=1)
        if not finite.all():
            # a box seen in the left image only (no stereo match) is expected, and counted; the
            # object update needs both images
            monocular = ~finite & np.all(np.isfinite(z[:, :2]), axis=1)
            self.counters["detections_monocular"] += int(monocular.sum())
            if (~finite & ~monocular).any():
                self.reject("object_measurements", int((~finite & ~monocular).sum()), "non-finite")
        sizes = self.sequence.detections.sizes_of(t)
        if sizes is not None:  # each box its own noise (filter/box_noise.py)
            f = self.config.filter
            z = box_rows(z, sizes, self.image_size, f.object_std, f.object_size_share)
            clipped = z[finite, 6:10].any(axis=1)
            self.counters["detections_clipped"] += int(clipped.sum())
        frame = self.tracker.assign(
            t,
            z,
            classes,
            self.state,
            self.config.filter.odometry_cov(),
            self.sequence.detections.appearance_of(t),
        )
        if self.tracker.revisit_d2:  # the robot's own re-identifications by appearance
            if self._learns_overconfidence:
                factors = {
                    (n, o): 0.5 * (self._object_kappa.get(n, 1.0) + self._object_kappa.get(o, 1.0))
                    for n, o in self.tracker.revisit_d2
                }
                self._learn_from(
                    -1, self.tracker.revisit_d2, factors, self.tracker.revisit_alternatives
                )
            self.tracker.revisit_d2 = {}
            self.tracker.revisit_alternatives = {}
        for new, old in frame.merged.tolist():  # loop closure: one object seen again
            self.views.merge(new, old)
            self._formed.merge(new, old)
        for tid, frames, zs in frame.confirmed:
            self.object_history[tid].extend(
                (int(f), row) for f, row in zip(frames.tolist(), zs, strict=True)
            )
        self.detection_ids = frame.ids
        out = (frame.ids >= 0) & finite  # a box named in the left image only: not for the filter
        self._tracked = (frame.ids[out], z[out])
        for name, value in self.tracker.counters.items():
            self.counters[name] = value
        self.timings["tracking"] += time.perf_counter() - begin

    def _reenter_objects(self, t: int) -> None:
        """Bring the retired objects observed at ``t`` back into the state (before the update)."""
        if self._tracked is not None:
            ids, z = self._tracked
        else:
            ids, z = self.sequence.objects.frame(t)
        ids = np.unique(ids[np.all(np.isfinite(z), axis=1)])
        back = ids[self.state.retired.contains(ids)]
        if back.size:
            self.state.reenter_objects(back, t)
            self.counters["objects_reentered"] += int(back.size)

    def _retire_objects(self, t: int) -> None:
        """Move to the persistent map the objects unobserved for ``objects.retire_after``
        frames, then, beyond the budget (:meth:`active_budget`), the least recently observed
        ones not observed at ``t``."""
        cfg = self.config.objects
        last_seen = self.state.object_last_seen
        stale = np.zeros(last_seen.size, bool)
        if cfg.retire_after > 0:
            stale = t - last_seen >= cfg.retire_after
        budget = self.active_budget(t)
        excess = last_seen.size - int(stale.sum()) - budget
        if budget > 0 and excess > 0:
            candidates = np.flatnonzero(~stale & (last_seen < t))
            oldest = candidates[np.argsort(last_seen[candidates], kind="stable")][:excess]
            stale[oldest] = True
        if stale.any():
            loosened = self.state.retire_objects(np.flatnonzero(stale), cfg.max_consider)
            self.counters["objects_retired"] += int(stale.sum())
            if loosened:
                self.counters["consider_states_dropped"] += loosened

    def active_budget(self, t: int) -> int:
        """The most objects the state may hold after frame ``t`` (0: no bound).

        ``objects.max_active``; with ``objects.active_windows = k > 0``, ``k`` times the most
        objects of the state observed within one window (``filter.window`` frames) so far —
        learned from the robot's own data, so it follows the scene — or the smaller of the two
        when both are set.
        """
        cfg = self.config.objects
        if cfg.active_windows == 0:
            return cfg.max_active
        observed = self.state.object_last_seen > t - self.config.filter.window
        self.window_objects_peak = max(self.window_objects_peak, int(observed.sum()))
        learned = cfg.active_windows * self.window_objects_peak
        return learned if cfg.max_active == 0 or learned == 0 else min(learned, cfg.max_active)

    def _object_rows(self, t: int) -> tuple[MeasurementRows, Callable[[], tuple] | None]:
        """The gated object rows at the current estimate, and a function that linearises the
        same rows again at whatever the state's mean then is (for the iterated update;
        ``None`` when there are no rows)."""
        empty = MeasurementRows.empty(), None
        ids, z = self._finite_observations("objects", t)
        for i, row in zip(ids.tolist(), z, strict=True):
            self.object_history[i].append((t, row))
        slots = self.state.object_slots(ids)
        known = slots >= 0
        self.state.mark_seen(slots[known], t)
        if not known.any():
            return empty
        slots, zk, ids = slots[known], z[known], ids[known]
        # an object the estimate puts (nearly) behind the camera has no usable projection
        _, p_cam = points_in_camera(
            self.state.current_pose, self.state.objects[slots], self.T_cam_body
        )
        in_front = p_cam[:, 2] > 1e-3 * self.camera.baseline
        if not in_front.all():
            self.reject("object_behind_camera", int((~in_front).sum()), "object behind the camera")
            slots, zk, ids = slots[in_front], zk[in_front], ids[in_front]
        if slots.size == 0:
            return empty
        r, local_h, local_p, noise_cov, occluded = self._object_linearization(slots, zk, ids)
        f = self.config.filter
        box = is_box(zk)
        # box rows: each object's rows whitened by its own noise (unit variance after)
        variance = (
            box_variances(zk, f.object_std, f.object_size_share, self._kappa)
            if box
            else f.object_std**2
        )
        s = local_h @ local_p @ np.swapaxes(local_h, 1, 2) + noise_cov
        accepted, nis = self.health.test(
            "objects",
            r,
            s,
            variance,
            float(f.gate(4)),
            size2=box_size2(zk) if box else None,
            clipped=(zk[:, 6:10].any(axis=1) | occluded) if box else None,
        )
        self.counters["rejected_objects_gate"] += int((~accepted).sum())
        self.counters["object_updates"] += int(accepted.sum())
        if not accepted.any():
            return empty
        noise = np.full(int(accepted.sum()), 1.0 if box else variance)
        if self.config.objects.loss != "none":  # one M-estimator reweighting step
            weight = self.config.objects.robust_weight(np.sqrt(nis[accepted]))
            self.counters["objects_downweighted"] += int((weight < 1).sum())
            noise = noise / weight
        slots, zk, ids = slots[accepted], zk[accepted], ids[accepted]
        if self._learns_overconfidence:
            for i in ids.tolist():  # its first boxes: those of its initialisation
                if i not in self._formed.boxes:
                    initial = max(len(self.object_history[i]) - 1, 1)
                    self._formed.add(np.array([i]), self._object_kappa.get(i, 1.0), initial)
            self._formed.add(ids, 1.0 if self._kappa is None else self._kappa)
        if self._kappa is not None:
            self._object_kappa.update(dict.fromkeys(ids.tolist(), self._kappa))
        if box and self.tracker is None:  # with ids given the robot learns the sizes itself
            whole = ~occluded[accepted]  # of whole boxes (not cut short): z − r is predicted
            pred = zk[whole, :4] - r[accepted][whole]
            self._extents.add(ids[whole], pred[:, 0] - pred[:, 2], zk[whole])
        rows = self._object_measurement_rows(
            slots, local_h[accepted], r[accepted], noise_cov[accepted], noise, box
        )

        def rows_at() -> MeasurementRows:
            r, local_h, _, noise_cov, _ = self._object_linearization(slots, zk, ids)
            return self._object_measurement_rows(slots, local_h, r, noise_cov, noise, box)

        return rows, rows_at

    def _object_linearization(
        self, slots: np.ndarray, z: np.ndarray, ids: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Rows of the objects ``slots`` observed as ``z``, at the state's current mean.

        Returns the residuals ``(k, 4)``, each object's local Jacobian ``(k, 4, 9)`` over the
        current pose and the object and the covariance of those columns ``(k, 9, 9)``, each
        object's ``(k, 4, 4)`` measurement noise (with the policy's linearisation noise when it
        compensates), and ``(k,)`` which boxes fell short of their object and were taken at the
        edge an occluder left (:func:`~teamslam.msckf.filter.box_noise.occlusion_shift`).
        """
        state = self.state
        k = slots.size
        box = is_box(z)
        pred = observe(self.camera, self.T_cam_body, state.current_pose, state.objects[slots])
        _, d_pose, d_point = observe_jacobians(
            self.camera,
            self.T_cam_body,
            self._linearization_poses(np.array(state.n_poses - 1)),
            self.policy.objects(
                state.objects[slots],
                state.object_fe[slots],
                self.truth.objects(ids) if self.policy.needs_truth else None,
            ),
        )
        # each object's 9 columns (current pose + object) and their covariance
        pose_cols = np.broadcast_to(state.newest_pose().columns, (k, 6))
        local_cols = np.concatenate([pose_cols, state.object(slots).columns], axis=1)
        local_p = state.covariance(local_cols)
        d_pose, d_point = self.policy.constrain(
            d_pose, d_point, state.pose_fe[-1], state.object_fe[slots], local_p
        )
        local_h = np.concatenate([d_pose, d_point], axis=2)  # (k, 4, 9)
        f = self.config.filter
        r = z[:, :4] - pred
        occluded = np.zeros(k, bool)
        if box:
            variances = box_variances(z, f.object_std, f.object_size_share, self._kappa)
            # a box short of its object: at the edge an occluder left (box_noise.py)
            own = box_variances(z, f.object_std, f.object_size_share)
            # the predicted size's variance: the current pose's and the object's, projected
            expected = self.extents.expected(
                ids, pred, local_h @ local_p @ np.swapaxes(local_h, 1, 2)
            )
            shift, variances = occlusion_shift(
                expected, z, r, variances, own, self._occlusion_sigmas
            )
            r = r + shift
            occluded = (shift != 0).any(axis=1)
            noise_cov = variances[:, :, None] * np.eye(4)
        else:
            noise_cov = np.broadcast_to(f.object_std**2 * np.eye(4), (k, 4, 4))
        if self.policy.compensates:
            # the rows are not the current-estimate Jacobians: their difference, times the
            # state error, is part of the residual (linearisation.py, FEJ2 compensation)
            _, c_pose, c_point = observe_jacobians(
                self.camera, self.T_cam_body, state.current_pose, state.objects[slots]
            )
            current_h = np.concatenate([c_pose, c_point], axis=2)
            noise_cov = noise_cov + self.policy.linearization_noise(local_h, current_h, local_p)
        return r, local_h, local_p, noise_cov, occluded

    def _object_measurement_rows(
        self,
        slots: np.ndarray,
        local_h: np.ndarray,
        r: np.ndarray,
        noise_cov: np.ndarray,
        noise: np.ndarray,
        box: bool = False,
    ) -> MeasurementRows:
        """Stacked rows of accepted objects ``slots`` (local Jacobians ``(k, 4, 9)`` over the
        current pose and the object) with per-object noise variance ``noise``, compact over the
        current pose's and the objects' columns; ``box``: each object its own 4 × 4 noise
        ``noise_cov``, the rows whitened by it and ``noise`` relative to it."""
        if box:
            # each detection's own noise: whiten by all of it (the rows' variance is then 1)
            chol = np.linalg.cholesky(noise_cov)
            local_h = np.linalg.solve(chol, local_h)
            r = np.linalg.solve(chol, r[..., None])[..., 0]
        elif self.policy.compensates:
            # whiten each object's rows by its 4 × 4 noise: L⁻¹H, L⁻¹r with LLᵀ = noise
            chol = np.linalg.cholesky(noise_cov / self.config.filter.object_std**2)
            local_h = np.linalg.solve(chol, local_h)
            r = np.linalg.solve(chol, r[..., None])[..., 0]
        state = self.state
        k = slots.size
        held, position = np.unique(slots, return_inverse=True)  # an object seen twice: once
        columns = np.concatenate([state.newest_pose().columns, state.object(held).columns.ravel()])
        h = np.zeros((k, 4, columns.size))
        h[:, :, :6] = local_h[:, :, :6]
        object_at = 6 + 3 * position.reshape(k)[:, None, None] + np.arange(3)[None, None, :]
        h[np.arange(k)[:, None, None], np.arange(4)[None, :, None], object_at] = local_h[:, :, 6:]
        return MeasurementRows(h.reshape(4 * k, -1), r.ravel(), np.repeat(noise, 4), columns)

    def _initialise_objects(self, t: int) -> None:
        cfg = self.config
        self._reanchor_objects(t)
        candidates = []
        in_map = set(self.state.object_ids.tolist())
        for oid, obs in self.object_history.items():
            if obs[-1][0] != t or oid in in_map:
                continue
            frames = np.array([f for f, _ in obs])
            widx = self.state.window_index(frames)
            keep = widx >= 0
            if keep.sum() >= cfg.objects.init_observations:
                zs = np.stack([zz for (_, zz), k in zip(obs, keep, strict=True) if k])
                candidates.append((oid, widx[keep], zs))
        if not candidates:
            self._use_waiting_objects(t)
            return
        by_length: dict[int, list] = defaultdict(list)
        for c in candidates:
            by_length[c[1].size].append(c)
        variance = cfg.filter.object_std**2
        for n, members in by_length.items():
            widx = np.stack([m[1] for m in members])
            zs = np.stack([m[2] for m in members])
            points, ok, rms = self._triangulate_objects(widx, zs)
            depth = np.linalg.norm(points - self.state.current_pose[:3, 3], axis=1)
            ok &= (depth > cfg.objects.min_depth) & (depth < cfg.objects.max_depth)
            ok &= self._fits_its_rows(zs, rms)
            self.counters["rejected_object_init"] += int((~ok).sum())
            moved = False
            for j in np.flatnonzero(ok):
                point = points[j]
                if moved:
                    # an earlier object's update moved the poses: the least-squares point at
                    # the poses its rows are formed at, so that it enters at the optimum
                    again, good, _ = self._triangulate_objects(widx[j][None], zs[j][None])
                    if not good[0]:
                        self.counters["rejected_object_init"] += 1
                        continue
                    point = again[0]
                moved |= self._add_object(members[j][0], point, widx[j], zs[j], variance, n)
        self._use_waiting_objects(t)

    def _reanchor_objects(self, t: int) -> None:
        """Re-anchor the objects observed at ``t`` whose first estimate their data now rule out
        (``objects.reanchor_probability``): each is marginalised out of the state and its
        history cleared, so that it enters again, at a fresh first estimate, from observations
        made after ``t`` only. Not for a team state, whose other robots' histories hold the
        object's earlier observations, nor for a robot that averages with neighbours unless
        ``objects.reanchor_with_consensus`` is set."""
        probability = self.config.objects.reanchor_probability
        state = self.state
        if (
            probability == 0
            or (self.with_consensus and not self.config.objects.reanchor_with_consensus)
            or not keeps_first_estimates(self.config.filter.linearization)
            or isinstance(state, RobotWindow)
        ):
            return
        slots = np.flatnonzero(state.object_last_seen == t)
        if slots.size == 0:
            return
        # the object's marginal: its first estimate as a point of the world, whose rigid
        # motions its rows take
        marginals = state.covariance(state.object(slots).columns)
        distance = first_estimate_distance(state.objects[slots], state.object_fe[slots], marginals)
        moved = slots[distance > chi2_quantile(probability, 3)]
        if moved.size == 0:
            return
        for oid in state.object_ids[moved].tolist():
            self.object_history.pop(oid, None)
        state.marginalize_objects(moved)
        self.counters["objects_reanchored"] += int(moved.size)

    def _use_waiting_objects(self, t: int) -> None:
        """Objects waiting for their rows to be linear enough
        (``objects.init_linearity_probability``) whose oldest observation leaves the window at
        this frame. One still observed at ``t`` has the longest track the window can give it:
        it enters now, from all of it (delayed initialisation). One no longer observed updates
        the poses with its window observations as a geometric feature does (the landmark-free
        rows of :meth:`_add_object`) and starts again from its next observation — no
        observation is used twice."""
        cfg = self.config
        if not self._waits_for_linearity() or self.state.n_poses <= cfg.filter.window:
            return
        oldest = self.state.frames[0]
        in_map = set(self.state.object_ids.tolist())
        for oid, obs in self.object_history.items():
            if oid in in_map or not obs or obs[0][0] != oldest:
                continue
            widx = self.state.window_index(np.array([f for f, _ in obs]))
            keep = widx >= 0
            if keep.sum() >= cfg.objects.init_observations:
                zs = np.stack([zz for (_, zz), k in zip(obs, keep, strict=True) if k])
                points, ok, rms = self._triangulate_objects(widx[keep][None], zs[None])
                if ok[0] and self._fits_its_rows(zs[None], rms)[0]:
                    n, seen = int(keep.sum()), obs[-1][0] == t
                    variance = cfg.filter.object_std**2
                    self._add_object(
                        oid, points[0], widx[keep], zs, variance, n, enter=seen, wait=False
                    )
                    if seen:
                        continue  # in the state now: its history goes as the window slides
            obs.clear()

    def _fits_its_rows(self, zs: np.ndarray, rms: np.ndarray) -> np.ndarray:
        """``(k,)`` whether each triangulated object's RMS residual ``rms`` lies within 3 σ of
        its observations ``zs`` (``(k, n, ·)``): the RMS σ of the boxes' own noise for box rows,
        ``filter.object_std`` otherwise."""
        f = self.config.filter
        if is_box(zs):
            noise = box_variances(zs, f.object_std, f.object_size_share, self._kappa)
            return rms < 3.0 * np.sqrt(noise.mean(axis=(1, 2)))
        return rms < 3.0 * f.object_std

    def _triangulate_objects(
        self, window_index: np.ndarray, zs: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Least-squares points of objects observed as ``zs`` (``(k, n, 4)``) from the window
        poses ``window_index`` (``(k, n)``): :func:`triangulate` to convergence."""
        return triangulate(
            self.camera,
            self.T_cam_body,
            self.state.poses[window_index],
            zs[..., :4],
            iterations=OBJECT_GAUSS_NEWTON_ITERATIONS,
        )

    def _add_object(
        self,
        oid: int,
        point: np.ndarray,
        widx: np.ndarray,
        zs: np.ndarray,
        variance: float,
        n: int,
        enter: bool = True,
        wait: bool = True,
    ) -> bool:
        """QR initialisation (eqs. 29–30), then an update with the landmark-free rows.

        Box rows ``zs`` (each observation its own noise) are whitened first, ``variance`` then
        being 1. Returns whether the object entered the state (and the state was updated);
        ``enter=False``: the landmark-free rows only, as a geometric feature's (returns whether
        they updated the state); ``wait=False``: no linearity test
        (``objects.init_linearity_probability``)."""
        state = self.state
        pred = observe(self.camera, self.T_cam_body, state.poses[widx], point[None])
        true_point = self.truth.objects(np.array([oid]))[0] if self.policy.needs_truth else None
        # the point the rows are evaluated at: the object's first estimate (linearization.py)
        linearised = self.policy.feature_points(point, true_point)
        _, d_pose, d_point = observe_jacobians(
            self.camera, self.T_cam_body, self._linearization_poses(widx), linearised[None]
        )
        # the rows touch only the poses of the observations: work on those 6n columns
        cols = state.pose(widx).columns.ravel()
        h_s = np.zeros((n, 4, n, 6))
        h_s[np.arange(n), :, np.arange(n), :] = d_pose
        h_s = h_s.reshape(4 * n, 6 * n)
        h_p = d_point.reshape(4 * n, 3)
        r = (zs[:, :4] - pred).ravel()
        if is_box(zs):
            f = self.config.filter
            variances = box_variances(zs, f.object_std, f.object_size_share, self._kappa)
            weight = 1.0 / np.sqrt(variances.ravel())
            h_s, h_p, r = h_s * weight[:, None], h_p * weight[:, None], r * weight
            variance = 1.0
        upper, projected = householder_project(h_p[None], np.column_stack([r, h_s])[None])
        r_p, projected = upper[0], projected[0]
        z1, z2 = projected[:3, 0], projected[3:, 0]
        h_s1, h_s2 = projected[:3, 1:], projected[3:, 1:]
        cov_cc = state.covariance(cols)
        # gate the landmark-free part before touching the state
        s2 = h_s2 @ cov_cc @ h_s2.T + variance * np.eye(4 * n - 3)
        # not a sensor-health innovation: it is linearised at a fresh triangulation, so its NIS
        # measures the triangulation as much as the noise
        if z2 @ np.linalg.solve(s2, z2) > self.config.filter.gate(4 * n - 3):
            self.counters["rejected_object_init"] += 1
            return False
        # the rows enter the state below: non-finite ones stop the run before any edit
        state.check_finite(f"initialisation rows of object {oid}", r_p, projected)
        if not enter:
            state.update(h_s2, z2, variance * np.eye(4 * n - 3), columns=cols)
            self.counters["objects_used_as_features"] += 1
            return True
        r_p_inv = np.linalg.inv(r_p)
        position = point + r_p_inv @ z1
        gain = -(r_p_inv @ h_s1)  # the object's error from the poses': δp = G δx[cols] + noise
        cov_ps = gain @ state.cross_covariance(cols)  # Σˢᵖᵀ = −R_p⁻¹ H_s1 Σ
        cov_pp = r_p_inv @ (h_s1 @ cov_cc @ h_s1.T + variance * np.eye(3)) @ r_p_inv.T
        # the point's covariance given the window poses (what its data allow relative to them;
        # the poses' own uncertainty moves it with them and leaves its rows as they are)
        relative = variance * (r_p_inv @ r_p_inv.T)
        if (
            wait
            and self._waits_for_linearity()
            and self._entry_nonlinearity(linearised, widx, zs, relative) > 1
        ):
            # its first estimate, which fixes its rows' directions for good, is not yet known
            # well enough for them: wait for more observations (state untouched)
            self.counters["object_init_deferred"] += 1
            return False
        limit = self.config.objects.init_max_relative_std
        if limit > 0:
            # still uncertain relative to its distance: wait for more observations (the state is
            # untouched, the observations stay in the history)
            distance = np.linalg.norm(position - state.current_pose[:3, 3])
            if np.linalg.eigvalsh(cov_pp)[-1] > (limit * distance) ** 2:
                self.counters["object_init_deferred"] += 1
                return False
        state.add_object(
            oid, position, cov_pp, cov_ps, first_estimate=linearised, from_columns=(gain, cols)
        )
        self.counters["objects_initialised"] += 1
        if self._kappa is not None:
            self._object_kappa[oid] = self._kappa
        # the landmark-free rows, compact over the poses of the observations
        state.update(h_s2, z2, variance * np.eye(4 * n - 3), columns=cols)
        return True

    def _waits_for_linearity(self) -> bool:
        """Whether a new object waits until its rows are near linear: with
        ``objects.init_linearity_probability`` set, for a policy that fixes an object's
        directions at its first estimate (``fej``, ``oc``; the others linearise its rows where
        it is each time)."""
        return self.config.objects.init_linearity_probability > 0 and keeps_first_estimates(
            self.config.filter.linearization
        )

    def _entry_nonlinearity(
        self, point: np.ndarray, widx: np.ndarray, zs: np.ndarray, cov: np.ndarray
    ) -> float:
        """:func:`linearisation_reach` of a new object's rows: linearised at ``point`` (its first
        estimate) from the window poses ``widx`` at which the policy evaluates them, over its
        covariance ``cov`` given those poses, each coordinate whitened by its noise (``zs``' own
        for boxes)."""
        f = self.config.filter
        if is_box(zs):
            std = np.sqrt(box_variances(zs, f.object_std, f.object_size_share, self._kappa))
        else:
            std = np.full((widx.size, 4), f.object_std)
        return linearisation_reach(
            self.camera,
            self.T_cam_body,
            self._linearization_poses(widx),
            point,
            cov,
            std,
            self.config.objects.init_linearity_probability,
        )

    def _prune_histories(self) -> None:
        first = self.state.frames[0]
        if self._odometry_rejected:
            self._odometry_rejected = {f for f in self._odometry_rejected if f >= first}
        for store in (self.object_history, self.tracks):
            stale = []
            for key, obs in store.items():
                while obs and obs[0][0] < first:
                    obs.pop(0)
                if not obs:
                    stale.append(key)
            for key in stale:
                del store[key]
