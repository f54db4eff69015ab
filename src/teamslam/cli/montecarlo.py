"""``teamslam montecarlo``: NEES and RMSE of the 3D team filter over noise realisations."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from teamslam.cli._common import non_negative_int, positive_int

__all__ = ["register"]


def _names(text: str) -> tuple[str, ...]:
    return tuple(s.strip() for s in text.split(",") if s.strip())


def _cmd_montecarlo(args: argparse.Namespace) -> int:
    from teamslam.eval.team_montecarlo import MonteCarloSpec, table, write_montecarlo
    from teamslam.msckf.settings.sources import parse_assignments

    spec = MonteCarloSpec(
        robots=args.robots,
        steps=args.steps,
        runs=args.runs,
        filters=_names(args.filters),
        modes=_names(args.modes),
        objects_only=args.objects_only,
        seed=args.seed,
        window=args.window,
        settings=tuple(parse_assignments(args.set).items()),
        graph=args.graph,
        loss=args.loss,
        route=args.route,
    )
    summary, figures, store = write_montecarlo(
        spec, args.out, args.workers, scheduler=args.scheduler, resume=args.resume
    )
    if args.resume:
        print(
            f"resumed: {store.loaded} of {spec.runs} runs read back from {store.directory}, "
            f"{store.saved} run",
            file=sys.stderr,
        )
    if args.json:
        print(json.dumps(summary))
    else:
        print(table(summary))
        print(f"\nwrote {args.out / 'montecarlo.json'}, " + ", ".join(p.name for p in figures))
    return 0


def register(subparsers) -> None:
    """Add ``teamslam montecarlo``."""

    mc = subparsers.add_parser(
        "montecarlo",
        help="Monte Carlo NEES and RMSE of the 3D team filter: linearisation × team mode",
        description="Run N noise realisations of one simulated stereo team through every "
        "chosen linearisation (std, fej, ideal, oc) and team mode (separate, consensus, "
        "hybrid consensus, consensus on information increments, centralised); report the "
        "average NEES of the current pose and of the objects with the χ² band, RMSE of "
        "position and heading, and write montecarlo.json and figures.",
    )
    mc.add_argument("--robots", type=positive_int, default=5, help="team size")
    mc.add_argument("--steps", type=positive_int, default=200, help="motion steps per robot")
    mc.add_argument("--runs", type=positive_int, default=20, help="noise realisations")
    mc.add_argument("--filters", default="std,fej,ideal", help="comma-separated policies")
    mc.add_argument(
        "--modes",
        default="separate,consensus,centralised",
        help="comma-separated modes: separate, consensus, hybrid, increments, centralised",
    )
    mc.add_argument(
        "--graph",
        choices=("complete", "ring", "random"),
        default="complete",
        help="communication graph of the consensus modes (random: connected random geometric, "
        "drawn from --seed)",
    )
    mc.add_argument(
        "--loss",
        type=float,
        default=0.0,
        metavar="R",
        help="per-frame probability that a link is down (consensus modes)",
    )
    mc.add_argument(
        "--route",
        default="lissajous",
        help="lissajous: curves through one arena; long: side by side along a long route that "
        "never comes back (--steps metres; --seed draws the route, the same in every run)",
    )
    mc.add_argument("--objects-only", action="store_true", help="ignore geometric features")
    mc.add_argument("--seed", type=non_negative_int, default=0, help="seed of paths and map")
    mc.add_argument("--window", type=positive_int, default=10, help="MSCKF window size")
    mc.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="GROUP.NAME=VALUE",
        help="a filter setting for every run (repeatable; filter.linearization comes from "
        "--filters)",
    )
    mc.add_argument("--workers", type=positive_int, default=None, help="processes (all cores)")
    mc.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run each noise realisation as a task of the Dask scheduler at ADDRESS "
        "(tcp://host:8786; the 'cluster' extra) instead of --workers processes",
    )
    mc.add_argument(
        "--resume",
        action="store_true",
        help="keep the runs OUT/runs holds from an interrupted study of the same settings and "
        "run only the missing ones",
    )
    mc.add_argument("--json", action="store_true", help="print the summary as JSON")
    mc.add_argument("--out", type=Path, required=True, help="directory for JSON and figures")
    mc.set_defaults(handler=_cmd_montecarlo)
