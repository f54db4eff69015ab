"""Boxes seen in the left image only that no object took, kept for an object named later.

A box seen in one image gives no depth: no object starts from it. A track confirmed later, or a
long-unseen object taken back, may be the object it showed; :class:`UnnamedBoxes` keeps such
boxes with the pose estimate of their frame (the newest the window gave, kept when the frame
leaves it), so that the object can be projected into that frame and name the box in hindsight.

A box is kept as long as an object could still tell it from chance (:func:`hindsight_horizon`):
the relative pose's odometry noise grows with the frames between, and once the gate it alone
opens around the box — its rotation part, given the translation, at a distant point, the least
any object's gate can be — would hold one of the frame's kept boxes by chance with the gate's
own miss probability, no name given there would be worth more than a guess. Without an image
size the boxes of the window's frames are kept. The rule and why: the concept page *Tracking*.
"""

from __future__ import annotations

import numpy as np

from teamslam.gaussian import chi2_quantile
from teamslam.geometry import so3
from teamslam.geometry.camera import StereoCamera

__all__ = ["UnnamedBoxes", "chance_in_gate", "hindsight_horizon", "rotation_given_translation"]


def chance_in_gate(
    count: np.ndarray, gate_cov: np.ndarray, image_size: tuple[float, float], probability: float
) -> np.ndarray:
    """Expected number of ``count`` boxes spread uniformly over the image that fall by chance
    inside the ``probability`` gate of χ²(2) whose covariance is ``gate_cov`` (``(..., 2, 2)``):
    ``count · π q √det S / (W H)``, ``q`` the gate's quantile."""
    det = np.maximum(np.linalg.det(gate_cov), 0.0)
    area = np.pi * chi2_quantile(probability, 2) * np.sqrt(det)
    return np.asarray(count, float) * area / (float(image_size[0]) * float(image_size[1]))


def rotation_given_translation(odometry_cov: np.ndarray) -> np.ndarray:
    """The rotation block of the odometry noise ``W`` (6×6, translation first) given its
    translation: the Schur complement ``W_φφ − W_φρ W_ρρ⁻¹ W_ρφ``, the rotation noise no
    translation can offset."""
    w = np.asarray(odometry_cov, float)
    rho, phi, cross = w[:3, :3], w[3:, 3:], w[:3, 3:]
    factor = np.linalg.cholesky(rho)
    half = np.linalg.solve(factor, cross)
    out = phi - half.T @ half
    return 0.5 * (out + out.T)


def hindsight_horizon(
    camera: StereoCamera,
    T_cam_body: np.ndarray,
    uv: np.ndarray,
    odometry_cov: np.ndarray,
    count: int,
    image_size: tuple[float, float],
    probability: float,
) -> np.ndarray:
    """How many frames each box of one frame (left-image centres ``uv``, ``(M, 2)``, ``count``
    boxes kept in that frame) may wait for an object to name it.

    After ``g`` frames the relative pose's odometry noise is ``g W``; its rotation part given
    the translation moves a point at infinite depth along the box's ray by ``J_φ`` (the left
    image's rows; a finite depth adds the translation's part), so every object's gate there
    holds at least ``g J_φ W_φ|ρ J_φᵀ``. The horizon is the largest ``g`` for which the frame's
    boxes, spread over the image, put fewer than ``1 − probability`` of them inside that gate
    by chance (:func:`chance_in_gate`): beyond it a chance box is likelier than the gate's own
    miss. ``inf`` where the odometry has no rotation noise.
    """
    uv = np.asarray(uv, float).reshape(-1, 2)
    k = camera.intrinsics
    ray = np.stack(
        [(uv[:, 0] - k[0, 2]) / k[0, 0], (uv[:, 1] - k[1, 2]) / k[1, 1], np.ones(len(uv))],
        axis=1,
    )
    r_cam_body = np.asarray(T_cam_body, float)[:3, :3]
    # ∂(u_l, v_l)/∂φ at p_body = s R_body_cam ray as s → ∞: P(ray) R_cam_body [R_body_cam ray]^
    j_phi = camera.project_jacobian(ray)[:, :2] @ r_cam_body @ so3.hat(ray @ r_cam_body)
    one = j_phi @ rotation_given_translation(odometry_cov) @ np.swapaxes(j_phi, 1, 2)
    per_frame = chance_in_gate(np.full(len(uv), count), one, image_size, probability)
    with np.errstate(divide="ignore"):
        return np.where(per_frame > 0, (1.0 - probability) / per_frame, np.inf)


class UnnamedBoxes:
    """The kept boxes: per box its frame, its row among the frame's detections, its left-image
    centre, variances and cut sides, its label and the last frame it may be named in; per frame
    with a kept box, its pose estimate and how many boxes it kept."""

    def __init__(self) -> None:
        self.keys = np.zeros((0, 2), np.int64)  # (frame, row)
        #: per box ``(u_l, v_l, σ²_u, σ²_v, cut side u, cut side v, label)``
        self.boxes = np.zeros((0, 7))
        self.until = np.zeros(0)  # the last frame each box may be named in
        self.pose_frames = np.zeros(0, np.int64)
        self.poses = np.zeros((0, 4, 4))
        self.counts = np.zeros(0, np.int64)

    def __len__(self) -> int:
        return int(self.keys.shape[0])

    def keep(
        self,
        t: int,
        rows: np.ndarray,
        boxes: np.ndarray,
        until: np.ndarray,
        T_world_body: np.ndarray,
    ) -> None:
        """Keep frame ``t``'s boxes ``boxes`` (``(M, 7)``, rows ``rows``) until frames
        ``until``, with the frame's pose estimate."""
        m = len(rows)
        if not m:
            return
        self.keys = np.concatenate(
            [self.keys, np.stack([np.full(m, t), np.asarray(rows)], axis=1).astype(np.int64)]
        )
        self.boxes = np.concatenate([self.boxes, np.asarray(boxes, float).reshape(m, 7)])
        self.until = np.concatenate([self.until, np.asarray(until, float)])
        self.pose_frames = np.append(self.pose_frames, np.int64(t))
        self.poses = np.concatenate([self.poses, np.asarray(T_world_body, float)[None]])
        self.counts = np.append(self.counts, np.int64(m))

    def update_poses(self, t: int, state) -> None:
        """Forget the boxes past their last frame before ``t`` and the frames left without a box;
        take the window's newest estimate of the frames still in it."""
        self.drop(self.until < t)
        if self.pose_frames.size and hasattr(state, "window_index"):
            at = state.window_index(self.pose_frames)
            inside = at >= 0
            self.poses[inside] = state.poses[at[inside]]

    def drop(self, gone: np.ndarray) -> None:
        """Forget the boxes ``gone`` (boolean), and the frames left without a box."""
        if not gone.any():
            return
        keep = ~gone
        self.keys, self.boxes, self.until = self.keys[keep], self.boxes[keep], self.until[keep]
        used = np.isin(self.pose_frames, self.keys[:, 0])
        self.pose_frames, self.poses = self.pose_frames[used], self.poses[used]
        self.counts = self.counts[used]

    def frame_of(self, index: np.ndarray) -> np.ndarray:
        """Positions in :attr:`pose_frames` of boxes ``index``."""
        return np.searchsorted(self.pose_frames, self.keys[index, 0])

    def arrays(self) -> dict[str, np.ndarray]:
        """The kept boxes as arrays, for a checkpoint (:meth:`from_arrays`)."""
        return {
            "unnamed_keys": self.keys.copy(),
            "unnamed": self.boxes.copy(),
            "unnamed_until": self.until.copy(),
            "unnamed_pose_frames": self.pose_frames.copy(),
            "unnamed_poses": self.poses.copy(),
            "unnamed_counts": self.counts.copy(),
        }

    @classmethod
    def from_arrays(cls, state: dict[str, np.ndarray], window: int) -> UnnamedBoxes:
        """The kept boxes of :meth:`arrays`; a checkpoint from before the frames' poses were kept
        gives its boxes the window's frames and no pose (named while their frame is in it)."""
        out = cls()
        out.keys = np.array(state.get("unnamed_keys", np.zeros((0, 2))), np.int64).reshape(-1, 2)
        out.boxes = np.array(state.get("unnamed", np.zeros((0, 7))), float).reshape(-1, 7)
        if "unnamed_until" in state:
            out.until = np.array(state["unnamed_until"], float)
            out.pose_frames = np.array(state["unnamed_pose_frames"], np.int64)
            out.poses = np.array(state["unnamed_poses"], float).reshape(-1, 4, 4)
            out.counts = np.array(state["unnamed_counts"], np.int64)
        else:
            out.until = out.keys[:, 0] + window - 1.0
            out.pose_frames = np.unique(out.keys[:, 0])
            out.poses = np.full((out.pose_frames.size, 4, 4), np.nan)
            out.counts = np.array([np.sum(out.keys[:, 0] == f) for f in out.pose_frames], np.int64)
        return out
