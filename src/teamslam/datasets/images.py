"""From a team's stereo image folders to a team dataset, through the stereo front-end.

Each robot gives a folder of left images and one of right images (paired by file name, in
name order), optionally a timestamps file (one stamp per line, seconds, increasing), an
odometry trajectory and a ground-truth trajectory (TUM files, interpolated at the image
stamps). The team shares one camera file (:func:`teamslam.frontend.load_camera`).

Per frame the front-end (:class:`teamslam.frontend.StereoFrontend`) gives the stereo pixel
coordinates of feature tracks (ids unique over the team) and of fiducial markers (the marker
id is the object id, shared by every robot). Without odometry, the robot's motion is stereo
visual odometry (PnP + RANSAC), recorded as such in ``metadata``; without ground truth the
poses stored as truth are the dead-reckoned odometry, also recorded in ``metadata`` (scores
against them mean nothing).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from teamslam.datasets.model import Calibration, FrameObservations, RobotSequence, TeamDataset
from teamslam.datasets.trajectory import read_tum
from teamslam.errors import InputError
from teamslam.frontend._cv import require_cv2
from teamslam.frontend.camera import StereoRig, load_camera
from teamslam.frontend.config import FrontendConfig
from teamslam.frontend.odometry import stereo_motion
from teamslam.frontend.pipeline import StereoFrontend
from teamslam.geometry import se3

__all__ = [
    "IMAGE_SUFFIXES",
    "dataset_from_images",
    "image_pairs",
    "read_image",
    "read_markers",
    "read_timestamps",
    "rendered_team_inputs",
]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".pgm", ".ppm", ".bmp", ".tif", ".tiff")


def image_pairs(left_dir: str | Path, right_dir: str | Path) -> list[tuple[Path, Path]]:
    """Left and right image files paired by name, in name order."""
    left_dir, right_dir = Path(left_dir), Path(right_dir)
    files = []
    for d in (left_dir, right_dir):
        if not d.is_dir():
            raise InputError(f"{d}: not a directory of images")
        files.append(sorted(p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES))
    left, right = files
    if not left:
        raise InputError(f"{left_dir}: no images ({', '.join(IMAGE_SUFFIXES)})")
    names_r = {p.name for p in right}
    for p in left:
        if p.name not in names_r:
            raise InputError(f"{p}: no right image of the same name in {right_dir}")
    names_l = {p.name for p in left}
    for p in right:
        if p.name not in names_l:
            raise InputError(f"{p}: no left image of the same name in {left_dir}")
    return [(p, right_dir / p.name) for p in left]


def read_image(path: Path, image_size: tuple[int, int]) -> np.ndarray:
    """An 8-bit grey image of ``(width, height)``; :class:`InputError` naming the file else."""
    cv2 = require_cv2()
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(f"{path}: cannot read the image (missing, empty or not an image)")
    if img.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        img = cv2.cvtColor(img, code)
    if img.dtype == np.uint16:
        img = (img // 257).astype(np.uint8)
    if img.dtype != np.uint8:
        raise InputError(f"{path}: unsupported pixel type {img.dtype} (8 or 16 bit needed)")
    w, h = image_size
    if img.shape != (h, w):
        raise InputError(
            f"{path}: image is {img.shape[1]}×{img.shape[0]}, the camera file says {w}×{h}"
        )
    return img


def read_timestamps(path: str | Path) -> np.ndarray:
    """Stamps (first column of each line, seconds); a negative, non-finite or out-of-order
    stamp is an error."""
    path = Path(path)
    try:
        rows = np.loadtxt(path, ndmin=2, comments="#")
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read timestamps ({exc})") from None
    stamps = rows[:, 0] if rows.size else np.zeros(0)
    bad = np.flatnonzero(~np.isfinite(stamps) | (stamps < 0))
    if bad.size:
        k = int(bad[0])
        raise InputError(
            f"{path}: stamp {float(stamps[k])!r} (line {k + 1}); stamps must be finite and ≥ 0"
        )
    bad = np.flatnonzero(np.diff(stamps) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise InputError(
            f"{path}: stamp {float(stamps[k])!r} (line {k + 1}) "
            f"is not after {float(stamps[k - 1])!r}"
        )
    return stamps


def read_markers(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A marker map ``id x y z`` per line: ``(ids (K,), positions (K, 3))``."""
    path = Path(path)
    try:
        rows = np.loadtxt(path, ndmin=2, comments="#")
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read markers ({exc})") from None
    if rows.size and rows.shape[1] != 4:
        raise InputError(f"{path}: marker lines need 4 numbers (id x y z)")
    if rows.size == 0:
        return np.zeros(0, np.int64), np.zeros((0, 3))
    return rows[:, 0].astype(np.int64), rows[:, 1:4]


def _poses_at(path: Path, stamps: np.ndarray | None, frames: int, what: str) -> np.ndarray:
    """Poses of a TUM file at the image stamps (interpolated), or row by row without stamps."""
    t, poses = read_tum(path)
    if len(t) == 0:
        raise InputError(f"{path}: empty {what} trajectory")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise InputError(
            f"{path}: stamp {float(t[k])!r} (line {k + 1}) is not after {float(t[k - 1])!r}"
        )
    if stamps is None:
        if len(poses) != frames:
            raise InputError(
                f"{path}: {len(poses)} {what} poses for {frames} image pairs "
                "(give --timestamps to interpolate at the image stamps)"
            )
        return poses
    tol = 1e-6 * max(1.0, float(np.abs(t).max()))
    outside = np.flatnonzero((stamps < t[0] - tol) | (stamps > t[-1] + tol))
    if outside.size:
        s = stamps[outside[0]]
        raise InputError(
            f"{path}: image stamp {float(s)!r} lies outside the {what} trajectory "
            f"[{float(t[0])!r}, {float(t[-1])!r}]"
        )
    q = np.clip(stamps, t[0], t[-1])
    out = np.tile(np.eye(4), (len(q), 1, 1))
    for axis in range(3):
        out[:, axis, 3] = np.interp(q, t, poses[:, axis, 3])
    if len(t) == 1:
        out[:, :3, :3] = poses[0, :3, :3]
    else:
        out[:, :3, :3] = Slerp(t, Rotation.from_matrix(poses[:, :3, :3]))(q).as_matrix()
    return out


def _per_robot(value, robots: int, what: str) -> list:
    if value is None:
        return [None] * robots
    if isinstance(value, (str, Path)):
        value = [value]
    value = list(value)
    if len(value) != robots:
        raise InputError(f"{len(value)} {what} for {robots} robots")
    return value


def dataset_from_images(
    left_dirs: Sequence[str | Path],
    right_dirs: Sequence[str | Path],
    camera: str | Path,
    timestamps: Sequence[str | Path | None] | None = None,
    odometry: Sequence[str | Path | None] | None = None,
    ground_truth: Sequence[str | Path | None] | None = None,
    robot_names: Sequence[str] | None = None,
    *,
    markers: str | Path | None = None,
    config: FrontendConfig | None = None,
    name: str = "images",
    progress: bool = True,
) -> TeamDataset:
    """Run the stereo front-end over every robot's images and build the team dataset.

    Parameters
    ----------
    left_dirs, right_dirs
        Per robot, the folders of left and right images (paired by file name).
    camera
        The team's stereo camera file (:func:`teamslam.frontend.load_camera`).
    timestamps, odometry, ground_truth
        Per robot (``None`` entries allowed): a timestamps file, an odometry TUM file, a
        ground-truth TUM file. Without odometry the motion is stereo visual odometry.
    robot_names
        Per robot a name (recorded in ``metadata``); default ``robot_0``, ``robot_1``, ….
    markers
        Optional marker map (``id x y z`` per line), the objects' true positions.
    config
        Front-end settings.
    name
        The dataset's name.
    progress
        Show a progress bar.

    Returns
    -------
    TeamDataset
        Pixel measurements in the rectified camera; ``metadata["images"]`` records the
        sources, the front-end settings, and per robot where odometry and truth came from,
        stereo observations per frame and the share the outlier gate rejected.
    """
    from tqdm import tqdm

    left_dirs, right_dirs = list(left_dirs), list(right_dirs)
    n = len(left_dirs)
    if n == 0 or len(right_dirs) != n:
        raise InputError(f"{n} left folders and {len(right_dirs)} right folders: need one each")
    stamps_files = _per_robot(timestamps, n, "timestamps files")
    odo_files = _per_robot(odometry, n, "odometry files")
    gt_files = _per_robot(ground_truth, n, "ground-truth files")
    names = list(robot_names) if robot_names is not None else [f"robot_{i}" for i in range(n)]
    if len(names) != n or len(set(names)) != n:
        raise InputError(f"need {n} distinct robot names, got {names}")
    config = config or FrontendConfig()
    rig = load_camera(camera)
    pairs = [image_pairs(a, b) for a, b in zip(left_dirs, right_dirs, strict=True)]
    stamps = []
    for i, f in enumerate(stamps_files):
        if f is None:
            stamps.append(None)
            continue
        s = read_timestamps(f)
        if len(s) != len(pairs[i]):
            raise InputError(f"{f}: {len(s)} stamps for {len(pairs[i])} image pairs")
        stamps.append(s)
    bar = tqdm(total=sum(len(p) for p in pairs), desc="images", disable=not progress)
    try:
        robots, info = [], []
        next_id = 0
        for i in range(n):
            frames = len(pairs[i])
            odo = None
            if odo_files[i] is not None:
                odo = _poses_at(Path(odo_files[i]), stamps[i], frames, "odometry")
            truth = None
            if gt_files[i] is not None:
                truth = _poses_at(Path(gt_files[i]), stamps[i], frames, "ground-truth")
            images = (
                (read_image(lp, rig.image_size), read_image(rp, rig.image_size), str(lp))
                for lp, rp in pairs[i]
            )
            robot, record, next_id = _robot_sequence(
                images, rig, config, next_id, odo, truth, stamps[i], bar
            )
            record.update(
                {
                    "name": names[i],
                    "left": str(left_dirs[i]),
                    "right": str(right_dirs[i]),
                    "odometry": f"file {odo_files[i]}" if odo is not None else record["odometry"],
                    "ground_truth": (
                        f"file {gt_files[i]}" if truth is not None else record["ground_truth"]
                    ),
                }
            )
            robots.append(robot)
            info.append(record)
    finally:  # closed before any error is printed
        bar.close()
    return _team(robots, info, rig, config, markers, name, {"camera": str(camera)})


def _robot_sequence(
    images,
    rig: StereoRig,
    config: FrontendConfig,
    first_id: int,
    odometry_poses: np.ndarray | None,
    truth: np.ndarray | None,
    stamps: np.ndarray | None,
    bar,
) -> tuple[RobotSequence, dict, int]:
    """Run the front-end over ``(left, right, where)`` frames; build the robot's sequence."""
    px = config.pixels(rig.image_size)
    frontend = StereoFrontend(rig, config, first_id=first_id)
    feats, objs, motions = [], [], []
    prev = None
    searched = rejected = 0
    for k, (left, right, where) in enumerate(images):
        m = frontend.process(left, right, where=where)
        feats.append((m.feature_ids, m.features))
        objs.append((m.object_ids, m.objects))
        searched += m.searched
        rejected += m.rejected
        if odometry_poses is None and k > 0:
            motions.append(
                stereo_motion(
                    frontend.camera,
                    rig.T_rect_body,
                    prev.feature_ids,
                    prev.features,
                    m.track_ids,
                    m.track_uv,
                    px.vo_reprojection,
                    config.vo_min_inliers,
                )
            )
        prev = m
        bar.update()
    frames = len(feats)
    if frames == 0:
        raise InputError("no stereo frames")
    record: dict = {}
    if odometry_poses is not None:
        if len(odometry_poses) != frames:
            raise InputError(f"{len(odometry_poses)} odometry poses for {frames} stereo frames")
        odometry_rel = se3.inverse(odometry_poses[:-1]) @ odometry_poses[1:]
        record["odometry"] = "given"
    else:
        odometry_rel, failed, last = np.tile(np.eye(4), (frames - 1, 1, 1)), 0, np.eye(4)
        for k, motion in enumerate(motions):
            if motion is None:  # too few inliers: assume the previous motion again
                failed += 1
                motion = last
            odometry_rel[k] = motion
            last = motion
        record["odometry"] = "stereo visual odometry (PnP + RANSAC)"
        record["visual_odometry_failures"] = failed
    if truth is not None:
        if len(truth) != frames:
            raise InputError(f"{len(truth)} ground-truth poses for {frames} stereo frames")
        record["ground_truth"] = "given"
    else:
        truth = np.tile(np.eye(4), (frames, 1, 1))
        for k in range(frames - 1):
            truth[k + 1] = truth[k] @ odometry_rel[k]
        record["ground_truth"] = "none: the poses stored as truth are dead-reckoned odometry"
    features = FrameObservations.from_frames(feats)
    record["stereo_observations_per_frame"] = float(features.counts().mean())
    record["stereo_rejected_share"] = rejected / max(searched, 1)
    robot = RobotSequence(
        T_world_body=truth,
        odometry=odometry_rel,
        features=features,
        objects=FrameObservations.from_frames(objs),
        timestamps=stamps,
    )
    return robot, record, frontend.next_id


def _team(robots, info, rig, config, markers, name, source: dict) -> TeamDataset:
    if markers is not None:
        object_ids, object_positions = read_markers(markers)
    else:
        object_ids, object_positions = np.zeros(0, np.int64), np.zeros((0, 3))
    return TeamDataset(
        name=name,
        calibration=Calibration(rig.camera, rig.T_rect_body, rig.image_size),
        robots=robots,
        object_ids=object_ids,
        object_positions=object_positions,
        metadata={
            "source": "teamslam.datasets.images",
            "images": {
                **source,
                "markers": None if markers is None else str(markers),
                "frontend": asdict(config),
                "robots": info,
            },
        },
    )


def rendered_team_inputs(directory: str | Path) -> dict:
    """The :func:`dataset_from_images` arguments for a folder written by
    :func:`teamslam.sim.render.render_team` (every robot's folders, files and the markers)."""
    directory = Path(directory)
    robots = sorted(
        (p for p in directory.glob("robot_*") if p.is_dir()), key=lambda p: int(p.name[6:])
    )
    if not robots:
        raise InputError(f"{directory}: no robot_k folders of a rendered team")
    return {
        "left_dirs": [r / "left" for r in robots],
        "right_dirs": [r / "right" for r in robots],
        "camera": robots[0] / "camera.yaml",
        "timestamps": [r / "timestamps.txt" for r in robots],
        "odometry": [r / "odometry.tum" for r in robots],
        "ground_truth": [r / "groundtruth.tum" for r in robots],
        "robot_names": [r.name for r in robots],
        "markers": directory / "markers.txt",
    }
