"""The ``teamslam`` command, one module per command group.

Exit status: 0 on success; 2 when the input is wrong (a flag, a value out of range, a malformed
or inconsistent file — :class:`teamslam.errors.InputError`, or a file that cannot be read); 1
when the inputs were valid but the estimate could not be computed
(:class:`teamslam.errors.EstimationError`, naming robot and frame) or a robot process failed;
130 when interrupted.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from teamslam import __version__
from teamslam.cli import data, dvi, evaluate, fej, montecarlo, msckf, ros2, team
from teamslam.cli._common import Parser
from teamslam.errors import EXIT_FAILURE, EXIT_USAGE, EstimationError, InputError

__all__ = ["build_parser", "main"]

# ros2 last: it adds options to run, data and agent
GROUPS = (dvi, data, msckf, team, fej, montecarlo, evaluate, ros2)


def build_parser() -> argparse.ArgumentParser:
    """The full ``teamslam`` argument parser."""
    parser = Parser(
        prog="teamslam",
        description="Multi-robot SLAM by filtering: distributed inference, consistency measured.",
    )
    parser.add_argument("--version", action="version", version=f"teamslam {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for group in GROUPS:
        group.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``teamslam`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "handler", None) is None:
        parser.print_help()
        return EXIT_USAGE
    try:
        return int(args.handler(args))
    except (InputError, OSError) as exc:
        sys.stderr.write(f"teamslam {args.command}: error: {exc}\n")
        return EXIT_USAGE
    except EstimationError as exc:
        sys.stderr.write(f"teamslam {args.command}: failed: {exc}\n")
        return EXIT_FAILURE
    except KeyboardInterrupt:
        sys.stderr.write(f"teamslam {args.command}: interrupted\n")
        return 130
