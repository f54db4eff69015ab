"""Trajectory evaluation of a team: alignment, absolute and relative pose errors.

Conventions of ``evo`` and Sturm et al. (IROS 2012), so numbers compare: **APE** is the position
error ``‖t(Q_k) − t(P_k)‖`` (m) and the angle of ``R(Q_k)ᵀ R(P_k)`` (degrees); **RPE** over a
step ``Δ`` (frames or metres travelled) is that of ``(Q_k⁻¹ Q_{k+Δ})⁻¹ (P_k⁻¹ P_{k+Δ})``; with
their RMSE, mean, median, population std, max and min. Alignment before the errors: ``none``
(the paper's choice), ``se3`` / ``sim3`` (Umeyama 1991, closed form) or ``first-pose``; per robot
or one transform for the whole team (the honest choice for a shared map).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from teamslam.errors import InputError
from teamslam.geometry import se3
from teamslam.geometry.alignment import align

__all__ = [
    "ALIGNMENTS",
    "RPE_UNITS",
    "RobotEvaluation",
    "Similarity",
    "TeamEvaluation",
    "Trajectory",
    "absolute_errors",
    "alignment",
    "associate",
    "error_statistics",
    "evaluate_team",
    "first_pose_alignment",
    "relative_errors",
    "rpe_pairs",
    "umeyama",
]

ALIGNMENTS = ("none", "se3", "sim3", "first-pose")
RPE_UNITS = ("frames", "m")


@dataclass(frozen=True)
class Similarity:
    """``x ↦ s R x + t``, acting on poses as ``T ↦ [[s R R_T, s R t_T + t], [0, 1]]``.

    Attributes
    ----------
    rotation
        ``(3, 3)`` rotation ``R``.
    translation
        ``(3,)`` translation ``t``.
    scale
        ``s > 0`` (1 for a rigid transform).
    """

    rotation: np.ndarray
    translation: np.ndarray
    scale: float = 1.0

    @staticmethod
    def identity() -> Similarity:
        """The identity transform."""
        return Similarity(np.eye(3), np.zeros(3), 1.0)

    def matrix(self) -> np.ndarray:
        """``(4, 4)`` matrix ``[[s R, t], [0, 1]]``."""
        out = np.eye(4)
        out[:3, :3] = self.scale * self.rotation
        out[:3, 3] = self.translation
        return out

    def apply_points(self, points: np.ndarray) -> np.ndarray:
        """Transform ``(..., 3)`` points."""
        return self.scale * points @ self.rotation.T + self.translation

    def apply_poses(self, poses: np.ndarray) -> np.ndarray:
        """Transform ``(N, 4, 4)`` poses (rotations stay rotations: the scale acts on positions)."""
        out = poses.copy()
        out[:, :3, :3] = self.rotation @ poses[:, :3, :3]
        out[:, :3, 3] = self.apply_points(poses[:, :3, 3])
        return out

    def to_json(self) -> dict:
        """Rotation (row-major), translation and scale."""
        return {
            "rotation": self.rotation.tolist(),
            "translation": self.translation.tolist(),
            "scale": float(self.scale),
        }


@dataclass(frozen=True)
class Trajectory:
    """Poses ``T_world_body`` ``(N, 4, 4)`` and their timestamps ``(N,)`` (``None``: unknown)."""

    poses: np.ndarray
    timestamps: np.ndarray | None = None
    name: str = ""

    def __post_init__(self) -> None:
        poses = np.asarray(self.poses, dtype=float)
        label = self.name or "trajectory"
        if poses.ndim != 3 or poses.shape[1:] != (4, 4):
            raise InputError(f"{label}: poses must be (N, 4, 4), got {poses.shape}")
        if not np.all(np.isfinite(poses)):
            raise InputError(f"{label}: poses contain NaN or infinite values")
        object.__setattr__(self, "poses", poses)
        if self.timestamps is not None:
            ts = np.asarray(self.timestamps, dtype=float)
            if ts.shape != (len(poses),):
                raise InputError(f"{label}: {len(poses)} poses but {ts.shape} timestamps")
            if not np.all(np.isfinite(ts)):
                raise InputError(f"{label}: timestamps contain NaN or infinite values")
            object.__setattr__(self, "timestamps", ts)

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def positions(self) -> np.ndarray:
        """``(N, 3)`` positions."""
        return self.poses[:, :3, 3]


def umeyama(source: np.ndarray, target: np.ndarray, with_scale: bool) -> Similarity:
    """The similarity (or rigid transform) taking ``source`` points onto ``target`` points.

    Minimises ``Σ_i ‖y_i − (s R x_i + t)‖²`` in closed form, all points weighted alike
    (:func:`teamslam.geometry.alignment.align`), and refuses collinear points.

    Parameters
    ----------
    source, target
        ``(n, 3)`` corresponding points ``x_i`` (estimate) and ``y_i`` (reference).
    with_scale
        Estimate the scale ``s`` (Sim(3)); otherwise ``s = 1`` (SE(3)).

    Raises
    ------
    InputError
        Shapes differ, fewer than three points, or the points are (nearly) collinear so the
        rotation about their line is not determined.
    """
    source = np.asarray(source, dtype=float)
    target = np.asarray(target, dtype=float)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 3:
        raise InputError(
            f"alignment needs two (n, 3) point sets, got {source.shape} and {target.shape}"
        )
    n = source.shape[0]
    if n < 3:
        raise InputError(f"alignment needs at least 3 corresponding positions, got {n}")
    found = align(source, target, with_scale=with_scale)
    d = found.singular_values
    if not d[1] > 1e-12 * max(d[0], np.finfo(float).tiny):
        raise InputError(
            "alignment is not determined: the positions are collinear (a straight-line "
            "trajectory leaves the rotation about it free); use --align none or first-pose"
        )
    return Similarity(found.rotation, found.translation, float(found.scale))


def first_pose_alignment(estimate: np.ndarray, reference: np.ndarray) -> Similarity:
    """``Q_0 P_0⁻¹`` as a rigid transform: the estimate's first pose onto the reference's."""
    r_est, r_ref = estimate[:3, :3], reference[:3, :3]
    rotation = r_ref @ r_est.T
    return Similarity(rotation, reference[:3, 3] - rotation @ estimate[:3, 3], 1.0)


def alignment(estimates: list[np.ndarray], references: list[np.ndarray], method: str) -> Similarity:
    """One transform for the (associated) pose sets ``estimates[i] ↔ references[i]`` together.

    ``method`` is one of :data:`ALIGNMENTS`; ``first-pose`` uses the first pair's first pose.
    """
    if method not in ALIGNMENTS:
        raise InputError(f"unknown alignment {method!r}; choose one of {', '.join(ALIGNMENTS)}")
    if method == "none":
        return Similarity.identity()
    nonempty = [(e, r) for e, r in zip(estimates, references, strict=True) if len(e)]
    if not nonempty:
        raise InputError("alignment needs at least one pose")
    if method == "first-pose":
        return first_pose_alignment(nonempty[0][0][0], nonempty[0][1][0])
    source = np.concatenate([e[:, :3, 3] for e, _ in nonempty])
    target = np.concatenate([r[:, :3, 3] for _, r in nonempty])
    return umeyama(source, target, with_scale=method == "sim3")


def associate(
    estimate: Trajectory, reference: Trajectory, max_time_diff: float = 0.01
) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(i_est, i_ref)`` of the estimate's and the reference's poses at the same time.

    Each estimated pose is paired with the reference pose nearest in time if they differ by at
    most ``max_time_diff`` seconds; each reference pose is used once (the nearest estimate
    wins). Without timestamps on either side, the two must have the same number of poses and
    are paired frame by frame.
    """
    label = f"{estimate.name or 'estimate'} vs {reference.name or 'reference'}"
    if estimate.timestamps is None or reference.timestamps is None:
        if len(estimate) != len(reference):
            raise InputError(
                f"{label}: {len(estimate)} and {len(reference)} poses and no timestamps to "
                "match them (KITTI files pair frame by frame)"
            )
        idx = np.arange(len(estimate))
        return idx, idx.copy()
    t_est, t_ref = estimate.timestamps, reference.timestamps
    if len(t_ref) == 0 or len(t_est) == 0:
        raise InputError(f"{label}: an empty trajectory")
    order = np.argsort(t_ref, kind="stable")
    sorted_ref = t_ref[order]
    pos = np.searchsorted(sorted_ref, t_est)
    lo = np.clip(pos - 1, 0, len(sorted_ref) - 1)
    hi = np.clip(pos, 0, len(sorted_ref) - 1)
    pick = np.where(np.abs(sorted_ref[hi] - t_est) < np.abs(sorted_ref[lo] - t_est), hi, lo)
    diff = np.abs(sorted_ref[pick] - t_est)
    i_est = np.flatnonzero(diff <= max_time_diff)
    i_ref = order[pick[i_est]]
    # one estimate per reference pose: keep the closest in time
    keep_order = np.lexsort((diff[i_est], i_ref))
    i_est, i_ref = i_est[keep_order], i_ref[keep_order]
    first = np.ones(len(i_ref), dtype=bool)
    first[1:] = i_ref[1:] != i_ref[:-1]
    i_est, i_ref = i_est[first], i_ref[first]
    by_time = np.argsort(i_est, kind="stable")
    i_est, i_ref = i_est[by_time], i_ref[by_time]
    if len(i_est) == 0:
        raise InputError(
            f"{label}: no poses within {max_time_diff} s of each other (timestamps "
            f"{t_est.min():.6g}..{t_est.max():.6g} vs {t_ref.min():.6g}..{t_ref.max():.6g})"
        )
    return i_est, i_ref


def _rotation_angle_deg(rotations: np.ndarray) -> np.ndarray:
    if len(rotations) == 0:
        return np.zeros(0)
    return np.degrees(Rotation.from_matrix(rotations).magnitude())


def absolute_errors(estimate: np.ndarray, reference: np.ndarray) -> dict[str, np.ndarray]:
    """Per-pose APE of associated ``(N, 4, 4)`` poses.

    Returns
    -------
    dict
        ``translation_sq`` (squared position error, m², summed over axes exactly as the RMSE
        of :func:`teamslam.eval.metrics.trajectory_rmse`), ``translation_m`` and
        ``rotation_deg``.
    """
    err = estimate[:, :3, 3] - reference[:, :3, 3]
    sq = np.sum(err**2, axis=1)
    rel = np.swapaxes(reference[:, :3, :3], -1, -2) @ estimate[:, :3, :3]
    return {
        "translation_sq": sq,
        "translation_m": np.sqrt(sq),
        "rotation_deg": _rotation_angle_deg(rel),
    }


def rpe_pairs(
    reference: np.ndarray, delta: float, unit: str = "frames", all_pairs: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(i, j)`` of the RPE.

    ``unit == "frames"``: ``j = i + Δ``, every ``i`` (``all_pairs``) or ``i = 0, Δ, 2Δ, …``.
    ``unit == "m"``: ``j`` is the first pose at least ``Δ`` metres further along the
    reference's path than ``i``, for every ``i`` (or, without ``all_pairs``, each ``i`` being
    the previous pair's ``j``).
    """
    n = len(reference)
    if unit not in RPE_UNITS:
        raise InputError(f"unknown RPE unit {unit!r}; choose one of {', '.join(RPE_UNITS)}")
    if not (np.isfinite(delta) and delta > 0):
        raise InputError(f"RPE step must be positive, got {delta}")
    if unit == "frames":
        if delta != int(delta):
            raise InputError(f"RPE step in frames must be an integer, got {delta}")
        step = int(delta)
        start = np.arange(0, n - step, 1 if all_pairs else step)
        return start, start + step
    steps = np.linalg.norm(np.diff(reference[:, :3, 3], axis=0), axis=1)
    travelled = np.concatenate([[0.0], np.cumsum(steps)])
    target = np.searchsorted(travelled, travelled + delta, side="left")
    if all_pairs:
        i = np.flatnonzero(target < n)
        return i, target[i]
    pairs_i, pairs_j = [], []
    i = 0
    while i < n and target[i] < n:
        pairs_i.append(i)
        pairs_j.append(int(target[i]))
        i = int(target[i])
    return np.asarray(pairs_i, dtype=int), np.asarray(pairs_j, dtype=int)


def relative_errors(
    estimate: np.ndarray,
    reference: np.ndarray,
    delta: float = 1,
    unit: str = "frames",
    all_pairs: bool = True,
) -> dict[str, np.ndarray]:
    """Per-pair RPE of associated ``(N, 4, 4)`` poses: ``translation_m``, ``rotation_deg``,
    and the pairs ``i``, ``j``."""
    i, j = rpe_pairs(reference, delta, unit, all_pairs)
    q_rel = se3.inverse(reference[i]) @ reference[j]
    p_rel = se3.inverse(estimate[i]) @ estimate[j]
    e = se3.inverse(q_rel) @ p_rel
    return {
        "translation_m": np.linalg.norm(e[:, :3, 3], axis=1),
        "rotation_deg": _rotation_angle_deg(e[:, :3, :3]),
        "i": i,
        "j": j,
    }


def error_statistics(values: np.ndarray, squared: np.ndarray | None = None) -> dict[str, float]:
    """RMSE, mean, median, population std, max, min and count of errors ``values``.

    ``squared`` (the squared errors, if computed without a square root in between) gives the
    RMSE bit-for-bit equal to ``sqrt(mean(squared))``.
    """
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        nan = float("nan")
        return dict.fromkeys(("rmse", "mean", "median", "std", "max", "min"), nan) | {"count": 0}
    sq = values**2 if squared is None else squared
    return {
        "rmse": float(np.sqrt(np.mean(sq))),
        "mean": float(np.mean(values)),
        "median": float(np.median(values)),
        "std": float(np.std(values)),
        "max": float(np.max(values)),
        "min": float(np.min(values)),
        "count": int(values.size),
    }


@dataclass
class RobotEvaluation:
    """One robot's errors after association and alignment.

    ``timestamps`` are the estimate's, or its frame indices when it has none (``timed`` false).
    """

    name: str
    timestamps: np.ndarray
    estimate: np.ndarray
    reference: np.ndarray
    alignment: Similarity
    ape: dict[str, np.ndarray]
    rpe: dict[str, np.ndarray]
    timed: bool = True

    def statistics(self) -> dict:
        """APE and RPE statistics (translation in m, rotation in degrees)."""
        return {
            "frames": len(self.estimate),
            "ape_translation_m": error_statistics(
                self.ape["translation_m"], self.ape["translation_sq"]
            ),
            "ape_rotation_deg": error_statistics(self.ape["rotation_deg"]),
            "rpe_translation_m": error_statistics(self.rpe["translation_m"]),
            "rpe_rotation_deg": error_statistics(self.rpe["rotation_deg"]),
            "alignment": self.alignment.to_json(),
        }


@dataclass
class TeamEvaluation:
    """APE/RPE of every robot of a team and of the team as a whole.

    The team's statistics pool every robot's frames (or pairs); ``ape_translation_rmse_avg_m``
    is the mean of the robots' RMSEs (``trajectory_rmse_avg_m`` of ``metrics.json`` when no
    alignment is applied).
    """

    robots: list[RobotEvaluation]
    align: str
    scope: str
    rpe_delta: float
    rpe_unit: str
    team_alignment: Similarity | None = None

    def statistics(self) -> dict:
        """Everything as plain numbers (the ``--json`` output of ``teamslam eval``)."""
        robots = [r.statistics() for r in self.robots]

        def pooled(kind: str, part: str) -> dict:
            vals = np.concatenate([getattr(r, kind)[part] for r in self.robots])
            sq = None
            if kind == "ape" and part == "translation_m":
                sq = np.concatenate([r.ape["translation_sq"] for r in self.robots])
            return error_statistics(vals, sq)

        team = {
            "ape_translation_m": pooled("ape", "translation_m"),
            "ape_rotation_deg": pooled("ape", "rotation_deg"),
            "rpe_translation_m": pooled("rpe", "translation_m"),
            "rpe_rotation_deg": pooled("rpe", "rotation_deg"),
            "ape_translation_rmse_avg_m": float(
                np.mean([r["ape_translation_m"]["rmse"] for r in robots])
            ),
            "ape_translation_rmse_max_m": float(
                np.max([r["ape_translation_m"]["rmse"] for r in robots])
            ),
        }
        if self.team_alignment is not None:
            team["alignment"] = self.team_alignment.to_json()
        return {
            "align": self.align,
            "scope": self.scope,
            "rpe_delta": self.rpe_delta,
            "rpe_unit": self.rpe_unit,
            "team": team,
            "robots": robots,
        }


def evaluate_team(
    estimates: list[Trajectory],
    references: list[Trajectory],
    align: str = "none",
    scope: str = "team",
    rpe_delta: float = 1,
    rpe_unit: str = "frames",
    max_time_diff: float = 0.01,
    all_pairs: bool = True,
) -> TeamEvaluation:
    """APE and RPE of each robot's estimate against its reference, after alignment.

    Parameters
    ----------
    estimates, references
        One trajectory per robot, in the same order.
    align
        One of :data:`ALIGNMENTS`.
    scope
        ``"team"``: one transform for every robot together; ``"robot"``: one per robot.
    rpe_delta, rpe_unit
        RPE step, in frames or in metres travelled (:func:`rpe_pairs`).
    max_time_diff
        Largest time difference of associated poses, seconds (:func:`associate`).
    all_pairs
        RPE over every start pose (else non-overlapping steps).
    """
    if len(estimates) != len(references):
        raise InputError(
            f"{len(estimates)} estimated trajectories but {len(references)} references "
            "(one reference per robot)"
        )
    if not estimates:
        raise InputError("no trajectories to evaluate")
    if scope not in ("team", "robot"):
        raise InputError(f"unknown alignment scope {scope!r}; choose team or robot")
    if align not in ALIGNMENTS:
        raise InputError(f"unknown alignment {align!r}; choose one of {', '.join(ALIGNMENTS)}")
    pairs = []
    for est, ref in zip(estimates, references, strict=True):
        i_est, i_ref = associate(est, ref, max_time_diff)
        ts = est.timestamps[i_est] if est.timestamps is not None else i_est.astype(float)
        pairs.append((ts, est.poses[i_est], ref.poses[i_ref]))
    team_transform = None
    if scope == "team":
        team_transform = alignment([p[1] for p in pairs], [p[2] for p in pairs], align)
    robots = []
    for k, (ts, est, ref) in enumerate(pairs):
        transform = team_transform if team_transform is not None else alignment([est], [ref], align)
        aligned = est if align == "none" else transform.apply_poses(est)
        robots.append(
            RobotEvaluation(
                name=estimates[k].name or f"robot {k}",
                timestamps=ts,
                estimate=aligned,
                reference=ref,
                alignment=transform,
                ape=absolute_errors(aligned, ref),
                rpe=relative_errors(aligned, ref, rpe_delta, rpe_unit, all_pairs),
                timed=estimates[k].timestamps is not None,
            )
        )
    return TeamEvaluation(robots, align, scope, rpe_delta, rpe_unit, team_transform)
