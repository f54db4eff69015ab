"""The ROS 2 commands of ``teamslam``, added to the parser by :func:`register`.

* ``teamslam export mcap RESULT_DIR --out run.mcap``
* ``teamslam data import-bag BAG --robot NAME:ODOM_TOPIC[:GT_TOPIC] ... --observations TEMPLATE
  --camera FILE --out DIR``
* ``teamslam data export-bag DATASET --out team.mcap``
* ``teamslam agent ... --ros2 [--domain-id N]``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from teamslam.cli._common import number, positive_int, save_and_describe

_domain_id = number(int, lambda v: 0 <= v <= 232, "a ROS domain id in 0..232")

__all__ = ["print_mcap_summary", "register"]


def _subparsers_of(parser: argparse.ArgumentParser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action
    raise RuntimeError(f"{parser.prog} has no sub-commands")


def print_mcap_summary(summary: dict) -> None:
    """One line: what an MCAP export wrote."""
    print(
        f"wrote {summary['path']}: {summary['messages']} messages on {len(summary['topics'])} "
        f"topics, {summary['bytes'] / 1e6:.2f} MB in {summary['seconds']:.2f} s"
    )


def _cmd_export_mcap(args: argparse.Namespace) -> int:
    from teamslam.ros2.mcap_export import export_mcap

    print_mcap_summary(export_mcap(args.result_dir, args.out, path_messages=args.path_messages))
    return 0


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


def _wrap_agent(original):
    def handler(args: argparse.Namespace) -> int:
        from teamslam.runtime.team_file import load_team_file

        team = load_team_file(args.team)
        if not (args.ros2 or team.ros2 is not None):
            return original(args)
        from teamslam.datasets import load_dataset
        from teamslam.errors import InputError
        from teamslam.eval.estimates import stamps_ns
        from teamslam.ros2.rmw_zenoh import Ros2Publisher, ros2_settings
        from teamslam.runtime.agent_process import run_agent

        if not 0 <= args.robot < team.n:
            raise InputError(f"--robot must lie in 0..{team.n - 1}")
        settings = ros2_settings(
            team.ros2,
            domain_id=args.domain_id,
            connect=args.ros2_connect,
            listen=args.ros2_listen,
            period=args.period,
        )
        dataset_path, index = team.dataset_of(args.robot)
        sequence = load_dataset(dataset_path).robots[index]
        publisher = Ros2Publisher(
            robot=args.robot,
            stamps_ns=stamps_ns(sequence.timestamps, sequence.frames, settings["period"]),
            domain_id=settings["domain_id"],
            connect=settings["connect"],
            listen=settings["listen"],
            path_every=settings["path_every"],
            objects_every=settings["objects_every"],
            wait_s=settings["wait_s"],
        )
        try:
            summary = run_agent(
                team, args.robot, Path(args.out), resume=args.resume, publisher=publisher
            )
        finally:
            publisher.close()
        print(json.dumps({k: summary[k] for k in ("robot", "frames", "lost_neighbours")}))
        return 0

    return handler


def register(subparsers) -> None:
    """Add the ROS 2 commands and flags to ``teamslam``'s sub-command parsers."""
    export = subparsers.add_parser("export", help="export results to other tools' formats")
    export_sub = export.add_subparsers(dest="export_command", metavar="FORMAT")
    export_sub.required = True
    mcap = export_sub.add_parser(
        "mcap",
        help="a run as MCAP with ROS 2 schemas (Foxglove, RViz, rosbag2)",
        description="Write a run's estimates (poses, paths, object maps with 3σ ellipsoids, "
        "ground truth, /tf) as one MCAP file with standard ROS 2 message schemas.",
    )
    mcap.add_argument("result_dir", type=Path, help="directory written by `teamslam run --out`")
    mcap.add_argument("--out", type=Path, required=True, help="MCAP file to write")
    mcap.add_argument(
        "--path-messages",
        type=positive_int,
        default=100,
        help="at most this many nav_msgs/Path messages per robot (default 100)",
    )
    mcap.set_defaults(handler=_cmd_export_mcap)

    data = subparsers.choices.get("data")
    if data is not None:
        data_sub = _subparsers_of(data)
        imp = data_sub.add_parser(
            "import-bag",
            help="a team dataset from a rosbag2 bag or MCAP file",
            description="Odometry (nav_msgs/Odometry), optional ground truth "
            "(PoseStamped/Odometry) and stereo observations (teamslam_msgs/StereoObservations) "
            "per robot, associated by stamps.",
        )
        imp.add_argument("bag", type=Path, help="rosbag2 directory or .mcap/.db3 file")
        imp.add_argument(
            "--robot",
            action="append",
            required=True,
            metavar="NAME:ODOM_TOPIC[:GT_TOPIC]",
            help="one robot (repeat per robot, in team order)",
        )
        imp.add_argument(
            "--observations",
            required=True,
            metavar="TEMPLATE",
            help="observation topic, {name} replaced by the robot's NAME "
            "(e.g. /{name}/stereo_observations)",
        )
        imp.add_argument(
            "--camera", type=Path, required=True, help="stereo calibration (JSON or YAML)"
        )
        imp.add_argument(
            "--tolerance",
            type=float,
            default=None,
            help="largest stamp difference (s) between an observation and its odometry "
            "(default: half the smallest odometry period)",
        )
        imp.add_argument("--out", type=Path, required=True, help="dataset directory to write")
        imp.set_defaults(handler=_cmd_import_bag)
        exp = data_sub.add_parser("export-bag", help="a team dataset as a ROS 2 MCAP bag")
        exp.add_argument("dataset", type=Path, help="dataset directory (teamslam format)")
        exp.add_argument("--out", type=Path, required=True, help="MCAP file to write")
        exp.add_argument(
            "--camera", type=Path, default=None, help="also write the calibration file here"
        )
        exp.set_defaults(handler=_cmd_export_bag)

    agent = subparsers.choices.get("agent")
    if agent is not None:
        agent.add_argument(
            "--ros2",
            action="store_true",
            help="publish pose, path and objects as ROS 2 topics over rmw_zenoh (also on when "
            "the team file has a ros2 section)",
        )
        agent.add_argument(
            "--domain-id",
            type=_domain_id,
            default=None,
            help="ROS_DOMAIN_ID (default: the team file's ros2.domain_id, else 0)",
        )
        agent.add_argument(
            "--period",
            type=float,
            default=None,
            help="seconds between frames, for stamps when the dataset has no timestamps "
            "(default 1)",
        )
        agent.add_argument(
            "--ros2-connect",
            action="append",
            default=None,
            metavar="ENDPOINT",
            help="Zenoh router to connect to (default tcp/localhost:7447, rmw_zenohd's)",
        )
        agent.add_argument(
            "--ros2-listen",
            action="append",
            default=None,
            metavar="ENDPOINT",
            help="endpoint the ROS 2 session listens on (default tcp/localhost:0)",
        )
        agent.set_defaults(handler=_wrap_agent(agent.get_default("handler")))
