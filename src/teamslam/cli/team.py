"""``teamslam agent`` (optionally publishing ROS 2 topics) and ``teamslam team``: robots as
processes."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import yaml

from teamslam.cli._common import Parser, number, print_run

__all__ = ["register"]


def _cmd_team_launch(args: argparse.Namespace) -> int:
    from teamslam import api

    run = api.launch(args.team_file, args.out, overwrite=args.overwrite)
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


def _cmd_agent(args: argparse.Namespace) -> int:
    from teamslam import api

    options = {
        "domain_id": args.domain_id,
        "connect": args.ros2_connect,
        "listen": args.ros2_listen,
        "period": args.period,
    }
    summary = api.run_robot(
        args.team, args.robot, args.out, args.resume, ros2=args.ros2, ros2_options=options
    )
    print(json.dumps({k: summary[k] for k in ("robot", "frames", "lost_neighbours")}))
    return 0


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
        type=number(int, lambda v: 0 <= v <= 232, "a ROS domain id in 0..232"),
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
