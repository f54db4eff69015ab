"""``teamslam export mcap RESULT_DIR --out run.mcap``: a run as MCAP with ROS 2 schemas;
``teamslam bag play BAG``: a bag's topics published live in rmw_zenoh's layout.

The other ROS 2 commands belong to their groups: ``teamslam data import-bag`` and
``export-bag`` (:mod:`teamslam.cli.data`), ``teamslam agent --ros2`` (:mod:`teamslam.cli.team`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from teamslam.cli._common import (
    ctrl_c_interrupts,
    non_negative_float,
    non_negative_int,
    positive_float,
    positive_int,
    print_mcap_summary,
    ros_domain_id,
)

__all__ = ["register"]


def _cmd_export_mcap(args: argparse.Namespace) -> int:
    from teamslam import api

    print_mcap_summary(api.export(args.result_dir, args.out, path_messages=args.path_messages))
    return 0


def _cmd_bag_play(args: argparse.Namespace) -> int:
    import sys

    from teamslam.cli import EXIT_INTERRUPTED
    from teamslam.ros2.bag_play import play_bag

    rate = 0.0 if args.as_fast_as_possible else args.rate

    def started(result) -> None:
        what = "as fast as possible" if rate == 0 else f"at rate {rate:g}"
        print(f"playing {len(result.keys)} topic(s) of {args.bag} {what}, domain {args.domain_id}")
        if args.wait_subscribers:
            print(f"waiting for {args.wait_subscribers} subscribing node(s)")
        sys.stdout.flush()

    with ctrl_c_interrupts():  # --loop ends on Ctrl-C only, even started with it ignored
        result = play_bag(
            args.bag,
            rate=rate,
            topics=args.topics,
            loop=args.loop,
            domain_id=args.domain_id,
            start_delay=args.start_delay,
            wait_subscribers=args.wait_subscribers,
            wait_timeout=args.wait_timeout,
            connect=args.connect,
            listen=args.listen,
            on_start=started,
        )
    for topic, count in result.counts.items():
        print(f"  {topic}: {count} message(s)")
    total = sum(result.counts.values())
    if result.stopped:
        print(f"stopped after {total} message(s)")
        return EXIT_INTERRUPTED
    print(f"published {total} message(s) in {result.passes} pass(es)")
    return 0


def register(subparsers) -> None:
    """Add ``teamslam export`` and ``teamslam bag`` to the ``teamslam`` subparsers."""
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

    bag = subparsers.add_parser("bag", help="ROS 2 bags played live (rmw_zenoh)")
    bag_sub = bag.add_subparsers(dest="bag_command", metavar="ACTION")
    bag_sub.required = True
    play = bag_sub.add_parser(
        "play",
        help="publish a bag's topics live in rmw_zenoh's layout with their recorded timing",
        description="Publish a ROS 2 bag's messages (rosbag2 sqlite3 or MCAP) as rmw_zenoh "
        "does, without a ROS 2 installation: each recorded CDR payload forwarded as is, with "
        "rmw_zenoh's attachment and liveliness tokens, at its recorded time scaled by --rate. "
        "Ctrl-C stops.",
    )
    play.add_argument("bag", type=Path, help="rosbag2 directory, .mcap or .db3 file")
    speed = play.add_mutually_exclusive_group()
    speed.add_argument(
        "--rate",
        type=non_negative_float,
        default=1.0,
        help="speed factor of the recorded timing (default 1; 0: as fast as possible)",
    )
    speed.add_argument(
        "--as-fast-as-possible", action="store_true", help="no waiting between messages"
    )
    play.add_argument(
        "--topics", nargs="+", default=None, metavar="TOPIC", help="only these topics"
    )
    play.add_argument("--loop", action="store_true", help="play again from the start, until Ctrl-C")
    play.add_argument(
        "--domain-id",
        type=ros_domain_id,
        default=0,
        help="ROS_DOMAIN_ID (default 0)",
    )
    play.add_argument(
        "--start-delay",
        type=non_negative_float,
        default=0.0,
        metavar="S",
        help="seconds to wait before the first message (after --wait-subscribers)",
    )
    play.add_argument(
        "--wait-subscribers",
        type=non_negative_int,
        default=0,
        metavar="N",
        help="first wait until N nodes subscribe to the bag's topics (liveliness tokens)",
    )
    play.add_argument(
        "--wait-timeout",
        type=positive_float,
        default=None,
        metavar="S",
        help="give up waiting for subscribers after S seconds (exit 2; default: wait)",
    )
    play.add_argument(
        "--connect",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="Zenoh router to connect to (default tcp/localhost:7447, rmw_zenohd's)",
    )
    play.add_argument(
        "--listen",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help="endpoint the session listens on (default tcp/localhost:0)",
    )
    play.set_defaults(handler=_cmd_bag_play)
