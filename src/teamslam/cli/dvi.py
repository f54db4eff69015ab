"""``teamslam dvi-demo``: the linear-Gaussian distributed Kalman filter."""

from __future__ import annotations

import argparse
from pathlib import Path

from teamslam.cli._common import UsageError, non_negative_int, positive_int, rate
from teamslam.eval.outputs import write_json

__all__ = ["register"]


def _cmd_dvi_demo(args: argparse.Namespace) -> int:
    from teamslam.dvi.demo import run_demo

    if args.agents < 2:
        raise UsageError("--agents must be at least 2 for a team")
    result = run_demo(
        agents=args.agents, graph=args.graph, loss=args.loss, steps=args.steps, seed=args.seed
    )
    print(result.table())
    if args.out is not None:
        path = Path(args.out) / "metrics.json"
        write_json(path, result.metrics())
        print(f"\nwrote {path}")
    return 0


def register(sub) -> None:
    """Add this group's commands to the ``teamslam`` subparsers."""
    from teamslam.graph import GRAPH_KINDS

    demo = sub.add_parser(
        "dvi-demo",
        help="distributed vs centralised Kalman filter on a linear-Gaussian team problem",
        description="Run the distributed Kalman filter (consensus averaging, predict, update) "
        "on a generated linear-Gaussian tracking problem and compare it with the centralised "
        "Kalman filter and with separate filters on the same data.",
    )
    demo.add_argument("--agents", type=positive_int, default=5, help="number of agents (≥ 2)")
    demo.add_argument("--graph", choices=GRAPH_KINDS, default="ring", help="communication graph")
    demo.add_argument("--loss", type=rate, default=0.0, help="per-step edge loss rate r")
    demo.add_argument("--steps", type=positive_int, default=60, help="number of time steps")
    demo.add_argument("--seed", type=non_negative_int, default=0, help="random seed")
    demo.add_argument("--out", type=Path, default=None, help="directory for metrics.json")
    demo.set_defaults(handler=_cmd_dvi_demo)
