"""Where a live robot's image front-end spends its CPU time, stage by stage, on the rendered team
of ``benchmarks/live_agents.py images``.

Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/frontend_cost.py [--robots 3] [--steps 100] \\
        [--width 640] [--repeats 3] [--rendered DIR] [--variant NAME=VALUE[,NAME=VALUE] ...] \\
        [--accuracy] [--objects shapes] [--markdown FILE]

The team is rendered as the live benchmark renders it (``teamslam simulate --images --seed 0``;
``--rendered DIR``: one rendered before, e.g. into ``results/``). Its ``images.mcap`` is read as
``agent --live`` receives it: per frame the two compressed images are decoded to grey (the
live robot's decoding, timed here), then one :class:`~teamslam.frontend.StereoFrontend` per
robot (the rig from the ``camera_info`` topics, feature ids continuing from robot to robot as
:func:`~teamslam.ros2.image_bags.dataset_from_bag` gives them) measures the frame; its
:class:`~teamslam.frontend._clock.StageClock` gives the CPU time of each stage, "other" the
rest of :meth:`~teamslam.frontend.StereoFrontend.process` (conversions, bookkeeping). Stereo
visual odometry (``stereo_motion`` between consecutive frames) is timed too, though a robot with
an odometry topic does not run it. ``--objects shapes`` renders the team with textured objects
and a simulated detector (``teamslam simulate --images --objects shapes``): each frame's boxes
come from the bag's detection topic, as a live robot with a detector reads them, and the box
stereo and the boxes' appearance descriptors (as ``agent --live`` describes them) are timed too.

One OpenCV and one BLAS thread, process time: CPU milliseconds, comparable under any load. The
whole sequence is measured ``--repeats`` times, each time by fresh front-ends (a frame meets the
same state every time; the measurements are checked to be equal); a frame's stage time is its
median over the repeats, the table the mean over frames. Each ``--variant`` (front-end settings,
``NAME=VALUE``) is measured the same way on the same frames; ``--accuracy`` adds per setting
the stereo observations per frame and the offline run's position RMSE against ground truth
(the dataset ``dataset_from_bag`` builds with those settings, noise levels calibrated on 60
frames, the distributed filter with ``filter.window=10``: the live benchmark's offline run).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _markdown import Markdown, add_option
from teamslam.frontend._clock import STAGES
from teamslam.frontend._cv import require_cv2
from teamslam.frontend.config import FrontendConfig, resolve_frontend

#: the stages of a live frame's front-end in the table: decoding, the front-end's, the rest
COLUMNS = ("decoding", *STAGES, "appearance", "other", "odometry")


def render(out: Path, robots: int, steps: int, width: int, objects: str | None) -> Path:
    """``teamslam simulate --images`` as ``benchmarks/live_agents.py`` runs it (with
    ``--objects`` when given); the bag."""
    argv = [sys.executable, "-m", "teamslam", "simulate", "--images", "--quiet"]
    argv += ["--robots", str(robots), "--steps", str(steps), "--image-width", str(width)]
    argv += ["--seed", "0", "--out", str(out)]
    if objects:
        argv += ["--objects", objects]
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL)
    return out / "images.mcap"


def read_bag(bag: Path, robots: int, boxes: bool = False):
    """The rig (from the first robot's ``camera_info``), the robots' topics and per robot its
    ``(stamp, left, right, boxes)`` frames in stamp order, each image its ``(serialised message,
    message type)`` as ``agent --live`` receives it; ``boxes`` the frame's
    :class:`~teamslam.frontend.detections.ImageDetections` from the robot's detection topic
    (with ``boxes``), else ``None``."""
    from teamslam.frontend.camera import rig_from_camera_info
    from teamslam.ros2 import messages as m
    from teamslam.ros2.detection_bags import read_detection_topic
    from teamslam.ros2.image_bags import ImageTopics

    topics = [ImageTopics.default(f"robot_{i}") for i in range(robots)]
    wanted = {t for r in topics for t in (r.left, r.right, *r.camera_info)}
    data: dict[str, list] = {t: [] for t in wanted}
    AnyReader = m.rosbags("highlevel", "reading a ROS 2 bag of images").AnyReader
    with AnyReader([bag], default_typestore=m.typestore()) as reader:
        conns = [c for c in reader.connections if c.topic in wanted]
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            data[conn.topic].append((m.stamp_ns(msg.header.stamp), (bytes(raw), conn.msgtype)))
    first = topics[0].camera_info
    infos = [m.typestore().deserialize_cdr(*data[t][0][1]) for t in first]
    rig = rig_from_camera_info(*infos)
    pairs = []
    for r in topics:
        right = dict(data[r.right])
        left = sorted(data[r.left], key=lambda x: x[0])
        given = [None] * len(left)
        if boxes:
            stamps = [s for s, _ in left]
            given = read_detection_topic(bag, f"/{r.name}/detections", stamps, rig.image_size)
            given = given.images
        pairs.append([(s, msg, right[s], b) for (s, msg), b in zip(left, given, strict=True)])
    return rig, topics, pairs


def one_pass(rig, pairs, config: FrontendConfig):
    """Every robot's frames through fresh front-ends: per frame ``{stage: CPU s}`` and the
    measurements (to check that passes agree)."""
    from teamslam.frontend.appearance import DEFAULT_DESCRIPTOR, describe
    from teamslam.frontend.odometry import stereo_motion
    from teamslam.frontend.pipeline import StereoFrontend
    from teamslam.ros2 import messages as m
    from teamslam.ros2.image_bags import _decode

    store = m.typestore()

    px = config.pixels(rig.image_size)
    times, out, next_id = [], [], 0
    for frames in pairs:
        frontend = StereoFrontend(rig, config, first_id=next_id)
        previous = None
        for stamp, left_msg, right_msg, boxes in frames:
            begin = time.process_time()  # as a live robot receives and decodes a pair
            left = _decode(store.deserialize_cdr(*left_msg), "left", stamp)
            right = _decode(store.deserialize_cdr(*right_msg), "right", stamp)
            decoded = time.process_time()
            frontend.clock.reset()
            measured = frontend.process(left, right, detections=boxes)
            done = time.process_time()
            row = frontend.clock.reset()
            row["other"] = done - decoded - sum(row.values())
            row["decoding"] = decoded - begin
            if boxes is not None:  # as agent --live describes a frame's boxes
                start = time.process_time()
                looks = describe(left, boxes.boxes, DEFAULT_DESCRIPTOR)
                row["appearance"] = time.process_time() - start
            if previous is not None:
                start = time.process_time()
                stereo_motion(
                    frontend.camera,
                    rig.T_rect_body,
                    previous.feature_ids,
                    previous.features,
                    measured.track_ids,
                    measured.track_uv,
                    px.vo_reprojection,
                    config.vo_min_inliers,
                )
                row["odometry"] = time.process_time() - start
            previous = measured
            times.append(row)
            m = measured
            out.append((m.feature_ids, m.features, m.object_ids, m.objects))
            if boxes is not None:
                out[-1] += (m.boxes.z, looks)
        next_id = frontend.next_id
    return times, out


def same(a, b) -> bool:
    """Two passes' measurements equal, bit for bit."""
    return all(
        x.shape == y.shape and x.tobytes() == y.tobytes()
        for fa, fb in zip(a, b, strict=True)
        for x, y in zip(fa, fb, strict=True)
    )


def profile(rig, pairs, config: FrontendConfig, repeats: int) -> tuple[dict, float]:
    """Per stage the mean over frames of each frame's median CPU ms over ``repeats`` passes;
    the stereo observations per frame."""
    runs = [one_pass(rig, pairs, config) for _ in range(repeats)]
    for _, measured in runs[1:]:
        if not same(runs[0][1], measured):
            raise SystemExit("the front-end measured a frame differently in two passes")
    frames = len(runs[0][0])
    out = {}
    for stage in COLUMNS:
        per_frame = np.array([[run[0][k].get(stage, 0.0) for run in runs] for k in range(frames)])
        out[stage] = 1e3 * float(np.median(per_frame, axis=1).mean())
    totals = np.array(
        [
            [sum(v for s, v in run[0][k].items() if s != "odometry") for run in runs]
            for k in range(frames)
        ]
    )
    out["total"] = 1e3 * float(np.median(totals, axis=1).mean())
    observations = float(np.mean([len(m[0]) for m in runs[0][1]]))
    return out, observations


def offline_rmse(bag: Path, topics, config: FrontendConfig, tmp: Path) -> float:
    """Position RMSE against ground truth of the offline distributed filter (``filter.window``
    10, noise levels calibrated on 60 frames) on the dataset the front-end builds from the bag
    with ``config``, robots pooled."""
    from teamslam import api
    from teamslam.datasets import save_dataset
    from teamslam.ros2.image_bags import dataset_from_bag

    folder = tmp / f"dataset-{len(list(tmp.iterdir()))}"
    save_dataset(dataset_from_bag(bag, topics, config=config, progress=False), folder)
    api.calibrate(folder, frames=60, write=True)
    run = api.run(folder, mode="consensus", settings={"filter.window": 10}, progress=False)
    poses = run.results["consensus"].poses
    errors = [
        p[:, :3, 3] - robot.T_world_body[:, :3, 3]
        for p, robot in zip(poses, run.dataset.robots, strict=True)
    ]
    e = np.concatenate(errors)
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--width", type=int, default=640, help="image width (4:3)")
    parser.add_argument("--repeats", type=int, default=3, help="passes over the sequence")
    parser.add_argument("--rendered", type=Path, default=None, help="a rendered team's folder")
    parser.add_argument(
        "--variant",
        action="append",
        default=[],
        metavar="NAME=VALUE[,NAME=VALUE]",
        help="also measure the front-end with these settings (repeatable)",
    )
    parser.add_argument(
        "--accuracy",
        action="store_true",
        help="the offline position RMSE of each setting (a dataset and a filter run each)",
    )
    parser.add_argument(
        "--objects",
        choices=["shapes"],
        default=None,
        help="render textured objects and a simulated detector's boxes, and time the box "
        "stereo and the boxes' appearance too",
    )
    add_option(parser)
    args = parser.parse_args()
    if args.objects and args.accuracy:
        parser.error("--accuracy is for the team without objects (the live benchmark's)")
    md = Markdown(args.markdown)
    cv2 = require_cv2()
    cv2.setNumThreads(1)
    variants = {"default": FrontendConfig()}
    for text in args.variant:
        variants[text] = resolve_frontend(text.split(","))[0]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.rendered is not None:
            bag = args.rendered / "images.mcap"
        else:
            bag = render(tmp / "rendered", args.robots, args.steps, args.width, args.objects)
        rig, topics, pairs = read_bag(bag, args.robots, boxes=bool(args.objects))
        # compile (or load) the alignment kernels before any frame is timed
        one_pass(rig, [frames[:3] for frames in pairs[:1]], FrontendConfig())
        width, height = rig.image_size
        frames = sum(len(f) for f in pairs)
        columns = ["settings", *COLUMNS, "total (no odometry)"]
        if args.accuracy:
            columns += ["stereo observations per frame", "offline RMSE (m)"]
        team = "the live benchmark's" if not args.objects else f"with objects: {args.objects}"
        boxes = (
            "box stereo: none (the team has no detector); appearance: none"
            if not args.objects
            else "box stereo: the detector's boxes measured in stereo; appearance: the boxes' "
            "descriptors (the default kind, on the grey left image, as agent --live makes them)"
        )
        md.table(
            f"Front-end CPU ms per stereo frame by stage: rendered team, {args.robots} robots × "
            f"{frames // args.robots} stereo frames {width}×{height} ({team}), "
            f"median of {args.repeats} passes per frame, mean over frames",
            columns,
            note="One OpenCV and one BLAS thread, process time. Decoding: the two images of a "
            "frame from their serialised messages (CDR, mono8) to grey arrays, as agent --live "
            "receives and decodes them. Rectification: none for this already rectified rig. "
            "Temporal LK: forward and "
            "backward tracking; track alignment: each track's affine alignment to its first "
            "appearance; feature detection: the mask, Shi–Tomasi corners, sub-pixel refinement "
            "and new templates; stereo search: the NCC row search of new points; stereo LK: "
            "the right image's gain correction and the left→right Lucas–Kanade (and back); "
            "stereo alignment: the affine left→right alignment; markers: ArUco in both images; "
            f"{boxes}. Other: the rest of a frame's "
            "front-end (conversions, bookkeeping). Odometry: stereo visual odometry between "
            "consecutive frames, which a robot with an odometry topic (as here) does not run."
            + (
                " Offline RMSE: the distributed filter (filter.window 10, noise levels "
                "calibrated on 60 frames) on the dataset built from the bag with those "
                "settings, robots pooled."
                if args.accuracy
                else ""
            ),
        )
        for name, config in variants.items():
            row, observations = profile(rig, pairs, config, args.repeats)
            cells = [name, *(f"{row[s]:.2f}" for s in COLUMNS), f"{row['total']:.1f}"]
            if args.accuracy:
                rmse = offline_rmse(bag, topics, config, tmp)
                cells += [f"{observations:.1f}", f"{rmse:.5f}"]
            print("  ".join(f"{c}={v}" for c, v in zip(columns, cells, strict=True)), flush=True)
            md.row(*cells)
        md.end()
    md.write()


if __name__ == "__main__":
    main()
