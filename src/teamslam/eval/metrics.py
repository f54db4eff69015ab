"""Accuracy, agreement and consistency of a team run (distributed MSCKF paper, §VI).

Per robot: trajectory RMSE **without alignment** (as the paper: aligning would hide the map
errors consensus is meant to fix) and odometry-only RMSE; object error (Table II) and object
disagreement with the other robots (Table III); pose NEES per frame, in the filter's convention
``T_true = T_est · exp(ε^)``, divided by 6; stage times; sensor health; and, with the robots'
own association or the consensus innovation check, per-link association figures
(:func:`association_metrics`; ``None`` where there was nothing to measure).
:func:`pose_nees_warning` says when the team's pose NEES leaves its χ² band.
"""

from __future__ import annotations

import numpy as np

from teamslam.datasets.model import TeamDataset
from teamslam.geometry import se3
from teamslam.msckf.team import TeamResult

__all__ = [
    "association_metrics",
    "dead_reckoning",
    "object_disagreement",
    "object_errors",
    "object_nees",
    "pose_nees",
    "pose_nees_warning",
    "team_metrics",
    "trajectory_rmse",
]


def trajectory_rmse(estimated: np.ndarray, truth: np.ndarray) -> float:
    """RMSE of positions ``(N, 4, 4)`` vs ``(N, 4, 4)``, no alignment."""
    err = estimated[:, :3, 3] - truth[:, :3, 3]
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


def dead_reckoning(start: np.ndarray, odometry: np.ndarray) -> np.ndarray:
    """Poses from composing odometry onto ``start``."""
    poses = np.empty((odometry.shape[0] + 1, 4, 4))
    poses[0] = start
    for k, step in enumerate(odometry):
        poses[k + 1] = poses[k] @ step
    return poses


def pose_nees(estimated: np.ndarray, covs: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-frame pose NEES / 6 with ``ε = log(T_est⁻¹ T_true)``."""
    eps = se3.log(se3.inverse(estimated) @ truth)
    solved = np.linalg.solve(covs, eps[..., None])[..., 0]
    return np.einsum("ki,ki->k", eps, solved) / 6.0


def object_errors(dataset: TeamDataset, ids: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """Distance of each estimated object to its true position."""
    return np.linalg.norm(positions - dataset.object_position(ids), axis=1)


def object_nees(dataset: TeamDataset, result: TeamResult) -> np.ndarray:
    """NEES / 3 of every object of every robot's final map whose true position is known.

    The objects of all robots are concatenated (robot 0's first); an object without ground truth
    is left out.
    """
    out = [np.empty(0)]
    for ids, positions, covs in zip(
        result.object_ids, result.objects, result.object_covs, strict=True
    ):
        err = positions - dataset.object_position(ids)
        ok = np.all(np.isfinite(err), axis=1)
        solved = np.linalg.solve(covs[ok], err[ok][..., None])[..., 0]
        out.append(np.einsum("ki,ki->k", err[ok], solved) / 3.0)
    return np.concatenate(out)


def object_disagreement(ids: list[np.ndarray], positions: list[np.ndarray]) -> np.ndarray:
    """Per robot, mean distance to the other robots' estimates of the same objects (NaN if none)."""
    lookup = [dict(zip(i.tolist(), range(i.size), strict=True)) for i in ids]
    out = np.full(len(ids), np.nan)
    for r, (rid, rpos) in enumerate(zip(ids, positions, strict=True)):
        dists = []
        for other in range(len(ids)):
            if other == r:
                continue
            common = [k for k in rid.tolist() if k in lookup[other]]
            if common:
                a = rpos[[lookup[r][k] for k in common]]
                b = positions[other][[lookup[other][k] for k in common]]
                dists.append(np.linalg.norm(a - b, axis=1))
        if dists:
            out[r] = float(np.mean(np.concatenate(dists)))
    return out


def pose_nees_warning(metrics: dict, probability: float = 0.95) -> str | None:
    """One line when a run's pose NEES / 6, averaged over its robots, leaves its two-sided χ²
    band (:func:`teamslam.gaussian.chi2_band`), else ``None``.

    One robot's per-frame NEES values are strongly correlated in time, so a band that takes
    its ``K`` poses as independent samples (``χ²(6K) / 6K``) is far too narrow and warns on
    consistent filters. The time average of identically distributed samples varies no more
    than one sample, so each robot's average counts as one ``χ²(6) / 6`` sample and the band
    is that of ``χ²(6R) / 6R`` over ``R`` robots: conservative (a warning means the filter is
    inconsistent, not that the band was narrow). Only meaningful when the dataset's poses are
    ground truth.
    """
    from teamslam.gaussian import chi2_band

    nees = np.asarray(metrics["nees_pose_avg"], dtype=float)
    frames = np.asarray(metrics["frames_per_robot"], dtype=float)
    keep = np.isfinite(nees) & (frames > 1)  # frame 0 is given
    if not keep.any():
        return None
    robots = int(keep.sum())
    value = float(np.mean(nees[keep]))
    low, high = chi2_band(6, robots, probability)
    if low <= value <= high:
        return None
    verdict = (
        "overconfident: its pose covariance is smaller than its errors"
        if value > high
        else "underconfident: its pose covariance is larger than its errors"
    )
    return (
        f"pose NEES/6 {value:.3g} outside its {100 * probability:.0f}% χ² band "
        f"[{low:.3g}, {high:.3g}] of {robots} robots' averages: the filter is {verdict}"
    )


def team_metrics(dataset: TeamDataset, result: TeamResult) -> dict:
    """The ``metrics.json`` of a run."""
    n = dataset.n_robots
    traj = [trajectory_rmse(result.poses[i], r.T_world_body) for i, r in enumerate(dataset.robots)]
    odo = [
        trajectory_rmse(dead_reckoning(r.T_world_body[0], r.odometry), r.T_world_body)
        for r in dataset.robots
    ]
    obj = []
    for i in range(n):
        e = object_errors(dataset, result.object_ids[i], result.objects[i])
        e = e[np.isfinite(e)]
        obj.append(float(e.mean()) if e.size else float("nan"))
    dis = object_disagreement(result.object_ids, result.objects)
    nees = [
        pose_nees(result.poses[i], result.pose_covs[i], r.T_world_body)
        for i, r in enumerate(dataset.robots)
    ]
    frames = [r.frames for r in dataset.robots]
    stages = ("consensus", "propagation", "update", "initialisation")
    timing = {
        s: float(
            np.mean([1e3 * t.get(s, 0.0) / f for t, f in zip(result.timings, frames, strict=True)])
        )
        for s in stages
    }
    timing["total"] = float(sum(timing.values()))

    def _finite_mean(values):
        v = np.asarray(values, dtype=float)
        v = v[np.isfinite(v)]
        return float(v.mean()) if v.size else float("nan")

    return {
        "robots": n,
        "consensus": result.consensus,
        "graph": result.graph,
        "loss": result.loss,
        "frames_per_robot": frames,
        "trajectory_rmse_m": traj,
        "trajectory_rmse_avg_m": float(np.mean(traj)),
        "trajectory_rmse_max_m": float(np.max(traj)),
        "odometry_rmse_m": odo,
        "odometry_rmse_avg_m": float(np.mean(odo)),
        "object_error_m": obj,
        "object_error_avg_m": _finite_mean(obj),
        "object_disagreement_m": dis.tolist(),
        "object_disagreement_avg_m": _finite_mean(dis),
        "objects_in_map": [int(i.size) for i in result.object_ids],
        "nees_pose_avg": [float(np.mean(v[1:])) for v in nees],
        "nees_pose_median": [float(np.median(v[1:])) for v in nees],
        "time_per_robot_step_ms": timing,
        "counters": result.counters,
        # consensus messages sent, per robot per step that could exchange (frames after the first)
        "bytes_per_robot_step": float(
            np.mean(
                [
                    c.get("bytes", 0) / max(f - 1, 1)
                    for c, f in zip(result.counters, frames, strict=True)
                ]
            )
        ),
        "wall_seconds": result.wall_seconds,
        # numba kernels compiled (the first run after an install or a change) and loaded from
        # the cache (the first run of a process) while the clock ran: their one-off cost is in
        # time_per_robot_step_ms
        "compilations": int(result.extra.get("compilations", 0)),
        "kernels_loaded": int(result.extra.get("kernels_loaded", 0)),
        **_health(result.health),
        **_association(dataset, result),
        **_tracking(dataset, result),
    }


def _tracking(dataset: TeamDataset, result: TeamResult) -> dict:
    """``{"tracking": …}`` (:func:`teamslam.eval.tracking.tracking_metrics`) when robots tracked
    their own detections and the dataset holds the truth of each (else nothing)."""
    from teamslam.eval.tracking import tracking_metrics

    hypotheses = _hypotheses(result)
    if not any(len(h) for h in hypotheses) or len(hypotheses) != dataset.n_robots:
        return {}
    records = result.extra.get("tracking_records")
    if records is None:  # robot processes: in each robot's summary
        records = result.extra.get("per_robot", [])
    tracking = tracking_metrics(
        dataset,
        [np.asarray(h, dtype=np.int64) for h in hypotheses],
        records if len(records) == len(hypotheses) else None,
    )
    return {} if tracking is None else {"tracking": tracking}


def _hypotheses(result: TeamResult) -> list:
    """Per robot the ids its tracker gave its detections (empty lists without a tracker)."""
    hypotheses = result.extra.get("tracking_hypotheses")
    if hypotheses is None:  # robot processes: in each robot's summary
        hypotheses = [s.get("tracking_hypotheses", []) for s in result.extra.get("per_robot", [])]
    return hypotheses


def _association(dataset: TeamDataset, result: TeamResult) -> dict:
    """``{"association": …}`` when the run recorded association (else nothing)."""
    per_robot = result.extra.get("association")
    if per_robot is None:  # robot processes: in each robot's summary
        summaries = result.extra.get("per_robot", [])
        per_robot = [s.get("association", {}) for s in summaries]
    if not any(per_robot):
        return {}
    return {
        "association": association_metrics(
            dataset, result, per_robot, tracked=_tracked_truth(dataset, result)
        )
    }


def _tracked_truth(dataset: TeamDataset, result: TeamResult) -> list | None:
    """Per robot which true object each object its tracker named is
    (:func:`teamslam.eval.tracking.object_truth`), when the robots named their own detections
    and the dataset holds each detection's truth but no identity of object ids; else ``None``."""
    from teamslam.eval.tracking import object_truth

    if dataset.object_id_scope == "global" or dataset.object_identity.size:
        return None
    hypotheses = _hypotheses(result)
    robots = list(result.robots or range(len(hypotheses)))
    if len(hypotheses) != len(robots) or not any(len(h) for h in hypotheses):
        return None
    out = []
    for r, hyp in zip(robots, hypotheses, strict=True):
        detections = dataset.robots[r].detections
        if detections is None or detections.truth is None or len(hyp) != detections.truth.size:
            return None
        out.append(object_truth(detections.truth, hyp))
    return out


def association_metrics(
    dataset: TeamDataset, result: TeamResult, per_robot: list[dict], tracked: list | None = None
) -> dict:
    """Per link and for the team: what the association exchanged, found and got right.

    Parameters
    ----------
    dataset
        The team data (ground truth of object identity: global ids, or ``object_identity``).
    result
        The run (final maps, timings, frames).
    per_robot
        Per robot (in ``result.robots`` order)
        :meth:`~teamslam.msckf.consensus.protocol.ConsensusProtocol.
        association_summary`: per neighbour the table's counts and pairs and the exchange
        statistics.
    tracked
        Per robot (in ``result.robots`` order) ``(ids, team ids)``: the truth of the objects
        robots named themselves (:func:`~teamslam.eval.tracking.object_truth`), used where
        the dataset holds none.

    Returns
    -------
    dict
        ``links``: ``"i-j"`` (``i < j``, seen from ``i``) → summary bytes per step (each way),
        ``proposed``, ``accepted``, ``revoked``, ``held``, ``excluded`` (objects left out of an
        average by the innovation test), ``ends_agree`` (both ends hold the same pairs) and,
        with ground truth, ``correct``, ``wrong``, ``shared``, ``precision``, ``recall``;
        ``team``: the sums, precision and recall over the links, and the association's share
        of the per-robot-step time.
    """
    from teamslam.association import score_correspondences

    robots = list(result.robots or range(len(per_robot)))
    index = {r: k for k, r in enumerate(robots)}
    scope = dataset.object_id_scope
    has_truth = scope == "global" or dataset.object_identity.size > 0 or tracked is not None
    links: dict[str, dict] = {}
    totals = {k: 0 for k in ("proposed", "accepted", "revoked", "held", "excluded")}
    correct = wrong = shared = 0
    for k, i in enumerate(robots):
        frames = max(len(result.poses[k]) - 1, 1)
        for key, entry in sorted(per_robot[k].items(), key=lambda kv: int(kv[0])):
            j = int(key)
            if j < i or j not in index:
                continue
            other = per_robot[index[j]].get(str(i), {})
            link = {
                "summary_bytes_per_step": [
                    entry.get("summary_bytes", 0) / frames,
                    other.get("summary_bytes", 0) / frames,
                ],
                "excluded": int(entry.get("excluded", 0)) + int(other.get("excluded", 0)),
            }
            for name in ("proposed", "accepted", "revoked", "held"):
                if name in entry:
                    link[name] = int(entry[name])
            pairs = np.asarray(entry.get("pairs", []), dtype=np.int64).reshape(-1, 2)
            if "pairs" in entry:
                theirs = np.asarray(other.get("pairs", []), dtype=np.int64).reshape(-1, 2)
                mirrored = theirs[:, ::-1]
                link["ends_agree"] = bool(
                    np.array_equal(
                        pairs[np.lexsort(pairs.T[::-1])] if pairs.size else pairs,
                        mirrored[np.lexsort(mirrored.T[::-1])] if mirrored.size else mirrored,
                    )
                )
            if has_truth and "pairs" in entry:
                own_ids, their_ids = result.object_ids[k], result.object_ids[index[j]]
                inside = np.isin(pairs[:, 0], own_ids) & np.isin(pairs[:, 1], their_ids)
                if tracked is not None:
                    truth = (tracked[k], tracked[index[j]])
                elif scope == "global":
                    truth = (None, None)
                else:
                    truth = (dataset.true_objects(i), dataset.true_objects(j))
                score = score_correspondences(pairs[inside], own_ids, their_ids, *truth)
                link.update(score.to_json())
                # nothing to measure is no measurement: no pair, nothing shared
                link.update(
                    precision=score.precision if score.correct + score.wrong else None,
                    recall=score.recall if score.shared else None,
                )
                correct += score.correct
                wrong += score.wrong
                shared += score.shared
            for name in totals:
                totals[name] += int(link.get(name, 0))
            links[f"{i}-{j}"] = link
    seconds = [
        sum(float(e.get("association_seconds", 0.0)) for e in per_robot[k].values())
        for k in range(len(robots))
    ]
    spent = [sum(float(v) for v in t.values()) for t in result.timings]
    team: dict = dict(totals)
    if has_truth:
        team.update(
            correct=correct,
            wrong=wrong,
            shared=shared,
            precision=correct / (correct + wrong) if correct + wrong else None,
            recall=correct / shared if shared else None,
        )
    team["association_seconds"] = float(sum(seconds))
    team["association_time_share"] = float(sum(seconds) / sum(spent)) if sum(spent) > 0 else 0.0
    team["summary_bytes_per_robot_step"] = float(
        np.mean(
            [
                sum(e.get("summary_bytes", 0) for e in per_robot[k].values())
                / max(len(result.poses[k]) - 1, 1)
                for k in range(len(robots))
            ]
        )
    )
    return {"links": links, "team": team}


def _health(health: dict) -> dict:
    """``nis``, ``gate_rejection_rate``, ``odometry_residual_ratio`` of the team, and per robot."""
    if not health:
        return {}
    team = health["team"]
    return {
        "nis": team["nis"],
        "gate_rejection_rate": team["gate_rejection_rate"],
        "odometry_residual_ratio": team["odometry_residual_ratio"],
        "health_per_robot": health["robots"],
    }
