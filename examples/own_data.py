"""Your own data: a team dataset built from numpy arrays, saved in teamslam's format, loaded
back and run.

    python examples/own_data.py --robots 3 --steps 120 --out results/own-data

Replace the "measurements" part with your robots' recordings: per robot the true poses (for
scoring), the odometry between frames and, per frame, the stereo observations of the objects
it sees, ``(u_left, v_left, u_right, v_right)`` in pixels keyed by object id. Here they come
from a few lines of simulation: robots drive circles in a field of objects.

Frames (``teamslam.datasets.model``): ``T_world_body`` maps body to world; the body frame is
x forward, y left, z up; ``T_cam_body`` maps body to the left camera's optical frame (x right,
y down, z forward); ``odometry[k] = T_world_body[k]⁻¹ · T_world_body[k + 1]``.
"""

from __future__ import annotations

import argparse

import numpy as np

import teamslam as ts
from teamslam.datasets import (
    Calibration,
    FrameObservations,
    RobotSequence,
    SensorModel,
    SensorNoise,
    TeamDataset,
)
from teamslam.geometry import se3
from teamslam.geometry.camera import StereoCamera

# the sensors: a 640×480 stereo camera, 0.5 m baseline; their noise, which the dataset carries
CAMERA = StereoCamera.from_baseline(fx=400.0, fy=400.0, cx=320.0, cy=240.0, baseline=0.5)
IMAGE_SIZE = (640, 480)
T_CAM_BODY = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]], dtype=float)
ODOMETRY_STD = np.array([0.03, 0.03, 0.01, 0.002, 0.002, 0.01])  # m, m, m, rad, rad, rad / step
PIXEL_STD = 1.0
DEPTH_RANGE = (1.0, 25.0)


def circle(centre: np.ndarray, radius: float, steps: int, phase: float) -> np.ndarray:
    """``(steps + 1, 4, 4)`` poses ``T_world_body`` once around a circle, heading forward."""
    angle = phase + np.linspace(0.0, 2 * np.pi, steps + 1)
    poses = np.tile(np.eye(4), (steps + 1, 1, 1))
    poses[:, 0, 3] = centre[0] + radius * np.cos(angle)
    poses[:, 1, 3] = centre[1] + radius * np.sin(angle)
    heading = angle + np.pi / 2  # the tangent, counter-clockwise
    poses[:, 0, 0], poses[:, 0, 1] = np.cos(heading), -np.sin(heading)
    poses[:, 1, 0], poses[:, 1, 1] = np.sin(heading), np.cos(heading)
    return poses


def observe(T_world_body: np.ndarray, objects: np.ndarray, rng) -> list:
    """Per frame ``(ids, (n, 4) noisy stereo pixels)`` of the objects in view."""
    frames = []
    for T in T_world_body:
        T_cam_world = T_CAM_BODY @ se3.inverse(T)
        p_cam = objects @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        seen = np.flatnonzero(CAMERA.in_view(p_cam, *IMAGE_SIZE, *DEPTH_RANGE))
        z = CAMERA.project(p_cam[seen]) + rng.normal(0.0, PIXEL_STD, (seen.size, 4))
        frames.append((seen, z))
    return frames


def make_dataset(robots: int, steps: int, seed: int) -> TeamDataset:
    rng = np.random.default_rng(seed)
    # the world: 150 objects in a 30 m × 30 m field, 0–3 m high
    objects = rng.uniform([-15, -15, 0], [15, 15, 3], (150, 3))
    sequences = []
    for i in range(robots):
        centre = rng.uniform(-4, 4, 2)
        truth = circle(centre, radius=8.0, steps=steps, phase=2 * np.pi * i / robots)
        # odometry: the true relative motion, perturbed on the right by exp(n), n ~ N(0, σ²)
        relative = se3.inverse(truth[:-1]) @ truth[1:]
        odometry = relative @ se3.exp(rng.normal(0.0, ODOMETRY_STD, (steps, 6)))
        sequences.append(
            RobotSequence(
                T_world_body=truth,
                odometry=odometry,
                features=FrameObservations.empty(steps + 1),  # objects only
                objects=FrameObservations.from_frames(observe(truth, objects, rng)),
                timestamps=np.arange(steps + 1) * 0.1,
            )
        )
    return TeamDataset(
        name=f"circles-{robots}r",
        calibration=Calibration(CAMERA, T_CAM_BODY, IMAGE_SIZE),
        robots=sequences,
        object_ids=np.arange(len(objects)),  # the same id in every robot's data
        object_positions=objects,
        sensor_model=SensorModel(
            SensorNoise(
                odometry_std=tuple(ODOMETRY_STD),
                object_std=PIXEL_STD,
                object_depth_range=DEPTH_RANGE,
            ),
            origin="user",
            note="the noise the example drew",
        ),
    )


def same_dataset(a: TeamDataset, b: TeamDataset) -> bool:
    """Every array of ``a`` and ``b`` equal, bit for bit."""
    pairs = [(a.object_positions, b.object_positions), (a.object_ids, b.object_ids)]
    for ra, rb in zip(a.robots, b.robots, strict=True):
        pairs += [(ra.T_world_body, rb.T_world_body), (ra.odometry, rb.odometry)]
        pairs += [(ra.timestamps, rb.timestamps)]
        for name in ("offsets", "ids", "measurements"):
            pairs.append((getattr(ra.objects, name), getattr(rb.objects, name)))
    return (
        len(a.robots) == len(b.robots)
        and a.sensor_model == b.sensor_model
        and all(np.array_equal(x, y) for x, y in pairs)
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=3, help="team size (default 3)")
    parser.add_argument("--steps", type=int, default=120, help="steps per robot (default 120)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="results/own-data", help="directory to write")
    args = parser.parse_args(argv)

    dataset = make_dataset(args.robots, args.steps, args.seed)
    # teamslam's format: a JSON manifest and one compressed .npz per robot, validated on load
    path = ts.datasets.save_dataset(dataset, f"{args.out}/dataset")
    loaded = ts.datasets.load_dataset(path)
    print(f"wrote {path}; loaded back equal: {same_dataset(dataset, loaded)}")
    print(ts.datasets.format_info(ts.datasets.dataset_info(loaded)))

    run = ts.run(loaded, mode="compare", progress=False, out=f"{args.out}/run")
    for mode in ("separate", "consensus"):
        m = run.by_mode[mode]
        print(
            f"{mode:>9}: trajectory RMSE {m['trajectory_rmse_avg_m']:.3f} m "
            f"(odometry {m['odometry_rmse_avg_m']:.3f} m), "
            f"object error {m['object_error_avg_m']:.3f} m"
        )
    print(f"run written to {args.out}/run")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
