"""``teamslam agent`` (optionally publishing ROS 2 topics) and ``teamslam team``: robots as
processes."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import yaml

from teamslam.cli._common import (
    Parser,
    ctrl_c_interrupts,
    non_negative_float,
    positive_float,
    positive_int,
    print_run,
    ros_domain_id,
)
from teamslam.errors import InputError

__all__ = ["register"]


def _cmd_team_launch(args: argparse.Namespace) -> int:
    import sys

    from teamslam import api

    if args.foxglove is not None and args.foxglove[1]:
        from teamslam.runtime.team_file import load_team_file

        robots = [r.id for r in load_team_file(args.team_file).robots]
        for robot, where in api.foxglove_ports(robots, *args.foxglove).items():
            print(f"robot {robot}: Foxglove view at ws://{where}")
        sys.stdout.flush()
    with ctrl_c_interrupts():  # Ctrl-C stops the robots, even started with it ignored
        run = api.launch(args.team_file, args.out, overwrite=args.overwrite, foxglove=args.foxglove)
    print_run(run, args.out)
    return run.exit_status


def _cmd_team_certs(args: argparse.Namespace) -> int:
    from teamslam.runtime.security import certify_team_file

    security, data = certify_team_file(
        Path(args.team_file), Path(args.out), args.days, update=not args.no_update
    )
    print(f"team CA: {security.ca_certificate} (keep {Path(args.out) / 'ca.key'} off the robots)")
    for robot, creds in sorted(security.robots.items()):
        name = data["robots"][robot].get("name", f"robot-{robot}")
        print(f"robot {robot} '{name}': {creds.key} (0600), {creds.certificate}")
    if args.no_update:
        print("\nadd to the team file (and make every endpoint tls/):")
        print(yaml.safe_dump({"security": data["security"]}, sort_keys=False), end="")
    else:
        print(f"updated {args.team_file} (security section, tls/ endpoints; was saved as .bak)")
    return 0


LIVE_FLAGS = {
    "odometry": "odometry",
    "observations": "observations",
    "left": "left",
    "right": "right",
    "camera_info": "camera_info",
    "camera": "camera",
    "sync_tolerance": "sync_tolerance_s",
    "queue": "queue",
    "camera_timeout": "camera_timeout_s",
    "detections": "detections",
}


def _cmd_agent(args: argparse.Namespace) -> int:
    from teamslam import api

    live_given = [
        f for f in (*LIVE_FLAGS, "frames", "realtime_budget") if getattr(args, f) is not None
    ]
    if live_given and not args.live:
        raise InputError(f"--{live_given[0].replace('_', '-')} needs --live")
    options = {
        "domain_id": args.domain_id,
        "connect": args.ros2_connect,
        "listen": args.ros2_listen,
        "period": args.period,
    }
    live = None
    if args.live:
        live = {
            "flags": {key: getattr(args, flag) for flag, key in LIVE_FLAGS.items()},
            "frames": args.frames,
            "idle_timeout_s": args.idle_timeout,
            "budget_ms": args.realtime_budget,
        }
        if args.compressed:
            live["flags"]["compressed"] = True
    with ctrl_c_interrupts():  # a live robot runs until Ctrl-C, even started with it ignored
        summary = api.run_robot(
            args.team,
            args.robot,
            args.out,
            args.resume,
            ros2=args.ros2,
            ros2_options=options,
            live=live,
            foxglove=args.foxglove,
        )
    keys = ("robot", "frames", "lost_neighbours")
    shown = {k: summary[k] for k in keys}
    if "live" in summary:
        shown["latency_ms"] = summary["live"]["latency_ms"]
        shown["dropped"] = summary["live"]["dropped"]
    print(json.dumps(shown))
    return 0


def foxglove_address(text: str) -> tuple[str, int]:
    """An argparse type: ``[HOST:]PORT`` as ``(host, port)``, host loopback by default."""
    from teamslam.viz.foxglove import parse_address

    try:
        return parse_address(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def register(sub) -> None:
    """Add this group's commands to the ``teamslam`` subparsers."""
    agent = sub.add_parser("agent", help="one robot's filter as a process (Zenoh)")
    agent.add_argument("--team", type=Path, required=True, help="team file (team.yaml)")
    agent.add_argument("--robot", type=int, required=True, help="robot id in the team file")
    agent.add_argument("--out", type=Path, default=Path("results/team"), help="output directory")
    agent.add_argument("--resume", action="store_true", help="continue from the last checkpoint")
    agent.add_argument(
        "--ros2",
        action="store_true",
        help="publish pose, path and objects as ROS 2 topics over rmw_zenoh (also on when "
        "the team file has a ros2 section)",
    )
    agent.add_argument(
        "--domain-id",
        type=ros_domain_id,
        default=None,
        help="ROS_DOMAIN_ID (default: the team file's ros2.domain_id, else 0)",
    )
    agent.add_argument(
        "--period",
        type=float,
        default=None,
        help="seconds between frames, for stamps when the dataset has no timestamps (default 1)",
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
    agent.add_argument(
        "--foxglove",
        type=foxglove_address,
        metavar="[HOST:]PORT",
        help="serve the robot's estimates over the Foxglove WebSocket protocol there while it "
        "runs (host default 127.0.0.1; the foxglove extra): pose, path, map, /tf; live, also "
        "the left image with the boxes and tracked ids, and the latency",
    )
    live = agent.add_argument_group(
        "live inputs",
        "--live: frames from ROS 2 topics (rmw_zenoh layout) instead of the dataset; the "
        "topics come from the team file's ros2.inputs section, these flags override it "
        "({id} and {name} in a topic are the robot's id and name)",
    )
    live.add_argument("--live", action="store_true", help="run on live topics")
    live.add_argument("--odometry", help="nav_msgs/Odometry topic (every message kept)")
    live.add_argument(
        "--observations", help="teamslam_msgs/StereoObservations topic (no image front-end)"
    )
    live.add_argument("--left", help="left image topic (sensor_msgs/Image)")
    live.add_argument("--right", help="right image topic")
    live.add_argument(
        "--compressed", action="store_true", help="the image topics are CompressedImage"
    )
    live.add_argument("--camera-info", help="LEFT,RIGHT sensor_msgs/CameraInfo topics (the rig)")
    live.add_argument(
        "--camera",
        type=Path,
        help="camera file: the rig of images (instead of camera_info), or the calibration of "
        "observations",
    )
    live.add_argument(
        "--detections",
        help="with images: vision_msgs/Detection2DArray topic of a detector's boxes in the left "
        "images (the robot tracks the objects it detects)",
    )
    live.add_argument(
        "--sync-tolerance",
        type=non_negative_float,
        help="largest stamp difference of a left and right image paired (default 0.005 s)",
    )
    live.add_argument(
        "--queue",
        type=positive_int,
        help="frames waiting at most; when full the oldest is dropped (default 8)",
    )
    live.add_argument(
        "--camera-timeout",
        type=positive_float,
        help="odometry seconds without camera input after which the robot runs on "
        "odometry alone (default 1)",
    )
    live.add_argument(
        "--frames",
        type=positive_int,
        help="stop after this many frames",
    )
    live.add_argument(
        "--idle-timeout",
        type=positive_float,
        default=5.0,
        help="end when no message came for this long and no publisher of the topics is left "
        "(default 5 s)",
    )
    live.add_argument(
        "--realtime-budget",
        type=positive_float,
        help="per-stage budget; the first overrun of each stage is said",
    )
    agent.set_defaults(handler=_cmd_agent)

    team_cmd = sub.add_parser("team", help="run a team of robot processes")
    team_sub = team_cmd.add_subparsers(dest="team_command", metavar="ACTION", parser_class=Parser)
    team_sub.required = True
    launch = team_sub.add_parser("launch", help="start one process per robot and gather results")
    launch.add_argument("team_file", type=Path, help="team file (team.yaml)")
    launch.add_argument("--out", type=Path, required=True, help="output directory")
    launch.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an earlier run in --out (entirely); without it one is refused",
    )
    launch.add_argument(
        "--foxglove",
        type=foxglove_address,
        metavar="[HOST:]BASEPORT",
        help="each robot serves its estimates over the Foxglove WebSocket protocol while it "
        "runs, robot i on BASEPORT+i (host default 127.0.0.1; 0: a free port each, in its log; "
        "the foxglove extra)",
    )
    launch.set_defaults(handler=_cmd_team_launch)

    certs = team_sub.add_parser(
        "certs",
        help="make a team CA and each robot's key and certificate; secure the team file",
        description="Make a certificate authority for the team and, per robot, a private key "
        "(mode 0600) and a certificate whose common name is the robot's name and whose "
        "subjectAltName is the host of its endpoint. The team file gains a 'security' section "
        "and tls/ endpoints (the previous file is kept as FILE.bak). A CA already in --out is "
        "reused.",
    )
    certs.add_argument("team_file", type=Path, help="team file (team.yaml)")
    certs.add_argument("--out", type=Path, required=True, help="directory for keys and certs")
    certs.add_argument("--days", type=int, default=365, help="validity of the certificates")
    certs.add_argument(
        "--no-update",
        action="store_true",
        help="leave the team file alone and print the security section to add",
    )
    certs.set_defaults(handler=_cmd_team_certs)
