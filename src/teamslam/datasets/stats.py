"""Summary statistics of a team dataset (``teamslam data info``)."""

from __future__ import annotations

import numpy as np

from teamslam.datasets.model import FrameObservations, TeamDataset

__all__ = ["dataset_info", "format_info"]


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
        "object_observations_per_frame": _per_frame([r.objects for r in dataset.robots]),
        "feature_observations_per_frame": _per_frame([r.features for r in dataset.robots]),
        "geometric_tracks": int(track_lengths.size),
        "geometric_track_length_mean": float(track_lengths.mean()) if track_lengths.size else 0.0,
        "fx": float(dataset.calibration.camera.intrinsics[0, 0]),
        "fx_baseline": dataset.calibration.camera.fx_baseline,
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
            f"object obs/frame   mean {o['mean']:.2f}, max {o['max']} ({o['total']} in all)",
            f"feature obs/frame  mean {f['mean']:.2f}, max {f['max']} ({f['total']} in all)",
            f"geometric tracks   {info['geometric_tracks']}, mean length "
            f"{info['geometric_track_length_mean']:.2f} frames",
            f"camera             fx {info['fx']:.6g}, fx·baseline {info['fx_baseline']:.6g}",
        ]
    )
