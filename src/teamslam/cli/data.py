"""``teamslam simulate`` and ``teamslam data``: make, inspect and import team datasets."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from teamslam.cli._common import Parser, non_negative_int, positive_int, save_and_describe

__all__ = ["register"]


def _cmd_simulate(args: argparse.Namespace) -> int:
    from teamslam.errors import InputError
    from teamslam.sim import lissajous_team, long_route_team

    if args.route == "long":
        if args.objects is not None:
            raise InputError(
                "--objects sets the Lissajous arena's map; the long route scatters objects "
                "along its length (about 1.2 per metre)"
            )
        dataset = long_route_team(
            robots=args.robots, steps=args.steps, seed=args.seed, noise_free=args.noise_free
        )
    else:
        dataset = lissajous_team(
            robots=args.robots,
            steps=args.steps,
            objects=210 if args.objects is None else args.objects,
            seed=args.seed,
            noise_free=args.noise_free,
        )
    if args.object_ids == "per-robot":
        from teamslam.datasets.identity import strip_object_ids

        dataset = strip_object_ids(dataset, seed=args.seed)
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


def register(sub) -> None:
    """Add this group's commands to the ``teamslam`` subparsers."""
    sim = sub.add_parser(
        "simulate",
        help="simulate a stereo robot team (Lissajous arena or long route) and write a dataset",
        description="Simulate a team of stereo robots — flying 3D Lissajous curves through one "
        "arena, or driving side by side along a long non-repeating route that keeps "
        "discovering new objects (--route long) — with objects, geometric feature tracks and "
        "noisy odometry, and write it in teamslam's dataset format.",
    )
    sim.add_argument(
        "--route",
        choices=("lissajous", "long"),
        default="lissajous",
        help="lissajous: curves through one arena (default); long: a long winding route "
        "through a world of about 1.2 objects per metre",
    )
    sim.add_argument("--robots", type=positive_int, default=5, help="number of robots")
    sim.add_argument("--steps", type=positive_int, default=300, help="motion steps per robot")
    sim.add_argument(
        "--objects",
        type=non_negative_int,
        default=None,
        help="objects in the Lissajous arena's map (default 210)",
    )
    sim.add_argument("--seed", type=non_negative_int, default=0, help="random seed")
    sim.add_argument("--noise-free", action="store_true", help="exact measurements and odometry")
    sim.add_argument(
        "--object-ids",
        choices=("global", "per-robot"),
        default="global",
        help="global: an object has one id in every robot's data (default); per-robot: each "
        "robot numbers its own objects (which are the same kept as ground truth)",
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
    strip.add_argument("--to", choices=("per-robot",), default="per-robot", help="the new id scope")
    strip.add_argument("--seed", type=non_negative_int, default=0, help="seed of the new ids")
    strip.set_defaults(handler=_cmd_strip_ids)
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
        required=True,
        metavar="TEMPLATE",
        help="observation topic, {name} replaced by the robot's NAME "
        "(e.g. /{name}/stereo_observations)",
    )
    bag.add_argument("--camera", type=Path, required=True, help="stereo calibration (JSON or YAML)")
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
