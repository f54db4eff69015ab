"""From a team's stereo image folders to a team dataset, through the stereo front-end.

Each robot gives a folder of left images and one of right images (paired by file name, in
name order), optionally a timestamps file (one stamp per line, seconds, increasing), an
odometry trajectory and a ground-truth trajectory (TUM files, interpolated at the image
stamps). The team shares one camera file (:func:`teamslam.frontend.load_camera`).

Per frame the front-end (:class:`teamslam.frontend.StereoFrontend`) gives the stereo pixel
coordinates of feature tracks (ids unique over the team) and the objects: fiducial markers (the
marker id is the object id, shared by every robot), or, given a detector's boxes per robot
(:func:`teamslam.frontend.detections.read_detections`), detections without ids — each box
measured in stereo, with its class, score, size and an appearance descriptor (the detector's
embedding where it gives one, else :func:`teamslam.frontend.appearance.describe` of the image
inside the box) — which each robot's filter then tracks itself. Without odometry, the robot's
motion is stereo visual odometry (PnP + RANSAC), recorded as such in ``metadata``; without
ground truth the poses stored as truth are the dead-reckoned odometry, also recorded in
``metadata`` (scores against them mean nothing).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from teamslam.datasets.model import (
    Calibration,
    FrameDetections,
    FrameObservations,
    RobotSequence,
    TeamDataset,
)
from teamslam.datasets.trajectory import read_tum
from teamslam.errors import InputError
from teamslam.frontend._cv import require_cv2
from teamslam.frontend.camera import StereoRig, load_camera
from teamslam.frontend.config import FrontendConfig
from teamslam.frontend.detections import DetectionsRead, ImageDetections, read_detections
from teamslam.frontend.odometry import stereo_motion
from teamslam.frontend.pipeline import StereoFrontend
from teamslam.geometry import se3

__all__ = [
    "IMAGE_SUFFIXES",
    "dataset_from_images",
    "image_pairs",
    "read_detection_truth",
    "read_image",
    "read_markers",
    "read_objects",
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


def read_image(path: Path, image_size: tuple[int, int], colour: bool = False) -> np.ndarray:
    """An 8-bit grey image of ``(width, height)`` — with ``colour``, the image as it is stored
    (BGR when it has colour, grey otherwise); :class:`InputError` naming the file else."""
    cv2 = require_cv2()
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(f"{path}: cannot read the image (missing, empty or not an image)")
    if colour and img.ndim == 3 and img.dtype == np.uint8:
        img = img[:, :, :3] if img.shape[2] == 4 else img
        w, h = image_size
        if img.shape[:2] != (h, w):
            raise InputError(
                f"{path}: image is {img.shape[1]}×{img.shape[0]}, the camera file says {w}×{h}"
            )
        return np.ascontiguousarray(img)
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


def read_objects(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An object map ``id class x y z`` per line: ``(ids (K,), classes (K,), positions (K, 3))``."""
    path = Path(path)
    try:
        rows = np.loadtxt(path, ndmin=2, comments="#")
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read objects ({exc})") from None
    if rows.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3))
    if rows.shape[1] != 5:
        raise InputError(f"{path}: object lines need 5 numbers (id class x y z)")
    if not np.all(np.isfinite(rows)):
        raise InputError(f"{path}: object lines must be finite numbers")
    return rows[:, 0].astype(np.int64), rows[:, 1].astype(np.int64), rows[:, 2:5]


def read_detection_truth(
    folder: str | Path, image_names: Sequence[str | Path], read: DetectionsRead
) -> list[np.ndarray]:
    """The true object of every box, for evaluation only: per image ``<stem>.txt`` in
    ``folder`` with one integer per box, in the order of the detection file (``-1``: a false
    box); an image without a file has no boxes. The counts must equal the boxes ``read`` kept.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: not a folder of detection truth files")
    out = []
    for name, boxes in zip(image_names, read.images, strict=True):
        path = folder / (Path(str(name)).stem + ".txt")
        ids = np.zeros(0, np.int64)
        if path.exists():
            try:
                values = np.loadtxt(path, ndmin=1, comments="#")
            except (OSError, ValueError) as exc:
                raise InputError(f"{path}: cannot read detection truth ({exc})") from None
            if values.size and (values.ndim != 1 or np.any(values != np.round(values))):
                raise InputError(f"{path}: one integer object id per line (-1: a false box)")
            ids = values.astype(np.int64).reshape(-1)
        if ids.size != len(boxes):
            raise InputError(
                f"{path}: {ids.size} truth lines for {len(boxes)} boxes kept of the detections"
            )
        if np.any(ids < -1):
            raise InputError(f"{path}: object ids must be ≥ 0, or -1 for a false box")
        out.append(ids)
    return out


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
    detections: Sequence[str | Path | None] | None = None,
    right_detections: Sequence[str | Path | None] | None = None,
    detection_truth: Sequence[str | Path | None] | None = None,
    coco_images: Sequence[str | Path | None] | None = None,
    objects: str | Path | None = None,
    descriptor: str | None = None,
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
    detections
        Per robot a detector's output for its left images (a YOLO folder or a COCO JSON,
        :func:`~teamslam.frontend.detections.read_detections`): the objects are then its boxes,
        without ids (markers are not read as objects), and each robot tracks them itself.
    right_detections
        Per robot the detector's output for the right images, when it ran on them (paired
        with the left boxes; the others are searched along the row).
    detection_truth
        Per robot, for evaluation only, a folder of ``<stem>.txt`` files giving the true
        object of each left box (:func:`read_detection_truth`).
    coco_images
        Per robot the COCO ``images`` list mapping integer image ids to files, when its COCO
        file has none.
    objects
        Optional object map (``id class x y z`` per line), the true objects of the boxes.
    descriptor
        The appearance descriptor of boxes without an embedding
        (:data:`~teamslam.frontend.appearance.DESCRIPTORS`; default
        :data:`~teamslam.frontend.appearance.DEFAULT_DESCRIPTOR`).
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
    det_sources = _per_robot(detections, n, "detection sources")
    right_sources = _per_robot(right_detections, n, "right-image detection sources")
    truth_dirs = _per_robot(detection_truth, n, "detection truth folders")
    coco_files = _per_robot(coco_images, n, "COCO images files")
    boxes_given = any(d is not None for d in det_sources)
    if boxes_given and not all(d is not None for d in det_sources):
        raise InputError("detections for some robots and not others: give one per robot")
    if not boxes_given:
        extra = [
            flag
            for flag, v in (
                ("right detections", right_detections),
                ("detection truth", detection_truth),
                ("COCO images files", coco_images),
            )
            if v is not None and any(x is not None for x in _per_robot(v, n, flag))
        ]
        if extra:
            raise InputError(f"{extra[0]} given without detections")
    config = config or FrontendConfig()
    rig = load_camera(camera)
    pairs = [image_pairs(a, b) for a, b in zip(left_dirs, right_dirs, strict=True)]
    boxes = [None] * n
    if boxes_given:
        boxes = [
            _robot_boxes(
                pairs[i], rig, det_sources[i], right_sources[i], truth_dirs[i], coco_files[i]
            )
            for i in range(n)
        ]
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
            colour = boxes[i] is not None
            images = (
                (
                    read_image(lp, rig.image_size, colour=colour),
                    read_image(rp, rig.image_size),
                    str(lp),
                )
                for lp, rp in pairs[i]
            )
            robot, record, next_id = _robot_sequence(
                images, rig, config, next_id, odo, truth, stamps[i], bar, boxes[i], descriptor
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
    source = {"camera": str(camera)}
    if boxes_given:
        source["detections"] = [str(d) for d in det_sources]
        source["objects"] = None if objects is None else str(objects)
    return _team(robots, info, rig, config, markers, name, source, objects, boxes_given)


def _robot_boxes(pairs, rig: StereoRig, source, right_source, truth_dir, coco_file) -> dict:
    """One robot's detector output, read and checked before any image is processed."""
    names = [lp.name for lp, _ in pairs]
    left = read_detections(source, names, rig.image_size, images_file=coco_file)
    right = None
    if right_source is not None:
        right = read_detections(right_source, names, rig.image_size, images_file=coco_file)
    truth = None if truth_dir is None else read_detection_truth(truth_dir, names, left)
    return {"left": left, "right": right, "truth": truth, "source": str(source)}


def _robot_sequence(
    images,
    rig: StereoRig,
    config: FrontendConfig,
    first_id: int,
    odometry_poses: np.ndarray | None,
    truth: np.ndarray | None,
    stamps: np.ndarray | None,
    bar,
    boxes: dict | None = None,
    descriptor: str | None = None,
) -> tuple[RobotSequence, dict, int]:
    """Run the front-end over ``(left, right, where)`` frames; build the robot's sequence."""
    px = config.pixels(rig.image_size)
    frontend = StereoFrontend(rig, config, first_id=first_id)
    feats, objs, motions = [], [], []
    frame_boxes = []
    prev = None
    searched = rejected = 0
    for k, (left, right, where) in enumerate(images):
        colour = left if left.ndim == 3 else None
        if colour is not None:
            cv2 = require_cv2()
            left = cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY)
        if boxes is not None:
            if k >= len(boxes["left"].images):
                raise InputError(f"{where}: more images than the detections were read for")
            right_boxes = None if boxes["right"] is None else boxes["right"].images[k]
            m = frontend.process(left, right, where, boxes["left"].images[k], right_boxes)
            frame_boxes.append(
                _described(
                    m.boxes, boxes["left"].images[k], left if colour is None else colour, descriptor
                )
            )
        else:
            m = frontend.process(left, right, where=where)
        feats.append((m.feature_ids, m.features))
        objs.append((m.object_ids, m.objects) if boxes is None else _no_objects())
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
    detections = None
    if boxes is not None:
        detections, counts = _frame_detections(frame_boxes, boxes["truth"])
        read = boxes["left"]
        record["detections"] = {
            "source": boxes["source"],
            "boxes_read": read.boxes_read,
            "boxes_clipped": read.boxes_clipped,
            "boxes_dropped": read.boxes_dropped,
            "images_without_file": read.images_without_file,
            "appearance": "embedding" if read.dimension else "descriptor",
            **counts,
        }
    robot = RobotSequence(
        T_world_body=truth,
        odometry=odometry_rel,
        features=features,
        objects=FrameObservations.from_frames(objs),
        timestamps=stamps,
        detections=detections,
    )
    return robot, record, frontend.next_id


def _no_objects() -> tuple[np.ndarray, np.ndarray]:
    return np.zeros(0, np.int64), np.zeros((0, 4))


def _described(measured, given: ImageDetections, image: np.ndarray, descriptor) -> tuple:
    """A frame's measured boxes with their appearance: the detector's embeddings, or
    descriptors of the image inside each box."""
    from teamslam.frontend.appearance import DEFAULT_DESCRIPTOR, describe

    if given.embeddings is not None:
        looks = np.asarray(given.embeddings, np.float32)
    else:
        looks = describe(image, given.boxes, descriptor or DEFAULT_DESCRIPTOR)
    return measured, looks


def _frame_detections(frames: list, truth: list | None) -> tuple[FrameDetections, dict]:
    """Every frame's measured boxes as detections without ids; counts by stereo source."""
    counts: dict[str, int] = {}
    for measured, _ in frames:
        for key, value in measured.counts().items():
            counts[key] = counts.get(key, 0) + value
    sizes = [m.sizes for m, _ in frames]
    offsets = np.concatenate([[0], np.cumsum([len(s) for s in sizes])]).astype(np.int64)
    detections = FrameDetections(
        offsets,
        np.concatenate([m.z for m, _ in frames]).reshape(-1, 4),
        np.concatenate([m.classes for m, _ in frames]).astype(np.int64),
        np.concatenate([m.scores for m, _ in frames]),
        None if truth is None else np.concatenate(truth).astype(np.int64),
        np.concatenate(sizes).reshape(-1, 2),
        np.concatenate([looks for _, looks in frames]).astype(np.float32),
    )
    return detections, counts


def _team(
    robots, info, rig, config, markers, name, source: dict, objects=None, boxes=False
) -> TeamDataset:
    if boxes:
        if objects is not None:
            object_ids, _, object_positions = read_objects(objects)
        else:
            object_ids, object_positions = np.zeros(0, np.int64), np.zeros((0, 3))
    elif markers is not None:
        object_ids, object_positions = read_markers(markers)
    else:
        object_ids, object_positions = np.zeros(0, np.int64), np.zeros((0, 3))
    return TeamDataset(
        name=name,
        calibration=Calibration(rig.camera, rig.T_rect_body, rig.image_size),
        robots=robots,
        object_ids=object_ids,
        object_positions=object_positions,
        object_id_scope="none" if boxes else "global",
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


def rendered_team_inputs(directory: str | Path, boxes: bool = True) -> dict:
    """The :func:`dataset_from_images` arguments for a folder written by
    :func:`teamslam.sim.render.render_team` (every robot's folders, files and the markers;
    with ``boxes``, the simulated detector's boxes, their truth and the object map where the
    render wrote them)."""
    directory = Path(directory)
    robots = sorted(
        (p for p in directory.glob("robot_*") if p.is_dir()), key=lambda p: int(p.name[6:])
    )
    if not robots:
        raise InputError(f"{directory}: no robot_k folders of a rendered team")
    inputs = {
        "left_dirs": [r / "left" for r in robots],
        "right_dirs": [r / "right" for r in robots],
        "camera": robots[0] / "camera.yaml",
        "timestamps": [r / "timestamps.txt" for r in robots],
        "odometry": [r / "odometry.tum" for r in robots],
        "ground_truth": [r / "groundtruth.tum" for r in robots],
        "robot_names": [r.name for r in robots],
        "markers": directory / "markers.txt",
    }
    if boxes and all((r / "detections").is_dir() for r in robots):
        inputs["detections"] = [r / "detections" for r in robots]
        if all((r / "detections_right").is_dir() for r in robots):
            inputs["right_detections"] = [r / "detections_right" for r in robots]
        if all((r / "detections_truth").is_dir() for r in robots):
            inputs["detection_truth"] = [r / "detections_truth" for r in robots]
        if (directory / "objects.txt").is_file():
            inputs["objects"] = directory / "objects.txt"
    return inputs
