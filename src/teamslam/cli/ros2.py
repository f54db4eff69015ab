"""``teamslam export mcap RESULT_DIR --out run.mcap``: a run as MCAP with ROS 2 schemas.

The other ROS 2 commands belong to their groups: ``teamslam data import-bag`` and
``export-bag`` (:mod:`teamslam.cli.data`), ``teamslam agent --ros2`` (:mod:`teamslam.cli.team`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from teamslam.cli._common import positive_int, print_mcap_summary

__all__ = ["register"]


def _cmd_export_mcap(args: argparse.Namespace) -> int:
    from teamslam import api

    print_mcap_summary(api.export(args.result_dir, args.out, path_messages=args.path_messages))
    return 0


def register(subparsers) -> None:
    """Add ``teamslam export`` to the ``teamslam`` subparsers."""
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
