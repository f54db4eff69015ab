"""``teamslam simulate`` and ``teamslam data``: make, inspect and import team datasets."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from teamslam.cli._common import (
    Parser,
    non_negative_float,
    non_negative_int,
    positive_int,
    rate,
    save_and_describe,
)

__all__ = ["register"]


def _cmd_simulate(args: argparse.Namespace) -> int:
    from teamslam.errors import InputError
    from teamslam.sim import grid_city_team, lissajous_team, long_route_team

    if args.objects == "shapes":
        raise InputError("--objects shapes renders objects: it needs --images")
    detector = {
        "clutter": args.clutter,
        "miss": args.miss,
        "classes": args.classes,
        "appearance": args.appearance,
        "appearance_noise": args.appearance_noise,
    }
    if args.route != "grid" and (args.blocks is not None or args.object_spacing is not None):
        raise InputError("--blocks and --object-spacing apply to --route grid")
    if args.route == "long":
        if args.objects is not None:
            raise InputError(
                "--objects sets the Lissajous arena's map; the long route scatters objects "
                "along its length (about 1.2 per metre)"
            )
        if args.clutter or args.miss or args.classes or args.appearance:
            raise InputError(
                "--clutter, --miss, --classes and --appearance apply to the Lissajous and grid "
                "routes"
            )
        dataset = long_route_team(
            robots=args.robots, steps=args.steps, seed=args.seed, noise_free=args.noise_free
        )
    elif args.route == "grid":
        grid = {
            "blocks": None if args.blocks is None else tuple(args.blocks),
            "object_spacing": args.object_spacing,
        }
        if args.objects is not None:
            raise InputError(
                "--objects sets the Lissajous arena's map; the grid city lines its streets "
                "with objects every --object-spacing metres"
            )
        dataset = grid_city_team(
            robots=args.robots,
            steps=args.steps,
            seed=args.seed,
            noise_free=args.noise_free,
            **{k: v for k, v in grid.items() if v is not None},
            **detector,
        )
    else:
        dataset = lissajous_team(
            robots=args.robots,
            steps=args.steps,
            objects=210 if args.objects is None else args.objects,
            seed=args.seed,
            noise_free=args.noise_free,
            **detector,
        )
    if args.object_ids != "global":
        from teamslam.datasets.identity import strip_object_ids

        dataset = strip_object_ids(dataset, to=args.object_ids, seed=args.seed)
    save_and_describe(dataset, args.out)
    return 0


def _cmd_data_info(args: argparse.Namespace) -> int:
    from teamslam.datasets import dataset_info, format_info, load_dataset

    info = dataset_info(load_dataset(args.dataset))
    print(json.dumps(info, indent=2) if args.json else format_info(info))
    return 0


def _cmd_data_import_reference(args: argparse.Namespace) -> int:
    from teamslam.datasets import import_reference

    dataset = import_reference(
        args.source,
        inverted_odometry=args.inverted_odometry,
        params=args.params,
        object_ids=args.object_ids,
        seed=args.seed,
    )
    path = save_and_describe(dataset, args.out)
    if dataset.sensor_model is not None:
        _check_params(dataset, path)
    return 0


def _cmd_strip_ids(args: argparse.Namespace) -> int:
    from teamslam.datasets import load_dataset
    from teamslam.datasets.identity import strip_object_ids

    dataset = strip_object_ids(load_dataset(args.dataset), to=args.to, seed=args.seed)
    save_and_describe(dataset, args.out)
    return 0


def _cmd_oracle_ids(args: argparse.Namespace) -> int:
    from teamslam.datasets import load_dataset
    from teamslam.datasets.identity import oracle_object_ids

    save_and_describe(oracle_object_ids(load_dataset(args.dataset)), args.out)
    return 0


def _check_params(dataset, path: Path) -> None:
    """Compare a params file's noise levels with a calibration from the data; warn on a gap."""
    from teamslam.msckf.calibration import params_check, params_warning

    print(f"\nsensor model from {dataset.sensor_model.note}")
    print(f"{'':<28}{'params file':>14}{'the data say':>14}")
    for label, given, found in params_check(dataset):
        print(f"{label:<28}{given:>14.4g}{found:>14.4g}")
        warning = params_warning(label, given, found, path)
        if warning is not None:
            print(f"warning: {warning}", file=sys.stderr)


def _cmd_import_bag(args: argparse.Namespace) -> int:
    from teamslam.ros2.bags import import_bag, parse_robot_spec

    dataset = import_bag(
        args.bag,
        [parse_robot_spec(s) for s in args.robot],
        observations=args.observations,
        camera=args.camera,
        tolerance=args.tolerance,
    )
    save_and_describe(dataset, args.out)
    return 0


def _cmd_export_bag(args: argparse.Namespace) -> int:
    from teamslam.datasets import load_dataset
    from teamslam.ros2.bags import export_bag

    summary = export_bag(load_dataset(args.dataset), args.out, camera=args.camera)
    print(f"wrote {summary['path']}: {summary['messages']} messages, {summary['bytes']} bytes")
    return 0


def _frontend(args: argparse.Namespace):
    """The front-end settings of ``--frontend-set``, printed with their sources."""
    from teamslam.frontend.config import frontend_table, resolve_frontend

    config, sources = resolve_frontend(args.frontend_set)
    print(frontend_table(config, sources))
    return config


_DETECTOR_FLAGS = {
    "detector_miss": "miss",
    "detector_clutter": "clutter",
    "detector_confusion": "confusion",
    "detector_noise": "box_noise",
}


def _cmd_simulate_images(args: argparse.Namespace) -> int:
    from teamslam.api import simulate_images
    from teamslam.errors import InputError
    from teamslam.sim.detector import DetectorConfig
    from teamslam.sim.render import render_size

    if args.route != "lissajous" or args.noise_free:
        raise InputError("--images renders a textured world: --route and --noise-free do not apply")
    if args.objects not in (None, "shapes"):
        raise InputError(f"--images takes --objects shapes (or none), not {args.objects}")
    detector_set = {v: getattr(args, k) for k, v in _DETECTOR_FLAGS.items()}
    detector_set = {k: v for k, v in detector_set.items() if v is not None}
    shapes = args.objects == "shapes"
    if detector_set and not shapes:
        raise InputError("--detector-* options need --objects shapes")
    if args.no_markers and not shapes:
        raise InputError("--no-markers leaves nothing to see: add --objects shapes")
    overrides = render_size(args.image_width)
    if shapes:
        overrides["objects"] = "shapes"
    if args.no_markers:
        overrides["markers_per_wall"] = 0
    team = simulate_images(
        args.out,
        robots=args.robots,
        steps=args.steps,
        seed=args.seed,
        bag=not args.no_bag,
        progress=not args.quiet,
        detector=DetectorConfig(**detector_set) if shapes else None,
        layout=args.layout,
        **overrides,
    )
    frames = team.config.steps + 1
    print(
        f"rendered {team.config.robots} robots × {frames} stereo frames "
        f"({team.config.image_size[0]}×{team.config.image_size[1]}, {args.layout}) to {args.out}"
    )
    print(f"  per robot: {args.out}/robot_k/{{left,right}}/, camera.yaml, timestamps.txt, ")
    print("  odometry.tum, groundtruth.tum; markers.txt (the marker map)")
    if shapes:
        print(
            f"  {len(team.room.shapes)} objects (objects.txt: id class x y z; classes.txt); "
            "per robot the simulated detector's boxes: detections/, detections_right/ "
            "(YOLO text) and their truth: detections_truth/, detections_right_truth/"
        )
    if not args.no_bag:
        print(f"  ROS 2 bag: {args.out}/images.mcap")
    print(f"next: teamslam data from-images --rendered {args.out} --out DATASET")
    return 0


def _cmd_simulate_any(args: argparse.Namespace) -> int:
    grid = args.route == "grid"
    args.robots = (4 if grid else 5) if args.robots is None else args.robots
    args.steps = (400 if grid else 300) if args.steps is None else args.steps
    if getattr(args, "images", False):
        return _cmd_simulate_images(args)
    return _cmd_simulate(args)


def _cmd_data_from_images(args: argparse.Namespace) -> int:
    from teamslam.datasets.images import dataset_from_images, rendered_team_inputs
    from teamslam.errors import InputError
    from teamslam.frontend._cv import require_cv2

    require_cv2()
    if args.rendered is not None:
        if args.folders or args.camera or args.timestamps or args.odometry or args.ground_truth:
            raise InputError("--rendered DIR takes every input from DIR: give no folders or files")
        if args.detections or args.right_detections or args.detection_truth:
            raise InputError(
                "--rendered DIR takes the detector's boxes from DIR (--markers-only: none)"
            )
        inputs = rendered_team_inputs(args.rendered, boxes=not args.markers_only)
        if args.robot:
            inputs["robot_names"] = args.robot
        if args.markers is not None:
            inputs["markers"] = args.markers
        if args.no_odometry:
            inputs["odometry"] = None
    else:
        if not args.folders or len(args.folders) % 2:
            raise InputError(
                f"give LEFT_DIR RIGHT_DIR per robot (got {len(args.folders)} folders), "
                "or --rendered DIR"
            )
        if args.camera is None:
            raise InputError("--camera FILE is needed (or --rendered DIR)")
        if args.no_odometry and args.odometry:
            raise InputError("--no-odometry and --odometry exclude each other")
        inputs = {
            "left_dirs": args.folders[0::2],
            "right_dirs": args.folders[1::2],
            "camera": args.camera,
            "timestamps": args.timestamps or None,
            "odometry": args.odometry or None,
            "ground_truth": args.ground_truth or None,
            "robot_names": args.robot or None,
            "markers": args.markers,
            "detections": args.detections or None,
            "right_detections": args.right_detections or None,
            "detection_truth": args.detection_truth or None,
            "coco_images": args.coco_images or None,
            "objects": args.objects,
        }
    config = _frontend(args)
    dataset = dataset_from_images(
        **inputs, descriptor=args.descriptor, config=config, progress=not args.quiet
    )
    _describe_images(dataset)
    save_and_describe(dataset, args.out)
    return 0


def _describe_images(dataset) -> None:
    from teamslam.frontend.boxes import MONOCULAR_REASONS

    for record in dataset.metadata["images"]["robots"]:
        print(
            f"{record['name']}: {record['stereo_observations_per_frame']:.0f} stereo "
            f"observations per frame, {100 * record['stereo_rejected_share']:.1f} % rejected by "
            f"the outlier gate; odometry: {record['odometry']}; truth: {record['ground_truth']}"
        )
        boxes = record.get("detections")
        if boxes:
            print(
                f"  boxes: {boxes['boxes_read']} read, {boxes['boxes_clipped']} clipped, "
                f"{boxes['boxes_dropped']} dropped (outside the image); in stereo "
                f"{boxes['right box']} by right boxes, {boxes['patch']} by their patch; "
                f"{boxes['monocular']} monocular ("
                + ", ".join(f"{k} {boxes[k]}" for k in MONOCULAR_REASONS if boxes.get(k))
                + f"); appearance: {boxes['appearance']}"
            )


def _cmd_import_bag_any(args: argparse.Namespace) -> int:
    from teamslam.errors import InputError

    if args.images is None:
        if args.detections is not None:
            raise InputError("--detections takes a topic of boxes in images: it needs --images")
        missing = [
            f
            for f, v in (("--observations", args.observations), ("--camera", args.camera))
            if v is None
        ]
        if missing:
            raise InputError(f"{' and '.join(missing)} needed (or --images for image topics)")
        return _cmd_import_bag(args)
    from teamslam.frontend._cv import require_cv2
    from teamslam.ros2.image_bags import dataset_from_bag, image_topics

    require_cv2()
    if args.observations is not None:
        raise InputError("--observations and --images exclude each other")
    if args.camera is None and args.camera_info is None:
        raise InputError("--images needs --camera FILE or --camera-info LEFT_TOPIC,RIGHT_TOPIC")
    robots = [
        image_topics(spec, args.images, args.camera_info, detections=args.detections)
        for spec in args.robot
    ]
    config = _frontend(args)
    dataset = dataset_from_bag(
        args.bag,
        robots,
        camera=args.camera,
        markers=args.markers,
        config=config,
        progress=not args.quiet,
    )
    _describe_images(dataset)
    save_and_describe(dataset, args.out)
    return 0


def _frontend_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--frontend-set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a front-end setting (teamslam.frontend.FrontendConfig), e.g. "
        "--frontend-set max_features=300 (repeatable); every setting is printed with its "
        "source (default or --frontend-set)",
    )
    parser.add_argument(
        "--markers",
        type=Path,
        default=None,
        help="marker map (id x y z per line): the objects' truth",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def _objects_arg(text: str):
    if text == "shapes":
        return text
    try:
        return non_negative_int(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(
            f"expected an integer ≥ 0 or shapes, got {text!r}"
        ) from None


def register(sub) -> None:
    """Add this group's commands to the ``teamslam`` subparsers."""
    sim = sub.add_parser(
        "simulate",
        help="simulate a stereo robot team (Lissajous arena, long route or grid city) and write "
        "a dataset",
        description="Simulate a team of stereo robots — flying 3D Lissajous curves through one "
        "arena, driving side by side along a long non-repeating route that keeps "
        "discovering new objects (--route long), or driving the streets of a grid city lined "
        "with regularly spaced objects (--route grid) — with objects, geometric feature tracks and "
        "noisy odometry, and write it in teamslam's dataset format.",
    )
    sim.add_argument(
        "--route",
        choices=("lissajous", "long", "grid"),
        default="lissajous",
        help="lissajous: curves through one arena (default); long: a long winding route "
        "through a world of about 1.2 objects per metre; grid: cars driving random routes "
        "through a grid of straight streets, objects every few metres along both kerbs "
        "(700 px camera, 1241×376)",
    )
    sim.add_argument(
        "--robots", type=positive_int, default=None, help="number of robots (default 5; grid: 4)"
    )
    sim.add_argument(
        "--steps",
        type=positive_int,
        default=None,
        help="motion steps per robot (default 300; grid: 400)",
    )
    sim.add_argument(
        "--blocks",
        type=positive_int,
        nargs=2,
        default=None,
        metavar=("NX", "NY"),
        help="grid route: blocks of the city (default 3 3)",
    )
    sim.add_argument(
        "--object-spacing",
        type=non_negative_float,
        default=None,
        metavar="M",
        help="grid route: metres between neighbouring objects along a kerb (default 8)",
    )
    sim.add_argument(
        "--objects",
        type=_objects_arg,
        default=None,
        help="objects in the Lissajous arena's map (default 210); with --images: shapes "
        "(textured objects of five classes and a simulated detector's boxes)",
    )
    sim.add_argument("--seed", type=non_negative_int, default=0, help="random seed")
    sim.add_argument("--noise-free", action="store_true", help="exact measurements and odometry")
    sim.add_argument(
        "--object-ids",
        choices=("global", "per-robot", "none"),
        default="global",
        help="global: an object has one id in every robot's data (default); per-robot: each "
        "robot numbers its own objects (which are the same kept as ground truth); none: "
        "per-frame detections without ids",
    )
    sim.add_argument(
        "--clutter",
        type=float,
        default=0.0,
        help="Lissajous and grid routes: false detections per frame, as a share of the true ones "
        "(uniform in the image, random disparity in the depth range)",
    )
    sim.add_argument(
        "--miss",
        type=float,
        default=0.0,
        help="Lissajous and grid routes: probability of a missed object",
    )
    sim.add_argument(
        "--classes",
        type=non_negative_int,
        default=0,
        help="Lissajous and grid routes: number of object classes (0: none)",
    )
    sim.add_argument(
        "--appearance",
        type=non_negative_int,
        default=0,
        metavar="DIM",
        help="Lissajous and grid routes: each detection carries an appearance descriptor of DIM "
        "dimensions, a noisy copy of its object's (0: none)",
    )
    sim.add_argument(
        "--appearance-noise",
        type=float,
        default=0.3,
        metavar="S",
        help="noise of each detection's descriptor, relative to the descriptor's unit norm",
    )
    sim.add_argument("--out", type=Path, required=True, help="dataset directory to write")
    sim.set_defaults(handler=_cmd_simulate)

    data = sub.add_parser("data", help="inspect and import team datasets")
    data_sub = data.add_subparsers(dest="data_command", metavar="ACTION", parser_class=Parser)
    data_sub.required = True
    info = data_sub.add_parser("info", help="summary of a dataset")
    info.add_argument("dataset", type=Path, help="dataset directory")
    info.add_argument("--json", action="store_true", help="print one JSON object")
    info.set_defaults(handler=_cmd_data_info)
    imp = data_sub.add_parser(
        "import-reference",
        help="convert the distributed-MSCKF paper's published data to teamslam's format",
    )
    imp.add_argument("source", type=Path, help="directory of the published files")
    imp.add_argument("out", type=Path, help="dataset directory to write")
    imp.add_argument(
        "--inverted-odometry",
        action="store_true",
        help="the source stores inverse relative poses (the published simulated teams)",
    )
    imp.add_argument(
        "--params",
        type=Path,
        default=None,
        help="the publisher's parameter file (params.yaml): its noise variances become the "
        "dataset's sensor model, checked against a calibration from the data",
    )
    imp.add_argument(
        "--object-ids",
        choices=("global", "per-robot"),
        default="global",
        help="global: the published team-wide instance ids (default); per-robot: each robot's "
        "objects renumbered on their own (the identity kept as ground truth)",
    )
    imp.add_argument(
        "--seed", type=non_negative_int, default=0, help="seed of the per-robot renumbering"
    )
    imp.set_defaults(handler=_cmd_data_import_reference)
    strip = data_sub.add_parser(
        "strip-ids",
        help="renumber each robot's objects on its own (ground-truth identity kept)",
        description="Write a copy of a global-id dataset in which every robot numbers its own "
        "objects, as a real team's trackers would; which per-robot ids are the same object is "
        "kept as ground truth (evaluation only, never read by a filter).",
    )
    strip.add_argument("dataset", type=Path, help="dataset directory (global object ids)")
    strip.add_argument("--out", type=Path, required=True, help="dataset directory to write")
    strip.add_argument(
        "--to",
        choices=("per-robot", "none"),
        default="per-robot",
        help="per-robot: each robot numbers its own objects; none: per-frame detections "
        "without ids, which each robot's tracker names (the identity kept as ground truth)",
    )
    strip.add_argument("--seed", type=non_negative_int, default=0, help="seed of the new ids")
    strip.set_defaults(handler=_cmd_strip_ids)
    oracle = data_sub.add_parser(
        "oracle-ids",
        help="give every detection its true object's id (the oracle to score tracking against)",
        description="Write a copy of a dataset of detections without ids in which every "
        "detection with a true object carries that object's team id (false boxes left out): "
        "the same run with an oracle's ids, beside which own tracking and association are "
        "scored.",
    )
    oracle.add_argument("dataset", type=Path, help="dataset directory (detections with truth)")
    oracle.add_argument("--out", type=Path, required=True, help="dataset directory to write")
    oracle.set_defaults(handler=_cmd_oracle_ids)
    bag = data_sub.add_parser(
        "import-bag",
        help="a team dataset from a rosbag2 bag or MCAP file",
        description="Odometry (nav_msgs/Odometry), optional ground truth "
        "(PoseStamped/Odometry) and stereo observations (teamslam_msgs/StereoObservations) "
        "per robot, associated by stamps.",
    )
    bag.add_argument("bag", type=Path, help="rosbag2 directory or .mcap/.db3 file")
    bag.add_argument(
        "--robot",
        action="append",
        required=True,
        metavar="NAME:ODOM_TOPIC[:GT_TOPIC]",
        help="one robot (repeat per robot, in team order)",
    )
    bag.add_argument(
        "--observations",
        default=None,
        metavar="TEMPLATE",
        help="observation topic, {name} replaced by the robot's NAME "
        "(e.g. /{name}/stereo_observations); needed unless --images",
    )
    bag.add_argument(
        "--camera",
        type=Path,
        default=None,
        help="stereo calibration (JSON or YAML); needed unless --images with --camera-info",
    )
    bag.add_argument(
        "--tolerance",
        type=float,
        default=None,
        help="largest stamp difference (s) between an observation and its odometry "
        "(default: half the smallest odometry period)",
    )
    bag.add_argument("--out", type=Path, required=True, help="dataset directory to write")
    bag.set_defaults(handler=_cmd_import_bag)
    exp = data_sub.add_parser("export-bag", help="a team dataset as a ROS 2 MCAP bag")
    exp.add_argument("dataset", type=Path, help="dataset directory (teamslam format)")
    exp.add_argument("--out", type=Path, required=True, help="MCAP file to write")
    exp.add_argument(
        "--camera", type=Path, default=None, help="also write the calibration file here"
    )
    exp.set_defaults(handler=_cmd_export_bag)

    # ---- images: simulate --images, data from-images, import-bag --images
    sim.description += (
        " With --images: render each robot's stereo images of a procedurally textured room "
        "with ArUco markers (image folders, a ROS 2 bag images.mcap, exact ground truth)."
    )
    sim.add_argument(
        "--images",
        action="store_true",
        help="render stereo images (folders + ROS 2 bag) instead of measurements; "
        "needs pip install teamslam[images]",
    )
    sim.add_argument(
        "--image-width",
        type=positive_int,
        default=None,
        help="with --images: image width in pixels (default 640; 4:3, same field of view)",
    )
    sim.add_argument("--no-bag", action="store_true", help="with --images: no images.mcap")
    sim.add_argument(
        "--layout",
        choices=("room", "street"),
        default="room",
        help="with --images: a room the robots circle in (default), or a street they drive "
        "round one after another",
    )
    sim.add_argument(
        "--no-markers", action="store_true", help="with --images: no ArUco markers on the walls"
    )
    for flag, what, kind in (
        ("miss", "probability of missing a visible object", rate),
        ("clutter", "mean false boxes per image", non_negative_float),
        ("confusion", "probability of a wrong class", rate),
        ("noise", "std of a box edge as a share of the box's size", non_negative_float),
    ):
        sim.add_argument(
            f"--detector-{flag}",
            type=kind,
            default=None,
            help=f"with --objects shapes: the simulated detector's {what}",
        )
    sim.add_argument("--quiet", action="store_true", help="with --images: no progress bars")
    sim.set_defaults(handler=_cmd_simulate_any)

    fi = data_sub.add_parser(
        "from-images",
        help="a team dataset from each robot's stereo image folders (the stereo front-end)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="""Run the stereo front-end (tracked corners, stereo matches, ArUco markers as
objects) over each robot's left and right image folders and write a team dataset.

One robot:
  teamslam data from-images L R --camera cam.yaml --timestamps t.txt \\
      --odometry odo.tum --ground-truth gt.tum --robot alpha --out ds

Several robots: give LEFT_DIR RIGHT_DIR per robot, in team order, and repeat each per-robot
option once per robot in the same order (all or none of the robots):
  teamslam data from-images a/left a/right b/left b/right c/left c/right \\
      --camera cam.yaml --timestamps a/t.txt --timestamps b/t.txt --timestamps c/t.txt \\
      --odometry a/odo.tum --odometry b/odo.tum --odometry c/odo.tum \\
      --robot a --robot b --robot c --out ds

A team written by `teamslam simulate --images --out DIR`:
  teamslam data from-images --rendered DIR --out ds

Without odometry the motion is stereo visual odometry (PnP + RANSAC), recorded in the
dataset's metadata; without ground truth the poses stored as truth are dead-reckoned.""",
    )
    fi.add_argument(
        "folders",
        nargs="*",
        type=Path,
        metavar="LEFT_DIR RIGHT_DIR",
        help="per robot its left and right image folders (paired by file name)",
    )
    fi.add_argument("--camera", type=Path, default=None, help="stereo camera file (YAML/JSON)")
    fi.add_argument(
        "--timestamps",
        action="append",
        type=Path,
        default=[],
        help="per robot a timestamps file (one stamp per line, s); repeat per robot",
    )
    fi.add_argument(
        "--odometry",
        action="append",
        type=Path,
        default=[],
        help="per robot an odometry TUM file (interpolated at the stamps); repeat per robot",
    )
    fi.add_argument(
        "--ground-truth",
        action="append",
        type=Path,
        default=[],
        help="per robot a ground-truth TUM file; repeat per robot",
    )
    fi.add_argument(
        "--robot",
        action="append",
        default=[],
        metavar="NAME",
        help="per robot a name (default robot_0, robot_1, …); repeat per robot",
    )
    fi.add_argument(
        "--rendered",
        type=Path,
        default=None,
        metavar="DIR",
        help="every robot's folders and files from a directory of `teamslam simulate --images`",
    )
    fi.add_argument(
        "--no-odometry",
        action="store_true",
        help="ignore the odometry files: stereo visual odometry instead",
    )
    fi.add_argument(
        "--detections",
        action="append",
        type=Path,
        default=[],
        metavar="DIR_OR_FILE",
        help="per robot a detector's boxes for its left images: a folder of YOLO .txt files "
        "or a COCO results .json; the objects are then these boxes, without ids (each robot "
        "tracks them); repeat per robot",
    )
    fi.add_argument(
        "--right-detections",
        action="append",
        type=Path,
        default=[],
        metavar="DIR_OR_FILE",
        help="per robot the detector's boxes for its right images, when it ran on them",
    )
    fi.add_argument(
        "--detection-truth",
        action="append",
        type=Path,
        default=[],
        metavar="DIR",
        help="per robot, for evaluation only: <stem>.txt files with the true object id of "
        "each left box (-1: false)",
    )
    fi.add_argument(
        "--coco-images",
        action="append",
        type=Path,
        default=[],
        metavar="FILE",
        help="per robot a COCO JSON with the images list (integer image_id -> file name)",
    )
    fi.add_argument(
        "--objects",
        type=Path,
        default=None,
        metavar="FILE",
        help="true object map for the boxes (id class x y z per line), for evaluation",
    )
    fi.add_argument(
        "--descriptor",
        default=None,
        metavar="KIND",
        help="appearance descriptor of boxes without an embedding: "
        "thumbnail, hog, intensity, hue-saturation, thumbnail+hue-saturation or "
        "hue-saturation-or-thumbnail (the default: colour images by their hue, grey ones by "
        "their thumbnail)",
    )
    fi.add_argument(
        "--markers-only",
        action="store_true",
        help="with --rendered: markers as objects, even where the render has detector boxes",
    )
    _frontend_arguments(fi)
    fi.add_argument("--out", type=Path, required=True, help="dataset directory to write")
    fi.set_defaults(handler=_cmd_data_from_images)

    bag.description += (
        " Or, with --images LEFT_TOPIC,RIGHT_TOPIC, stereo images (sensor_msgs/Image or "
        "CompressedImage) run through the stereo front-end; each --robot is then "
        "NAME[:ODOM_TOPIC[:GT_TOPIC]] (without odometry: stereo visual odometry), e.g. "
        "teamslam data import-bag DIR/images.mcap --images /{name}/left/image_raw,"
        "/{name}/right/image_raw --camera-info /{name}/left/camera_info,"
        "/{name}/right/camera_info --robot robot_0:/robot_0/odom:/robot_0/ground_truth "
        "--robot robot_1:/robot_1/odom:/robot_1/ground_truth --out DATASET."
    )
    bag.add_argument(
        "--images",
        default=None,
        metavar="LEFT_TOPIC,RIGHT_TOPIC",
        help="stereo image topics, {name} replaced by the robot's NAME",
    )
    bag.add_argument(
        "--camera-info",
        default=None,
        metavar="LEFT_TOPIC,RIGHT_TOPIC",
        help="with --images: sensor_msgs/CameraInfo topics ({name} replaced; the first "
        "robot's give the rig) in place of --camera",
    )
    bag.add_argument(
        "--detections",
        default=None,
        metavar="TOPIC",
        help="with --images: a vision_msgs/msg/Detection2DArray topic of boxes in the left "
        "images ({name} replaced), matched by stamp; the objects are then these boxes, "
        "without ids (each robot tracks them)",
    )
    _frontend_arguments(bag)
    bag.set_defaults(handler=_cmd_import_bag_any)
