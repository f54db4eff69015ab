"""Write a complete two-robot teamslam dataset with numpy and json alone.

Usage: python dataset_example.py OUT_DIR
"""

import json
import sys
from pathlib import Path

import numpy as np

out = Path(sys.argv[1] if len(sys.argv) > 1 else "two-robots")
out.mkdir(parents=True, exist_ok=True)
rng = np.random.default_rng(0)
frames = 12  # poses per robot: N + 1

# The stereo rig: K in pixels, the right camera 0.5 m along the left camera's x axis.
K = np.array([[450.0, 0.0, 320.0], [0.0, 450.0, 240.0], [0.0, 0.0, 1.0]])
T_left_right = np.eye(4)
T_left_right[0, 3] = 0.5
# Body x forward, y left, z up -> left optical frame x right, y down, z forward.
T_cam_body = np.eye(4)
T_cam_body[:3, :3] = [[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]

# The true map: 30 objects along a corridor, ids shared by both robots ("global" ids).
object_ids = np.arange(100, 130, dtype=np.int64)
object_positions = np.column_stack(
    [rng.uniform(0.0, 30.0, 30), rng.uniform(-6.0, 6.0, 30), rng.uniform(-1.0, 2.0, 30)]
)


def pose(x, y):
    """A body pose in the world frame: at (x, y, 0), facing +x."""
    T = np.eye(4)
    T[:2, 3] = x, y
    return T


def stereo(T_world_body, p_world):
    """(u_l, v_l, u_r, v_r) in pixels of the points in front of the camera, and which those are."""
    T_cam_world = T_cam_body @ np.linalg.inv(T_world_body)
    p_left = p_world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    p_right = p_left - T_left_right[:3, 3]
    visible = (p_left[:, 2] > 1.0) & (p_left[:, 2] < 25.0)
    uv_left = p_left[:, :2] / p_left[:, 2:] * K[0, 0] + K[:2, 2]
    uv_right = p_right[:, :2] / p_right[:, 2:] * K[0, 0] + K[:2, 2]
    return np.hstack([uv_left, uv_right]), visible


robots = []
for i, y in enumerate((-1.5, 1.5)):  # two robots driving side by side, 0.5 m per frame
    T_world_body = np.stack([pose(0.5 * k, y) for k in range(frames)])
    # odometry[k] = T_k^-1 T_{k+1}, measured with a little noise on the forward motion
    odometry = np.linalg.inv(T_world_body[:-1]) @ T_world_body[1:]
    odometry[:, 0, 3] += rng.normal(0.0, 0.01, frames - 1)
    ids, measurements, offsets = [], [], [0]
    for T in T_world_body:
        z, visible = stereo(T, object_positions)
        ids.append(object_ids[visible])
        measurements.append(z[visible] + rng.normal(0.0, 1.0, z[visible].shape))
        offsets.append(offsets[-1] + int(visible.sum()))
    np.savez_compressed(
        out / f"robot_{i:03d}.npz",
        T_world_body=T_world_body,
        odometry=odometry,
        feature_offsets=np.zeros(frames + 1, np.int64),  # this team has objects only
        feature_ids=np.zeros(0, np.int64),
        feature_measurements=np.zeros((0, 4)),
        object_offsets=np.array(offsets, np.int64),
        object_ids=np.concatenate(ids),
        object_measurements=np.concatenate(measurements),
        timestamps=0.1 * np.arange(frames),
    )
    robots.append({"file": f"robot_{i:03d}.npz", "frames": frames, "timestamps": True})

np.savez_compressed(
    out / "map.npz",
    object_ids=object_ids,
    object_positions=object_positions,
    landmark_ids=np.zeros(0, np.int64),
    landmark_positions=np.zeros((0, 3)),
    track_landmarks=np.zeros((0, 2), np.int64),
)
manifest = {
    "format": "teamslam-team-dataset",
    "version": 3,
    "name": "two-robots",
    "calibration": {
        "K": K.tolist(),
        "T_left_right": T_left_right.tolist(),
        "T_cam_body": T_cam_body.tolist(),
        "image_size": [640, 480],
    },
    "robots": robots,
    "map": "map.npz",
    "object_ids": "global",
    "sensor_model": {
        "version": 1,
        "origin": "user",
        "note": "the noise this script adds",
        "odometry_std": [0.01, 0.001, 0.001, 0.001, 0.001, 0.001],
        "feature_std": 1.0,
        "object_std": 1.0,
        "object_depth_range": [1.0, 25.0],
    },
    "metadata": {"source": "docs/reference/dataset_example.py"},
}
(out / "manifest.json").write_text(json.dumps(manifest, indent=2) + "\n")
print(f"wrote {out}")
