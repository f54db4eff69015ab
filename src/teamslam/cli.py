"""The ``teamslam`` command.

Usage errors (a wrong flag, a value out of range) print one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from teamslam import __version__

__all__ = ["main"]


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


class UsageError(Exception):
    """A command-line value that parses but cannot be used."""


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _rate(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}") from None
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {value}")
    return value


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer ≥ 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer ≥ 0, got {value}")
    return value


def _write_json(path: Path, payload: dict) -> None:
    """Write JSON atomically: a partial file never replaces a complete one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, sort_keys=True) + "\n")
    tmp.replace(path)


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
        _write_json(path, result.metrics())
        print(f"\nwrote {path}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The full ``teamslam`` argument parser."""
    from teamslam.graph import GRAPH_KINDS

    parser = _Parser(
        prog="teamslam",
        description="Multi-robot SLAM by filtering: distributed inference, consistency measured.",
    )
    parser.add_argument("--version", action="version", version=f"teamslam {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    demo = sub.add_parser(
        "dvi-demo",
        help="distributed vs centralised Kalman filter on a linear-Gaussian team problem",
        description="Run the distributed Kalman filter (consensus averaging, predict, update) "
        "on a generated linear-Gaussian tracking problem and compare it with the centralised "
        "Kalman filter and with separate filters on the same data.",
    )
    demo.add_argument("--agents", type=_positive_int, default=5, help="number of agents (≥ 2)")
    demo.add_argument("--graph", choices=GRAPH_KINDS, default="ring", help="communication graph")
    demo.add_argument("--loss", type=_rate, default=0.0, help="per-step edge loss rate r")
    demo.add_argument("--steps", type=_positive_int, default=60, help="number of time steps")
    demo.add_argument("--seed", type=_non_negative_int, default=0, help="random seed")
    demo.add_argument("--out", type=Path, default=None, help="directory for metrics.json")
    demo.set_defaults(handler=_cmd_dvi_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``teamslam`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "handler", None) is None:
        parser.print_help()
        return 2
    try:
        return int(args.handler(args))
    except (UsageError, ValueError) as exc:
        sys.stderr.write(f"teamslam {args.command}: error: {exc}\n")
        return 2


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
