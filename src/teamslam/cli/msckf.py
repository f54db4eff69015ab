"""``teamslam run``, ``calibrate`` and ``config``: the distributed MSCKF over a team dataset."""

from __future__ import annotations

import argparse
import json
import os
import shutil
from pathlib import Path

from teamslam.cli._common import (
    Parser,
    UsageError,
    effective_settings,
    non_negative_int,
    positive_int,
    print_health,
    rate,
    settings_arguments,
    settings_line,
)
from teamslam.cli.team import launch_and_report
from teamslam.eval.outputs import json_safe, write_team_outputs
from teamslam.eval.tables import team_table

__all__ = ["register"]


def _cmd_run(args: argparse.Namespace) -> int:
    from teamslam.datasets import load_dataset
    from teamslam.eval.metrics import team_metrics
    from teamslam.graph import make
    from teamslam.msckf import run_team

    dataset = load_dataset(args.dataset)
    effective = effective_settings(args, dataset)
    print(settings_line(dataset, effective))
    if args.mcap is not None and args.out is None:
        raise UsageError("--mcap needs --out (the run's result directory)")
    if args.secure and not args.processes:
        raise UsageError("--secure needs --processes (robots as processes on loopback)")
    if args.processes:
        if args.out is None or args.compare or args.separate or args.centralised:
            raise UsageError("--processes needs --out and runs consensus only")
        return _run_processes(args, dataset, effective)
    graph = make(args.graph, dataset.n_robots, seed=args.seed)
    modes = (
        {"separate": False, "consensus": True}
        if args.compare
        else ({"separate": False} if args.separate else {"consensus": True})
    )
    if args.centralised:
        modes = {"centralised": None}
    results, metrics = {}, {}
    for name, consensus in modes.items():
        if consensus is None:
            from teamslam.msckf.centralised import run_centralised

            results[name] = run_centralised(dataset, effective.robots)
        else:
            results[name] = run_team(
                dataset, effective.robots, graph, consensus, args.loss, args.seed
            )
        metrics[name] = {**team_metrics(dataset, results[name]), **effective.to_json()}
    print(f"{dataset.name}: {dataset.n_robots} robots, graph {graph.name}, loss {args.loss}")
    print(team_table(metrics))
    for name, m in metrics.items():
        print_health(name, m)
    if args.out is not None:
        out = Path(args.out)
        write_team_outputs(out, dataset, results, metrics, report=False)
        if args.mcap is not None:
            from teamslam.cli.ros2 import print_mcap_summary
            from teamslam.ros2.mcap_export import export_mcap

            target = out / "run.mcap" if args.mcap == "" else Path(args.mcap)
            print_mcap_summary(export_mcap(out, target))
        if not args.no_report:
            from teamslam.eval.report import write_run_report

            print(f"report: {write_run_report(out, dataset, results)}")
    return 0


def _run_processes(args: argparse.Namespace, dataset, effective) -> int:
    """``run --processes [--secure]``: write a loopback team file, launch it, report."""
    from teamslam.graph import make
    from teamslam.runtime.team_file import write_team_file

    out = Path(args.out)
    name = f"run-{os.getpid()}"
    adjacency = make(args.graph, dataset.n_robots, seed=args.seed).adjacency
    settings = {
        "base_port": args.base_port,
        "message_loss": args.loss,
        "filter": effective.config.to_json(),
    }
    if not args.secure:
        team_path = write_team_file(out / "team.yaml", name, args.dataset, adjacency, **settings)
        return launch_and_report(team_path, out, effective)
    from teamslam.runtime.security import SecuritySection, make_team_certificates

    keys = out / "certs"
    robots = {i: (f"robot-{i}", "127.0.0.1") for i in range(dataset.n_robots)}
    written = make_team_certificates(name, robots, keys, days=1, reuse_ca=False)
    try:
        security = SecuritySection(written.ca_certificate, written.robots)
        team_path = write_team_file(
            out / "team.yaml", name, args.dataset, adjacency, security=security, **settings
        )
        print(f"secured team: mutual TLS, access control; throw-away certificates in {keys}")
        return launch_and_report(team_path, out, effective)
    finally:
        shutil.rmtree(keys, ignore_errors=True)


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from teamslam.datasets import load_dataset, save_dataset
    from teamslam.msckf.calibration import calibrate
    from teamslam.msckf.settings import calibration_start

    dataset = load_dataset(args.dataset)
    # every setting from the usual layers, but the estimated noise levels start from the
    # camera-scaled defaults, not from what the dataset already says
    start = calibration_start(dataset, effective_settings(args, dataset, calibrate="never").config)
    result = calibrate(dataset, start, frames=args.frames, odometry_per_axis=args.odometry_per_axis)
    payload = result.to_json()
    if dataset.sensor_model is not None:
        payload["dataset_sensor_model"] = dataset.sensor_model.to_json()
    if args.json:
        print(json.dumps(json_safe(payload), indent=2))
    else:
        print(_calibration_table(dataset, result))
    if args.write:
        from dataclasses import replace

        model = result.sensor_model
        if dataset.sensor_model is not None:  # keep what calibration does not estimate
            model = replace(model, team=dataset.sensor_model.team.merged(model.team))
        save_dataset(replace(dataset, sensor_model=model), args.dataset)
        if not args.json:
            print(f"\nwrote the calibrated sensor model into {args.dataset}")
    return 0


def _calibration_table(dataset, result) -> str:
    from teamslam.textio import format_value

    noise = result.sensor_model.team
    old = dataset.sensor_model.team if dataset.sensor_model is not None else None
    lines = [
        f"{dataset.name}: calibrated from {result.frames} frames per robot in "
        f"{result.seconds:.1f} s, {len(result.iterations)} filter passes"
        f"{'' if result.converged else ' (not converged)'}",
        f"{'':<22}{'calibrated':>44}"
        + (f"  {'dataset (' + dataset.sensor_model.origin + ')':>44}" if old else ""),
    ]

    for label, key in (
        ("odometry σ (m, rad)", "odometry_std"),
        ("feature σ (K units)", "feature_std"),
        ("object σ (K units)", "object_std"),
        ("object depth (m)", "object_depth_range"),  # not calibrated: shown for reference
    ):
        row = f"{label:<22}{format_value(getattr(noise, key)):>44}"
        if old is not None:
            row += f"  {format_value(getattr(old, key)):>44}"
        lines.append(row)
    start = result.start
    for sensor in ("features", "objects"):
        bound = start.get(f"{sensor}_epipolar_std")
        if bound is not None:
            lines.append(
                f"{sensor} left/right-independent noise (epipolar residual): {bound:.4g} K units"
            )
    last = result.iterations[-1]
    health = ", ".join(f"{s} NIS/dof {v:.2f}" for s, v in last["nis"].items() if v is not None)
    if health:
        lines.append(f"last pass: {health}")
    return "\n".join(lines)


def _cmd_config_show(args: argparse.Namespace) -> int:
    from teamslam.datasets import load_dataset

    dataset = load_dataset(args.dataset)
    effective = effective_settings(args, dataset)
    if args.json:
        print(json.dumps(json_safe(effective.to_json()), indent=2))
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
    settings_arguments(run)
    run.add_argument("--seed", type=non_negative_int, default=0, help="seed of the link loss")
    run.add_argument("--out", type=Path, default=None, help="directory for results")
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
        description="Print every filter setting `teamslam run DATASET` would use and its source: "
        "default (scaled to the camera), dataset (its sensor model), calibration, file or flag.",
    )
    show.add_argument("dataset", type=Path, help="dataset directory (teamslam format)")
    show.add_argument("--json", action="store_true", help="print one JSON object")
    settings_arguments(show)
    show.set_defaults(handler=_cmd_config_show)
