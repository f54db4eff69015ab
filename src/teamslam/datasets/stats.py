"""Summary statistics of a team dataset (``teamslam data info``), and its noise measured against
its ground truth where it has one."""

from __future__ import annotations

import numpy as np

from teamslam.datasets.model import FrameObservations, TeamDataset
from teamslam.gaussian import robust_std
from teamslam.geometry import se3
from teamslam.textio import format_value

__all__ = ["dataset_info", "format_info", "ground_truth_noise", "robust_std", "seen_once"]


def _measurement_errors(dataset: TeamDataset, kind: str) -> np.ndarray:
    """``(M, 4)`` measured minus predicted stereo coordinates of ``kind`` at the true poses."""
    cal = dataset.calibration
    if kind == "objects":
        known_ids, known_positions = dataset.object_ids, dataset.object_positions
    else:  # a geometric track observes the landmark named in track_landmarks
        ids = dataset.landmark_ids.tolist()
        lookup = dict(zip(ids, range(len(ids)), strict=True))
        rows = [lookup.get(int(lm), -1) for lm in dataset.track_landmarks[:, 1]]
        known = np.array(rows, dtype=np.int64) >= 0
        known_ids = dataset.track_landmarks[known, 0]
        known_positions = dataset.landmark_positions[np.array(rows, dtype=np.int64)[known]]
    order = np.argsort(known_ids)
    sorted_ids = known_ids[order]
    errors = []
    for robot in dataset.robots:
        obs = getattr(robot, kind)
        if obs.ids.size == 0 or sorted_ids.size == 0:
            continue
        pos = np.clip(np.searchsorted(sorted_ids, obs.ids), 0, sorted_ids.size - 1)
        hit = sorted_ids[pos] == obs.ids
        frame = np.repeat(np.arange(obs.frames), obs.counts())[hit]
        points = known_positions[order[pos[hit]]]
        T_cam_world = cal.T_cam_body @ se3.inverse(robot.T_world_body[frame])
        p_cam = np.einsum("kij,kj->ki", T_cam_world[:, :3, :3], points) + T_cam_world[:, :3, 3]
        front = p_cam[:, 2] > 0
        errors.append(obs.measurements[hit][front] - cal.camera.project(p_cam[front]))
    return np.concatenate(errors) if errors else np.zeros((0, 4))


def ground_truth_noise(dataset: TeamDataset) -> dict:
    """The dataset's noise measured against its ground truth (robust std, 1.4826 × MAD).

    * ``odometry_std``: per axis of ``n = log(δT_true⁻¹ · odometry)`` (m, m, m, rad, rad, rad);
    * ``feature_std`` / ``object_std``: over all four stereo coordinates of measured minus
      projected true point, in the camera's units, with ``*_std_per_coordinate`` alongside
      (``None`` where there is no truth to project: no ground-truth points or no observations).
    """
    steps = []
    for robot in dataset.robots:
        if robot.odometry.shape[0]:
            true_steps = se3.inverse(robot.T_world_body[:-1]) @ robot.T_world_body[1:]
            steps.append(se3.log(se3.inverse(true_steps) @ robot.odometry))
    out: dict = {
        "odometry_std": robust_std(np.concatenate(steps)).tolist() if steps else None,
    }
    for kind, key in (("features", "feature_std"), ("objects", "object_std")):
        errors = _measurement_errors(dataset, kind)
        if errors.shape[0] < 2:
            out[key] = out[f"{key}_per_coordinate"] = None
            continue
        out[key] = float(robust_std(errors.ravel()))
        out[f"{key}_per_coordinate"] = robust_std(errors).tolist()
    return out


def _per_frame(obs: list[FrameObservations]) -> dict:
    counts = np.concatenate([o.counts() for o in obs]) if obs else np.zeros(0)
    return {
        "mean": float(counts.mean()) if counts.size else 0.0,
        "max": int(counts.max()) if counts.size else 0,
        "total": int(counts.sum()),
    }


def _tracks(obs: FrameObservations) -> np.ndarray:
    """Length (frames) of every track id in one robot's observations."""
    if obs.ids.size == 0:
        return np.zeros(0, dtype=int)
    _, lengths = np.unique(obs.ids, return_counts=True)
    return lengths


def seen_once(dataset: TeamDataset) -> list[tuple[int, int]]:
    """``(robot, object id)`` of every object observed in one frame by one robot and never
    again by anyone: nothing to estimate it from (with ``per-robot`` ids an id is the robot's
    own, so "anyone" is that robot). Not an error of the data — a detector can see an object
    once — but worth knowing."""
    once: list[tuple[int, int]] = []
    if dataset.object_id_scope == "global":
        everywhere = [r.objects.ids for r in dataset.robots]
        ids, counts = np.unique(np.concatenate(everywhere), return_counts=True)
        single = set(ids[counts == 1].tolist())
        for i, robot_ids in enumerate(everywhere):
            once += [(i, int(k)) for k in robot_ids.tolist() if k in single]
        return sorted(once)
    for i, robot in enumerate(dataset.robots):
        ids, counts = np.unique(robot.objects.ids, return_counts=True)
        once += [(i, int(k)) for k in ids[counts == 1].tolist()]
    return once


def dataset_info(dataset: TeamDataset) -> dict:
    """Robots, frames, objects observed and shared, observations per frame, geometric tracks."""
    seen_by = [np.unique(r.objects.ids) for r in dataset.robots]
    all_seen = np.concatenate(seen_by) if seen_by else np.zeros(0, np.int64)
    ids, robots_per_object = np.unique(all_seen, return_counts=True)
    track_lengths = np.concatenate([_tracks(r.features) for r in dataset.robots])
    frames = [r.frames for r in dataset.robots]
    return {
        "name": dataset.name,
        "robots": dataset.n_robots,
        "frames_per_robot": frames,
        "objects_in_map": int(dataset.object_ids.size),
        "objects_observed": int(ids.size),
        "objects_shared": int((robots_per_object >= 2).sum()),
        "objects_seen_once": [list(pair) for pair in seen_once(dataset)],
        "object_observations_per_frame": _per_frame([r.objects for r in dataset.robots]),
        "feature_observations_per_frame": _per_frame([r.features for r in dataset.robots]),
        "detections_per_frame": _detections_per_frame(dataset),
        "geometric_tracks": int(track_lengths.size),
        "geometric_track_length_mean": float(track_lengths.mean()) if track_lengths.size else 0.0,
        "fx": float(dataset.calibration.camera.intrinsics[0, 0]),
        "fx_baseline": dataset.calibration.camera.fx_baseline,
        "sensor_model": None if dataset.sensor_model is None else dataset.sensor_model.to_json(),
        "noise_against_ground_truth": ground_truth_noise(dataset),
    }


def format_info(info: dict) -> str:
    """Human-readable version of :func:`dataset_info`."""
    o, f = info["object_observations_per_frame"], info["feature_observations_per_frame"]
    return "\n".join(
        [
            f"dataset            {info['name']}",
            f"robots             {info['robots']}",
            f"frames per robot   {', '.join(str(n) for n in info['frames_per_robot'])}",
            f"objects            {info['objects_observed']} observed "
            f"({info['objects_shared']} by ≥ 2 robots), {info['objects_in_map']} in the map",
            *_seen_once_line(info.get("objects_seen_once") or []),
            f"object obs/frame   mean {o['mean']:.2f}, max {o['max']} ({o['total']} in all)",
            *_detections_line(info.get("detections_per_frame")),
            f"feature obs/frame  mean {f['mean']:.2f}, max {f['max']} ({f['total']} in all)",
            f"geometric tracks   {info['geometric_tracks']}, mean length "
            f"{info['geometric_track_length_mean']:.2f} frames",
            f"camera             fx {info['fx']:.6g}, fx·baseline {info['fx_baseline']:.6g}",
            *_noise_lines(info),
        ]
    )


def _detections_per_frame(dataset: TeamDataset) -> dict | None:
    """Detections without ids per frame, how many in stereo, and what they carry."""
    detections = [r.detections for r in dataset.robots if r.detections is not None]
    if not detections:
        return None
    counts = np.concatenate([np.diff(d.offsets) for d in detections])
    z = np.concatenate([d.measurements for d in detections])
    first = detections[0]
    return {
        "mean": float(counts.mean()) if counts.size else 0.0,
        "max": int(counts.max()) if counts.size else 0,
        "total": int(counts.sum()),
        "stereo": int(np.all(np.isfinite(z), axis=1).sum()),
        "classes": first.classes is not None,
        "appearance": None if first.appearance is None else int(first.appearance.shape[1]),
        "truth": first.truth is not None,
    }


def _detections_line(d: dict | None) -> list[str]:
    if not d:
        return []
    carried = [name for name in ("classes", "truth") if d[name]]
    if d["appearance"]:
        carried.append(f"appearance ({d['appearance']} numbers)")
    return [
        f"detections/frame   mean {d['mean']:.2f}, max {d['max']} ({d['total']} in all, "
        f"{d['stereo']} in stereo); without ids"
        + (f", with {', '.join(carried)}" if carried else "")
    ]


def _seen_once_line(once: list) -> list[str]:
    if not once:
        return []
    named = ", ".join(f"robot {r} id {k}" for r, k in once[:3])
    more = f" and {len(once) - 3} more" if len(once) > 3 else ""
    return [
        f"seen once          {len(once)} object{'s' if len(once) > 1 else ''} in one frame of "
        f"one robot only, nothing to estimate {'them' if len(once) > 1 else 'it'} from: "
        f"{named}{more}"
    ]


def _noise_lines(info: dict) -> list[str]:
    model = info.get("sensor_model")
    truth = info.get("noise_against_ground_truth") or {}
    lines = []
    if model is None:
        lines.append("sensor model       none (teamslam run calibrates one from the data)")
    else:
        note = f": {model['note']}" if model["note"] else ""
        lines.append(f"sensor model       {model['origin']}{note}")
        for key in ("odometry_std", "feature_std", "object_std", "object_depth_range"):
            if key in model:
                lines.append(f"  {key:<20}{format_value(model[key], 3)}")
    if truth:
        lines.append("noise against ground truth (robust std)")
        for key in ("odometry_std", "feature_std", "object_std"):
            lines.append(f"  {key:<20}{format_value(truth.get(key), 3)}")
    return lines
