"""One robot's stereo front-end: rectify, track, match, detect markers, measure a detector's
boxes in stereo, per frame. What it carries from one frame to the next — the feature tracks
and the last frame's stereo disparities — is its :meth:`StereoFrontend.state_dict` (a
checkpoint's)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.frontend._clock import StageClock
from teamslam.frontend.boxes import BoxMeasurements, BoxStereo
from teamslam.frontend.camera import StereoRig
from teamslam.frontend.config import FrontendConfig
from teamslam.frontend.detections import ImageDetections
from teamslam.frontend.markers import MarkerDetector
from teamslam.frontend.stereo import match_stereo
from teamslam.frontend.tracking import FeatureTracker

__all__ = ["FrameMeasurements", "StereoFrontend"]


@dataclass(frozen=True)
class FrameMeasurements:
    """What the front-end measured in one stereo frame.

    Attributes
    ----------
    feature_ids, features
        ``(N,)`` track ids and ``(N, 4)`` stereo observations ``(u_l, v_l, u_r, v_r)``.
    object_ids, objects
        ``(M,)`` marker ids and ``(M, 4)`` stereo marker centres.
    track_ids, track_uv
        All left-image tracks (with or without a stereo match), for visual odometry.
    searched, rejected
        Stereo searches made and rejected by the outlier gate in this frame.
    boxes
        The detector's boxes measured in stereo (:class:`~teamslam.frontend.boxes.BoxStereo`),
        or ``None`` when no boxes were given.
    """

    feature_ids: np.ndarray
    features: np.ndarray
    object_ids: np.ndarray
    objects: np.ndarray
    track_ids: np.ndarray
    track_uv: np.ndarray
    searched: int
    rejected: int
    boxes: BoxMeasurements | None = None


class StereoFrontend:
    """Rectification, tracking, stereo matching and markers for one robot's camera.

    Parameters
    ----------
    rig
        The calibrated stereo pair (rectified on the fly when needed).
    config
        Front-end settings.
    first_id
        First feature-track id (give each robot its own range; :attr:`next_id` after a run
        is the next free id).

    Attributes
    ----------
    clock
        The CPU time of each stage of the frames measured so far
        (:class:`~teamslam.frontend._clock.StageClock`).
    """

    def __init__(
        self, rig: StereoRig, config: FrontendConfig | None = None, first_id: int = 0
    ) -> None:
        self.rig = rig
        self.config = config or FrontendConfig()
        self.camera = rig.camera
        self.pixels = self.config.pixels(rig.image_size)
        self.disparity_range = self.config.disparity_range(self.camera.fx_baseline)
        self.clock = StageClock()
        self.tracker = FeatureTracker(rig.image_size, self.config, first_id, self.clock)
        self.markers = MarkerDetector(self.config)
        self.boxes = BoxStereo(rig, self.config)
        self._last_ids = np.zeros(0, np.int64)
        self._last_disparity = np.zeros(0)

    @property
    def next_id(self) -> int:
        """The next unused feature-track id."""
        return self.tracker.next_id

    def state_dict(self) -> dict[str, np.ndarray]:
        """What the front-end carries to the next frame: the tracker's state
        (:meth:`~teamslam.frontend.tracking.FeatureTracker.state_dict`, keys ``tracker_*``),
        the last frame's stereo-matched track ids and disparities, and the box pairs' width
        ratios (:attr:`BoxStereo.width_ratios <teamslam.frontend.boxes.BoxStereo.width_ratios>`)."""
        out = {f"tracker_{k}": v for k, v in self.tracker.state_dict().items()}
        out["last_ids"] = self._last_ids.copy()
        out["last_disparity"] = self._last_disparity.copy()
        out["box_width_ratios"] = self.boxes.width_ratios.copy()
        return out

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        """Continue from a :meth:`state_dict` of a front-end of the same rig and settings: the
        next frames are measured exactly as the original front-end would have.

        Raises
        ------
        ValueError
            A key missing or arrays that do not fit together.
        """
        if "last_ids" not in state or "last_disparity" not in state:
            raise ValueError("front-end state without the last frame's disparities")
        last_ids = np.asarray(state["last_ids"], np.int64).reshape(-1)
        disparity = np.array(state["last_disparity"]).reshape(-1)
        if disparity.shape != last_ids.shape:
            raise ValueError(
                f"front-end state: {disparity.size} disparities for {last_ids.size} tracks"
            )
        prefix = "tracker_"
        self.tracker.load_state_dict(
            {k[len(prefix) :]: v for k, v in state.items() if k.startswith(prefix)}
        )
        self._last_ids, self._last_disparity = last_ids.copy(), disparity.copy()
        ratios = np.asarray(state.get("box_width_ratios", np.zeros(0)), float).reshape(-1)
        if not np.all(np.isfinite(ratios)):
            raise ValueError("front-end state: box width ratios not finite")
        self.boxes.width_ratios = ratios.copy()

    def predicted(self, ids: np.ndarray, uv: np.ndarray, T_prev_cur: np.ndarray) -> np.ndarray:
        """``(N, 2)``: where the tracks ``ids`` at ``uv`` in the previous rectified left image
        project in the current one, the camera having moved by ``T_prev_cur``: those with a
        stereo disparity in the previous frame by their depth, the others as points at
        infinity (by the rotation alone)."""
        uv = np.asarray(uv, float)
        _, i_now, i_last = np.intersect1d(ids, self._last_ids, return_indices=True)
        depth = np.full(uv.shape[0], np.inf)
        disparity = self._last_disparity[i_last]
        ok = disparity > 0
        depth[i_now[ok]] = self.camera.fx_baseline / disparity[ok]
        k = self.camera.intrinsics
        rays = np.column_stack([uv, np.ones(uv.shape[0])]) @ np.linalg.inv(k).T
        T_cur_prev = np.linalg.inv(T_prev_cur)
        finite = np.isfinite(depth)
        # a point at depth z: R (z·ray) + t; at infinity: R ray
        p_cur = rays @ T_cur_prev[:3, :3].T
        p_cur[finite] = p_cur[finite] * depth[finite, None] + T_cur_prev[:3, 3]
        ahead = p_cur[:, 2] > 1e-6
        out = uv.copy()
        projected = p_cur[ahead] @ k.T
        out[ahead] = projected[:, :2] / projected[:, 2:]
        return out

    def process(
        self,
        left: np.ndarray,
        right: np.ndarray,
        where: str = "",
        detections: ImageDetections | None = None,
        right_detections: ImageDetections | None = None,
        motion: np.ndarray | None = None,
    ) -> FrameMeasurements:
        """Measure one stereo frame of 8-bit grey images (raw; rectified here), and a
        detector's boxes in it when given (raw left-image pixels; the right image's boxes
        too when the detector ran on it).

        ``motion``: the pose of this frame's rectified left camera in the previous frame's
        (``T_prev_cur``, e.g. from odometry over frames dropped in between), or ``None``. With
        it, each track with a stereo depth in the previous frame is looked for where that point
        projects now (:meth:`predicted`); without it, where it was."""
        self.rig.check_images(left, right, where)
        clock = self.clock
        with clock.stage("rectification"):
            left, right = self.rig.rectify(left, right)
        predict = None if motion is None else (lambda i, uv: self.predicted(i, uv, motion))
        left_f = left.astype(np.float32)  # one conversion for the tracker and the matcher
        ids, uv = self.tracker.track(left, predict, left_f)
        guess = np.full(len(ids), np.nan)
        _, i_now, i_last = np.intersect1d(ids, self._last_ids, return_indices=True)
        guess[i_now] = self._last_disparity[i_last]
        m = match_stereo(
            left, right, uv, self.disparity_range, self.config, self.pixels, guess, clock, left_f
        )
        z = np.concatenate([uv, m.uv_right], axis=1)[m.accepted]
        self._last_ids, self._last_disparity = ids[m.accepted], z[:, 0] - z[:, 2]
        with clock.stage("markers"):
            obj_ids, obj_z = self.markers.detect_stereo(
                left, right, self.disparity_range, self.pixels.marker_row
            )
        boxes = None
        if detections is not None:
            with clock.stage("box stereo"):
                boxes = self.boxes.measure(left, right, detections, right_detections)
        return FrameMeasurements(
            feature_ids=ids[m.accepted],
            features=z,
            object_ids=obj_ids,
            objects=obj_z,
            track_ids=ids,
            track_uv=uv,
            searched=int(m.searched.sum()),
            rejected=int((m.searched & ~m.accepted).sum()),
            boxes=boxes,
        )
