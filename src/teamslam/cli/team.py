"""``teamslam agent`` and ``teamslam team``: robots as processes."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

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


def _cmd_agent(args: argparse.Namespace) -> int:
    from teamslam.runtime.agent_process import run_agent
    from teamslam.runtime.team_file import load_team_file

    team = load_team_file(args.team)
    if not 0 <= args.robot < team.n:
        raise UsageError(f"--robot must lie in 0..{team.n - 1}")
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
