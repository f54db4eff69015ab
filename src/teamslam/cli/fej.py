"""``teamslam fej``: the planar multi-robot EKF (standard, first-estimate, ideal)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from teamslam.cli._common import Parser, default_data, non_negative_int, positive_int

__all__ = ["register"]


def _cmd_fej_table(args: argparse.Namespace) -> int:
    from teamslam import api
    from teamslam.ekf2d.experiments import format_table

    env = api.fej_environment(args.env, args.features, args.environment or (), args.layout)
    result = api.fej_table(
        env, args.runs, args.seed, args.workers, args.out, scheduler=args.scheduler
    )
    if args.json:
        print(json.dumps(result.table, indent=2))
    else:
        print(format_table(result))
        if args.out is not None:
            print(f"\nwrote {args.out}/table.json, nees_rmse.png, sigma_bounds.png")
    return 0


def _cmd_fej_victoria_park(args: argparse.Namespace) -> int:
    from teamslam import api

    summary = api.victoria_park(args.data, args.per_measurement_noise, args.out)
    print(api.victoria_park_table(summary))
    if args.out is not None:
        print(f"\nwrote {args.out}/metrics.json, victoria_park.png")
    return 0


def register(sub) -> None:
    """Add this group's commands to the ``teamslam`` subparsers."""
    fej = sub.add_parser("fej", help="planar multi-robot EKF: standard vs first-estimate vs ideal")
    fej_sub = fej.add_subparsers(dest="fej_command", metavar="ACTION", parser_class=Parser)
    fej_sub.required = True
    table = fej_sub.add_parser("table", help="Monte Carlo NEES/RMSE table (paper Tables 1–2)")
    table.add_argument("--env", type=int, choices=(1, 2), default=1, help="environment")
    table.add_argument("--features", type=int, choices=(20, 60, 100), default=20)
    table.add_argument(
        "--layout",
        type=non_negative_int,
        default=0,
        help="generated environment's layout: 0 is the tables' one, others draw the loops' "
        "shape and the features anew (same kind, same noise levels)",
    )
    table.add_argument("--runs", type=positive_int, default=100, help="Monte Carlo runs")
    table.add_argument("--seed", type=non_negative_int, default=0, help="base seed")
    table.add_argument(
        "--workers", type=positive_int, default=None, help="processes (default: all cores)"
    )
    table.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run each Monte Carlo run as a task of the Dask scheduler at ADDRESS "
        "(tcp://host:8786; the 'cluster' extra) instead of --workers processes",
    )
    table.add_argument(
        "--environment",
        nargs="+",
        metavar="FILE",
        default=None,
        help="environment files instead of the generated one: one teamslam JSON file, or the "
        "published MATLAB pair (waypoints file and features file; variables are merged)",
    )
    table.add_argument("--json", action="store_true", help="print one JSON object")
    table.add_argument(
        "--out", type=Path, default=None, help="directory for table.json and figures"
    )
    table.set_defaults(handler=_cmd_fej_table)
    vp = fej_sub.add_parser("victoria-park", help="two-robot split of Victoria Park (paper Fig. 6)")
    vp.add_argument(
        "--data",
        type=Path,
        default=default_data() / "victoria-park",
        help="directory of the Victoria Park files",
    )
    vp.add_argument(
        "--per-measurement-noise",
        action="store_true",
        help="use each measurement's own covariance instead of each robot's mean",
    )
    vp.add_argument("--out", type=Path, default=None, help="directory for metrics and figure")
    vp.set_defaults(handler=_cmd_fej_victoria_park)
