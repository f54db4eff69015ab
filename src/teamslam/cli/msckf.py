"""``teamslam run``, ``calibrate`` and ``config``: the distributed MSCKF over a team dataset."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from teamslam.cli._common import (
    Parser,
    UsageError,
    effective_settings,
    non_negative_int,
    positive_int,
    print_run,
    rate,
    settings_arguments,
    settings_line,
)
from teamslam.eval.outputs import json_safe

__all__ = ["register"]


def _cmd_run(args: argparse.Namespace) -> int:
    from teamslam import api
    from teamslam.datasets import load_dataset

    if args.mcap is not None and args.out is None:
        raise UsageError("--mcap needs --out (the run's result directory)")
    if args.secure and not args.processes:
        raise UsageError("--secure needs --processes (robots as processes on loopback)")
    if args.processes and (args.out is None or args.compare or args.separate or args.centralised):
        raise UsageError("--processes needs --out and runs consensus only")
    api.require_extras(processes=args.processes, secure=args.secure, mcap=args.mcap is not None)
    if args.overwrite and args.out is None:
        raise UsageError("--overwrite needs --out (the run directory it replaces)")
    if args.out is not None:  # before any data is read
        from teamslam.eval.outputs import check_run_directory

        check_run_directory(args.out, args.overwrite)
    dataset = load_dataset(args.dataset)
    if args.association is not None:
        args.set = [*(args.set or []), f"association.mode={args.association}"]
    effective = effective_settings(args, dataset)
    print(settings_line(dataset, effective))
    mode = next(
        (m for m in ("compare", "separate", "centralised") if getattr(args, m)), "consensus"
    )
    run = api.run(
        dataset,
        mode,
        args.graph,
        args.loss,
        args.seed,
        settings=effective,
        out=args.out,
        report=not args.no_report,
        mcap=None if args.mcap is None else (args.mcap or True),
        processes=args.processes,
        base_port=args.base_port,
        secure=args.secure,
        source=args.dataset,
        overwrite=args.overwrite,
    )
    if not args.processes:
        print(f"{dataset.name}: {dataset.n_robots} robots, graph {run.graph}, loss {args.loss}")
    print_run(run, args.out)
    return run.exit_status


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from teamslam import api
    from teamslam.datasets import load_dataset
    from teamslam.msckf.calibration import calibration_json, calibration_table

    dataset = load_dataset(args.dataset)
    result = api.calibrate(
        dataset,
        list(args.set or []),
        args.config,
        frames=args.frames,
        odometry_per_axis=args.odometry_per_axis,
        write=args.write,
        source=args.dataset,
    )
    if args.json:
        print(json.dumps(json_safe(calibration_json(dataset, result)), indent=2))
    else:
        print(calibration_table(dataset, result))
        if args.write:
            print(f"\nwrote the calibrated sensor model into {args.dataset}")
    return 0


def _cmd_config_show(args: argparse.Namespace) -> int:
    from teamslam.datasets import load_dataset

    dataset = load_dataset(args.dataset)
    effective = effective_settings(args, dataset)
    if args.json:
        payload = {"settings": effective.rows(), **effective.to_json()}
        print(json.dumps(json_safe(payload), indent=2))
    else:
        print(settings_line(dataset, effective))
        print(effective.table())
    return 0


def register(sub) -> None:
    """Add this group's commands to the ``teamslam`` subparsers."""
    from teamslam.graph import GRAPH_KINDS

    run = sub.add_parser(
        "run",
        help="run the distributed MSCKF (or separate MSCKFs) over a team dataset",
        description="Run one distributed-MSCKF agent per robot over a team dataset, with "
        "consensus over a communication graph (or separately), and report accuracy, agreement, "
        "consistency and timing.",
    )
    run.add_argument("dataset", type=Path, help="dataset directory (teamslam format)")
    run.add_argument("--graph", choices=GRAPH_KINDS, default="complete", help="communication graph")
    run.add_argument("--loss", type=rate, default=0.0, help="per-frame link loss rate r")
    mode = run.add_mutually_exclusive_group()
    mode.add_argument("--separate", action="store_true", help="no consensus")
    mode.add_argument("--compare", action="store_true", help="run separate and consensus")
    mode.add_argument(
        "--centralised",
        action="store_true",
        help="one MSCKF holding every robot's window and every object (the reference)",
    )
    run.add_argument("--window", type=positive_int, default=None, help="window size c")
    run.add_argument("--objects-only", action="store_true", help="ignore geometric features")
    run.add_argument(
        "--association",
        choices=("oracle", "own"),
        default=None,
        help="which objects robots share: equal ids (oracle, global ids only) or found by each "
        "link from exchanged object summaries (own; the default with per-robot ids)",
    )
    settings_arguments(run)
    run.add_argument("--seed", type=non_negative_int, default=0, help="seed of the link loss")
    run.add_argument("--out", type=Path, default=None, help="directory for results")
    run.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an earlier run in --out (entirely); without it one is refused",
    )
    run.add_argument("--no-report", action="store_true", help="no report.html in --out")
    run.add_argument(
        "--mcap",
        nargs="?",
        const="",
        default=None,
        metavar="FILE",
        help="also write the run as MCAP with ROS 2 schemas (default OUT/run.mcap)",
    )
    run.add_argument(
        "--processes",
        action="store_true",
        help="one process per robot talking over Zenoh on loopback",
    )
    run.add_argument(
        "--base-port",
        type=positive_int,
        default=17400,
        help="first loopback TCP port with --processes",
    )
    run.add_argument(
        "--secure",
        action="store_true",
        help="with --processes: mutual TLS and access control with throw-away certificates",
    )
    run.set_defaults(handler=_cmd_run)

    cal = sub.add_parser(
        "calibrate",
        help="estimate a dataset's sensor model (odometry and measurement noise) from its data",
        description="Estimate the odometry noise (per step) and the measurement noise of "
        "geometric features and objects (in the camera's units) from the data alone — no ground "
        "truth — by covariance matching of the filter's innovations (mean NIS = dof) and "
        "expectation-maximisation of the odometry noise over the smoothed window.",
    )
    cal.add_argument("dataset", type=Path, help="dataset directory (teamslam format)")
    cal.add_argument(
        "--frames",
        type=positive_int,
        default=None,
        help="frames per robot (default: ~1200/robots)",
    )
    cal.add_argument(
        "--odometry-per-axis",
        action="store_true",
        help="fit six odometry σ instead of one for translation and one for rotation",
    )
    cal.add_argument("--json", action="store_true", help="print one JSON object")
    cal.add_argument(
        "--write", action="store_true", help="store the result as the dataset's sensor model"
    )
    settings_arguments(cal, calibration_flags=False)
    cal.set_defaults(handler=_cmd_calibrate)

    config_cmd = sub.add_parser("config", help="the settings a run would use, and their sources")
    config_sub = config_cmd.add_subparsers(
        dest="config_command", metavar="ACTION", parser_class=Parser
    )
    config_sub.required = True
    show = config_sub.add_parser(
        "show",
        help="every effective setting and where it came from",
        description="Print every filter setting `teamslam run DATASET` would use, one line "
        "each: group.name, value, unit and source — default (scaled to the camera), dataset "
        "(its sensor model), calibration, file or flag.",
    )
    show.add_argument("dataset", type=Path, help="dataset directory (teamslam format)")
    show.add_argument("--json", action="store_true", help="print one JSON object")
    settings_arguments(show)
    show.set_defaults(handler=_cmd_config_show)
