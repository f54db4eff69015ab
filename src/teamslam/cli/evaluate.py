"""``teamslam eval`` and ``teamslam report``: trajectory evaluation of team runs, HTML report.

::

    teamslam eval RUN... [--ref DATASET | --ref-tum FILE... | --ref-kitti FILE...]
                  [--align none|se3|sim3|first-pose] [--per-robot | --team]
                  [--rpe-delta N] [--rpe-unit frames|m] [--max-time-diff S] [--json] [--out DIR]
    teamslam report RUN... --out report.html [same reference and alignment options]

``RUN`` is a run directory of ``teamslam run`` (two columns if it was run with ``--compare``),
a TUM or KITTI trajectory file (a one-robot team), or such files joined by commas (a robot per
file).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from teamslam.cli._common import non_negative_float, positive_float
from teamslam.errors import InputError

__all__ = ["register"]


def _evaluation_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "runs",
        nargs="+",
        metavar="RUN",
        help="run directory of `teamslam run`, a TUM/KITTI trajectory file, or files joined "
        "by commas (one robot each)",
    )
    ref = parser.add_mutually_exclusive_group()
    ref.add_argument(
        "--ref",
        type=Path,
        default=None,
        metavar="DATASET",
        help="ground truth from a team dataset (default: the one the run recorded)",
    )
    ref.add_argument(
        "--ref-tum", nargs="+", default=None, metavar="FILE", help="TUM ground truth, per robot"
    )
    ref.add_argument(
        "--ref-kitti",
        nargs="+",
        default=None,
        metavar="FILE",
        help="KITTI ground truth, per robot (paired frame by frame)",
    )
    parser.add_argument(
        "--align",
        choices=("none", "se3", "sim3", "first-pose"),
        default="none",
        help="alignment of the estimate to the reference (default: none)",
    )
    scope = parser.add_mutually_exclusive_group()
    scope.add_argument(
        "--per-robot",
        dest="scope",
        action="store_const",
        const="robot",
        help="one alignment per robot",
    )
    scope.add_argument(
        "--team",
        dest="scope",
        action="store_const",
        const="team",
        help="one alignment for the whole team (default: the honest one for a shared map)",
    )
    parser.set_defaults(scope="team")
    parser.add_argument(
        "--rpe-delta", type=positive_float, default=1.0, help="RPE step (default: 1)"
    )
    parser.add_argument(
        "--rpe-unit",
        choices=("frames", "m"),
        default="frames",
        help="RPE step in frames or in metres travelled along the reference",
    )
    parser.add_argument(
        "--max-time-diff",
        type=non_negative_float,
        default=0.01,
        help="largest time difference of associated poses, s (default: 0.01)",
    )


def _references(args: argparse.Namespace):
    from teamslam.eval.runs import dataset_references, read_trajectory

    if args.ref is not None:
        return dataset_references(args.ref)
    if args.ref_tum is not None or args.ref_kitti is not None:
        files = args.ref_tum if args.ref_tum is not None else args.ref_kitti
        refs = [read_trajectory(f, f"robot {k} reference") for k, f in enumerate(files)]
        if args.ref_kitti is not None and any(r.timestamps is not None for r in refs):
            raise InputError("--ref-kitti: a TUM file was given (8 values a line); use --ref-tum")
        if args.ref_tum is not None and any(r.timestamps is None for r in refs):
            raise InputError(
                "--ref-tum: a KITTI file was given (12 values a line); use --ref-kitti"
            )
        return refs
    return None


def _options(args: argparse.Namespace) -> dict:
    if args.rpe_unit == "frames" and args.rpe_delta != int(args.rpe_delta):
        raise InputError(f"--rpe-delta in frames must be a whole number, got {args.rpe_delta}")
    delta = int(args.rpe_delta) if args.rpe_unit == "frames" else args.rpe_delta
    return {
        "align": args.align,
        "scope": args.scope,
        "rpe_delta": delta,
        "rpe_unit": args.rpe_unit,
        "max_time_diff": args.max_time_diff,
    }


def _cmd_eval(args: argparse.Namespace) -> int:
    from teamslam import api
    from teamslam.eval.outputs import json_safe
    from teamslam.eval.report import evaluation_table

    result = api.evaluate(args.runs, _references(args), args.out, **_options(args))
    if args.json:
        print(json.dumps(json_safe({"runs": result["runs"]}), indent=2, sort_keys=True))
    else:
        print(evaluation_table(result["names"], result["statistics"]))
    if args.out is not None and not args.json:
        print(f"\nwrote {args.out}/eval.json, trajectories.png, ape_over_time.png, ape_path.png")
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from teamslam.eval.report import write_report

    start = time.perf_counter()
    path = write_report(args.runs, args.out, _references(args), **_options(args))
    size = path.stat().st_size
    print(f"wrote {path} ({size / 1e6:.2f} MB in {time.perf_counter() - start:.1f} s)")
    return 0


def register(subparsers) -> None:
    """Add ``eval`` and ``report`` to the ``teamslam`` subcommands."""
    ev = subparsers.add_parser(
        "eval",
        help="APE/RPE of team runs against ground truth, with alignment; runs side by side",
        description="Absolute and relative pose errors (translation and rotation: RMSE, mean, "
        "median, std, max) of every robot and of the team, after no alignment, SE(3), Sim(3) "
        "(Umeyama) or first-pose alignment, per robot or one for the team. Runs are compared "
        "side by side; `--align none` gives the trajectory RMSE of the run's metrics.json.",
    )
    _evaluation_arguments(ev)
    ev.add_argument("--json", action="store_true", help="print one JSON object")
    ev.add_argument(
        "--out", type=Path, default=None, help="directory for eval.json and the figures"
    )
    ev.set_defaults(handler=_cmd_eval)

    rep = subparsers.add_parser(
        "report",
        help="one self-contained HTML report of team runs, side by side",
        description="Write one HTML file (figures embedded, nothing fetched) with the team, its "
        "communication graph, accuracy, consistency, sensor health, timing, messages and the "
        "effective configuration with its sources; a column per run.",
    )
    _evaluation_arguments(rep)
    rep.add_argument("--out", type=Path, required=True, help="the HTML file to write")
    rep.set_defaults(handler=_cmd_report)
