"""``teamslam agent`` and ``teamslam team``: robots as processes."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import yaml

from teamslam.cli._common import Parser, UsageError, print_health
from teamslam.eval.outputs import write_team_outputs
from teamslam.eval.tables import team_table

__all__ = ["launch_and_report", "register"]


def launch_and_report(team_path: Path, out: Path, effective=None) -> int:
    from teamslam.datasets import load_dataset
    from teamslam.eval.metrics import team_metrics
    from teamslam.runtime.launch import exit_summary, gather, launch_team
    from teamslam.runtime.team_file import load_team_file

    team = load_team_file(team_path)
    codes = launch_team(team, team_path, out)
    finished = [r for r, c in sorted(codes.items()) if c == 0]
    if len(finished) < team.n:
        sys.stderr.write(f"teamslam team: {exit_summary(codes)} (see {out}/robot_N.log)\n")
    if not finished:
        return 1
    if team.dataset is None or any(r.dataset for r in team.robots):
        print("robots ran on their own datasets; per-robot results are in", out)
        return 0 if len(finished) == team.n else 1
    dataset = load_dataset(team.dataset)
    result = gather(team, out, finished)
    if len(finished) < team.n:
        print(f"robots {', '.join(str(r) for r in finished)} finished; metrics cover them only")
        dataset = dataset.subset(finished)
    metrics = {"consensus": team_metrics(dataset, result)}
    for summary in result.extra["per_robot"]:
        if summary["lost_neighbours"]:
            print(f"robot {summary['robot']} lost neighbour(s) {summary['lost_neighbours']}")
    metrics["consensus"]["transport"] = result.extra["per_robot"]
    if effective is not None:
        metrics["consensus"].update(effective.to_json())
    print(team_table(metrics))
    if "nis" in metrics["consensus"]:
        print_health("consensus", metrics["consensus"])
    write_team_outputs(out, dataset, {"consensus": result}, metrics)
    return 0 if len(finished) == team.n else 1


def _cmd_team_launch(args: argparse.Namespace) -> int:
    return launch_and_report(Path(args.team_file), Path(args.out))


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
    from teamslam.runtime.agent_process import run_agent
    from teamslam.runtime.team_file import load_team_file

    team = load_team_file(args.team)
    if not 0 <= args.robot < team.n:
        raise UsageError(f"--robot must lie in 0..{team.n - 1}")
    if team.security is not None:
        from teamslam.runtime.security import check_credentials

        check_credentials(team.security, args.robot)  # one line naming a missing/unreadable key
    summary = run_agent(team, args.robot, Path(args.out), resume=args.resume)
    print(json.dumps({k: summary[k] for k in ("robot", "frames", "lost_neighbours")}))
    return 0


def register(sub) -> None:
    """Add this group's commands to the ``teamslam`` subparsers."""
    agent = sub.add_parser("agent", help="one robot's filter as a process (Zenoh)")
    agent.add_argument("--team", type=Path, required=True, help="team file (team.yaml)")
    agent.add_argument("--robot", type=int, required=True, help="robot id in the team file")
    agent.add_argument("--out", type=Path, default=Path("results/team"), help="output directory")
    agent.add_argument("--resume", action="store_true", help="continue from the last checkpoint")
    agent.set_defaults(handler=_cmd_agent)

    team_cmd = sub.add_parser("team", help="run a team of robot processes")
    team_sub = team_cmd.add_subparsers(dest="team_command", metavar="ACTION", parser_class=Parser)
    team_sub.required = True
    launch = team_sub.add_parser("launch", help="start one process per robot and gather results")
    launch.add_argument("team_file", type=Path, help="team file (team.yaml)")
    launch.add_argument("--out", type=Path, required=True, help="output directory")
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
