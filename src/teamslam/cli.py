"""The ``teamslam`` command.

Usage errors (a wrong flag, a value out of range) print one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import math
import os
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


def _default_data() -> Path:
    """``$TEAMSLAM_DATA`` or ``../shared/data`` relative to the working directory."""
    import os

    return Path(os.environ.get("TEAMSLAM_DATA", Path("..") / "shared" / "data"))


def _json_safe(value):
    """NaN and infinities become ``null`` (strict JSON has no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    return value


def _write_json(path: Path, payload: dict) -> None:
    """Write JSON atomically: a partial file never replaces a complete one."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(_json_safe(payload), indent=2, sort_keys=True) + "\n")
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


def _cmd_simulate(args: argparse.Namespace) -> int:
    from teamslam.datasets import dataset_info, format_info, save_dataset
    from teamslam.sim import lissajous_team

    dataset = lissajous_team(
        robots=args.robots,
        steps=args.steps,
        objects=args.objects,
        seed=args.seed,
        noise_free=args.noise_free,
    )
    path = save_dataset(dataset, args.out)
    print(format_info(dataset_info(dataset)))
    print(f"\nwrote {path}")
    return 0


def _cmd_data_info(args: argparse.Namespace) -> int:
    from teamslam.datasets import dataset_info, format_info, load_dataset

    info = dataset_info(load_dataset(args.dataset))
    print(json.dumps(info, indent=2) if args.json else format_info(info))
    return 0


def _cmd_data_import_reference(args: argparse.Namespace) -> int:
    from teamslam.datasets import dataset_info, format_info, import_reference, save_dataset

    dataset = import_reference(
        args.source, inverted_odometry=args.inverted_odometry, params=args.params
    )
    path = save_dataset(dataset, args.out)
    print(format_info(dataset_info(dataset)))
    print(f"\nwrote {path}")
    if dataset.sensor_model is not None:
        _check_params(dataset, path)
    return 0


def _check_params(dataset, path: Path) -> None:
    """Compare a params file's noise levels with a calibration from the data; warn on a gap."""
    from teamslam.msckf.calibration import calibrate
    from teamslam.msckf.settings import calibration_start, resolve_config

    model = dataset.sensor_model.team
    start = calibration_start(dataset, resolve_config(dataset, calibrate="never").config)
    estimate = calibrate(dataset, start).sensor_model.team

    def pick(noise, label):
        odometry = noise.odometry_std
        return {
            "odometry σ translation (m)": None if odometry is None else max(odometry[:3]),
            "odometry σ rotation (rad)": None if odometry is None else max(odometry[3:]),
            "feature σ": noise.feature_std,
            "object σ": noise.object_std,
        }[label]

    print(f"\nsensor model from {dataset.sensor_model.note}")
    print(f"{'':<28}{'params file':>14}{'the data say':>14}")
    for label in (
        "odometry σ translation (m)",
        "odometry σ rotation (rad)",
        "feature σ",
        "object σ",
    ):
        given, found = pick(model, label), pick(estimate, label)
        if given is None or found is None:
            continue
        print(f"{label:<28}{given:>14.4g}{found:>14.4g}")
        if not 1 / 3 <= given / found <= 3:
            print(
                f"warning: the params file's {label} ({given:.4g}) is {given / found:.2g}× "
                f"what the data show ({found:.4g}); `teamslam calibrate {path} --write` "
                "replaces it",
                file=sys.stderr,
            )


def _fej_environment(args: argparse.Namespace):
    from teamslam.ekf2d.environments import environment, load_environment, load_matlab_environment

    if not args.environment:
        return environment(args.env, args.features)
    files = [Path(f) for f in args.environment]
    for f in files:
        if not f.is_file():
            raise UsageError(f"environment file {f} does not exist")
    if len(files) == 1 and files[0].suffix == ".json":
        env = load_environment(files[0])
    else:
        base = environment(args.env, 20)  # the chosen environment's noise levels
        env = load_matlab_environment(
            files,
            odometry_std=base.odometry_std,
            observation_std=base.observation_std,
            name="+".join(f.stem for f in files),
        )
    return env


def _cmd_fej_table(args: argparse.Namespace) -> int:
    from teamslam.ekf2d.experiments import format_table, monte_carlo

    env = _fej_environment(args)
    result = monte_carlo(env, runs=args.runs, seed=args.seed, workers=args.workers)
    if args.json:
        print(json.dumps(result.table, indent=2))
    else:
        print(format_table(result))
    if args.out is not None:
        from teamslam.eval.plots import plot_monte_carlo, plot_sigma_bounds

        out = Path(args.out)
        _write_json(
            out / "table.json",
            {
                "environment": env.name,
                "runs": args.runs,
                "steps": result.steps,
                "filters": result.table,
            },
        )
        plot_monte_carlo(result, out / "nees_rmse.png")
        plot_sigma_bounds(result, out / "sigma_bounds.png")
        if not args.json:
            print(f"\nwrote {out}/table.json, nees_rmse.png, sigma_bounds.png")
    return 0


def _cmd_fej_victoria_park(args: argparse.Namespace) -> int:
    from teamslam.datasets.victoria_park import load_victoria_park
    from teamslam.ekf2d.victoria_park import run_victoria_park
    from teamslam.eval.plots import plot_planar_map

    split = load_victoria_park(args.data)
    results = {p: run_victoria_park(split, p, args.per_measurement_noise) for p in ("std", "fej")}
    head = (
        f"{'EKF':<6} {'R1 pos RMSE':>12} {'R2 pos RMSE':>12} {'R1 head':>9} {'R2 head':>9} "
        f"{'feat RMSE':>10} {'time [s]':>9}"
    )
    print("Victoria Park, two-robot split (poses 719–3264 and 3265–5810), errors against the")
    print("reference batch Gauss–Newton solution:")
    print(head)
    print("-" * len(head))
    summary = {}
    for name, r in results.items():
        print(
            f"{name:<6} {r.position_rmse[0]:12.3f} {r.position_rmse[1]:12.3f} "
            f"{r.heading_rmse[0]:9.4f} {r.heading_rmse[1]:9.4f} {r.feature_rmse:10.3f} "
            f"{r.seconds:9.2f}"
        )
        summary[name] = {
            "position_rmse_m": r.position_rmse.tolist(),
            "heading_rmse_rad": r.heading_rmse.tolist(),
            "feature_rmse_m": r.feature_rmse,
            "seconds": r.seconds,
        }
    if args.out is not None:
        out = Path(args.out)
        _write_json(out / "metrics.json", summary)
        trajectories = {"reference (Gauss–Newton)": [r.reference_poses for r in split.robots]}
        features = {"reference (Gauss–Newton)": split.reference_features}
        for name, r in results.items():
            label = {"std": "Std-EKF", "fej": "FEJ-EKF"}[name]
            trajectories[label] = [r.poses[:, i] for i in range(r.poses.shape[1])]
            features[label] = r.features
        plot_planar_map(trajectories, features, out / "victoria_park.png", "Victoria Park")
        print(f"\nwrote {out}/metrics.json, victoria_park.png")
    return 0


def _team_table(runs: dict[str, dict]) -> str:
    """Side-by-side summary of team runs (separate vs consensus)."""
    names = list(runs)
    rows = [
        ("trajectory RMSE avg [m]", "trajectory_rmse_avg_m"),
        ("trajectory RMSE max [m]", "trajectory_rmse_max_m"),
        ("odometry-only RMSE avg [m]", "odometry_rmse_avg_m"),
        ("object error avg [m]", "object_error_avg_m"),
        ("object disagreement avg [m]", "object_disagreement_avg_m"),
    ]
    width = max(14, *(len(n) + 2 for n in names))
    lines = [f"{'':<36}" + "".join(f"{n:>{width}}" for n in names)]
    for label, key in rows:
        lines.append(f"{label:<36}" + "".join(f"{runs[n][key]:>{width}.3f}" for n in names))
    n_robots = runs[names[0]]["robots"]
    for i in range(n_robots):
        lines.append(
            f"{f'robot {i + 1} trajectory RMSE [m]':<36}"
            + "".join(f"{runs[n]['trajectory_rmse_m'][i]:>{width}.3f}" for n in names)
        )
    linearization = runs[names[0]].get("config", {}).get("linearization", "std")
    for i in range(n_robots):
        lines.append(
            f"{f'robot {i + 1} pose NEES / 6 ({linearization})':<36}"
            + "".join(f"{runs[n]['nees_pose_avg'][i]:>{width}.2f}" for n in names)
        )
    for sensor, label in (("features", "features"), ("objects", "objects")):
        if any(runs[n].get("nis", {}).get(sensor) is not None for n in names):
            lines.append(
                f"{f'{label} NIS/dof | gate rejected':<36}"
                + "".join(_health_cell(runs[n], sensor, width) for n in names)
            )
    if any(runs[n].get("odometry_residual_ratio") for n in names):
        lines.append(
            f"{'odometry residual ratio (t | r)':<36}"
            + "".join(_odometry_cell(runs[n], width) for n in names)
        )
    for stage in ("consensus", "propagation", "update", "initialisation", "total"):
        lines.append(
            f"{f'time {stage} [ms/robot/frame]':<36}"
            + "".join(f"{runs[n]['time_per_robot_step_ms'][stage]:>{width}.2f}" for n in names)
        )
    return "\n".join(lines)


def _health_cell(run: dict, sensor: str, width: int) -> str:
    nis = run.get("nis", {}).get(sensor)
    rejected = run.get("gate_rejection_rate", {}).get(sensor)
    if nis is None:
        return f"{'—':>{width}}"
    cell = f"{nis:.2f} | {100 * rejected:.1f}%"
    return f"{cell:>{width}}"


def _odometry_cell(run: dict, width: int) -> str:
    ratio = run.get("odometry_residual_ratio")
    if not ratio:
        return f"{'—':>{width}}"
    cell = f"{ratio['translation']:.2f} | {ratio['rotation']:.2f}"
    return f"{cell:>{width}}"


def _write_team_outputs(out: Path, dataset, results: dict, metrics: dict) -> None:
    from teamslam.datasets import write_tum
    from teamslam.eval.plots import plot_team_errors, plot_team_topview

    names = list(results)
    payload = (
        metrics[names[0]]
        if len(names) == 1
        else {**metrics["consensus"], "separate": metrics["separate"]}
    )
    _write_json(out / "metrics.json", payload)
    for name, result in results.items():
        prefix = out if len(names) == 1 else out / name
        for i, robot in enumerate(dataset.robots):
            write_tum(prefix / f"robot_{i + 1}.tum", result.poses[i], robot.timestamps)
            write_tum(
                prefix / f"robot_{i + 1}_groundtruth.tum", robot.T_world_body, robot.timestamps
            )
    plot_team_topview(dataset, results, out / "topview.png")
    plot_team_errors(dataset, results, out / "errors.png")
    print(f"\nwrote {out}/metrics.json, TUM trajectories, topview.png, errors.png")


def _launch_and_report(team_path: Path, out: Path, effective=None) -> int:
    from teamslam.datasets import load_dataset
    from teamslam.eval.metrics import team_metrics
    from teamslam.runtime.launch import exit_summary, gather, launch_team
    from teamslam.runtime.team_file import load_team_file

    team = load_team_file(team_path)
    codes = launch_team(team, team_path, out)
    finished = [r for r, c in sorted(codes.items()) if c == 0]
    if len(finished) < team.n:
        sys.stderr.write(f"teamslam team: {exit_summary(codes)} (see {out}/robot_N.log)\n")
    if not finished:
        return 1
    if team.dataset is None or any(r.dataset for r in team.robots):
        print("robots ran on their own datasets; per-robot results are in", out)
        return 0 if len(finished) == team.n else 1
    dataset = load_dataset(team.dataset)
    result = gather(team, out, finished)
    if len(finished) < team.n:
        print(f"robots {', '.join(str(r) for r in finished)} finished; metrics cover them only")
        from teamslam.datasets import TeamDataset

        dataset = TeamDataset(
            dataset.name,
            dataset.calibration,
            [dataset.robots[r] for r in finished],
            dataset.object_ids,
            dataset.object_positions,
            metadata=dataset.metadata,
        )
    metrics = {"consensus": team_metrics(dataset, result)}
    for summary in result.extra["per_robot"]:
        if summary["lost_neighbours"]:
            print(f"robot {summary['robot']} lost neighbour(s) {summary['lost_neighbours']}")
    metrics["consensus"]["transport"] = result.extra["per_robot"]
    if effective is not None:
        metrics["consensus"].update(effective.to_json())
    print(_team_table(metrics))
    if "nis" in metrics["consensus"]:
        _print_health("consensus", metrics["consensus"])
    _write_team_outputs(out, dataset, {"consensus": result}, metrics)
    return 0 if len(finished) == team.n else 1


def _cmd_team_launch(args: argparse.Namespace) -> int:
    return _launch_and_report(Path(args.team_file), Path(args.out))


def _cmd_agent(args: argparse.Namespace) -> int:
    from teamslam.runtime.agent_process import run_agent
    from teamslam.runtime.team_file import load_team_file

    team = load_team_file(args.team)
    if not 0 <= args.robot < team.n:
        raise UsageError(f"--robot must lie in 0..{team.n - 1}")
    summary = run_agent(team, args.robot, Path(args.out), resume=args.resume)
    print(json.dumps({k: summary[k] for k in ("robot", "frames", "lost_neighbours")}))
    return 0


def _settings(args: argparse.Namespace, dataset, calibrate: str | None = None):
    """The effective settings of a run: dataset, calibration, ``--config``, flags."""
    from teamslam.msckf.settings import load_config_file, parse_assignments, resolve_config

    file_values = load_config_file(args.config) if args.config is not None else {}
    flags = parse_assignments(args.set or [])
    if getattr(args, "window", None):
        flags["window"] = args.window
    if getattr(args, "objects_only", False):
        flags["use_geometric_features"] = False
    return resolve_config(
        dataset,
        file_values,
        flags,
        calibrate=calibrate or args.calibrate,
        calibration_frames=getattr(args, "calibration_frames", None),
    )


def _settings_line(dataset, effective) -> str:
    """One line: where the noise levels came from."""
    model = dataset.sensor_model
    if effective.calibration is not None:
        c = effective.calibration
        keys = sorted(k for k, v in effective.sources.items() if v == "calibration")
        return (
            f"sensor model: {'none in the dataset; ' if model is None else ''}calibrated from "
            f"the data in {c.seconds:.1f} s ({len(c.iterations)} passes over {c.frames} frames "
            f"per robot{'' if c.converged else ', not converged'}): {', '.join(keys)}"
        )
    if model is not None:
        note = f": {model.note}" if model.note else ""
        return f"sensor model: the dataset's ({model.origin}{note})"
    return "sensor model: none in the dataset and calibration off; camera-scaled defaults"


def _print_health(name: str, metrics: dict) -> None:
    from teamslam.msckf.health import health_warnings

    for line in health_warnings(
        {
            "nis": metrics["nis"],
            "gate_rejection_rate": metrics["gate_rejection_rate"],
            "odometry_residual_ratio": metrics["odometry_residual_ratio"],
        }
    ):
        print(f"warning ({name}): {line}", file=sys.stderr)


def _cmd_run(args: argparse.Namespace) -> int:
    from teamslam.datasets import load_dataset
    from teamslam.eval.metrics import team_metrics
    from teamslam.graph import make
    from teamslam.msckf import run_team

    dataset = load_dataset(args.dataset)
    effective = _settings(args, dataset)
    print(_settings_line(dataset, effective))
    if args.processes:
        if args.out is None or args.compare or args.separate or args.centralised:
            raise UsageError("--processes needs --out and runs consensus only")
        from teamslam.runtime.team_file import write_team_file

        adjacency = make(args.graph, dataset.n_robots, seed=args.seed).adjacency
        team_path = write_team_file(
            Path(args.out) / "team.yaml",
            f"run-{os.getpid()}",
            args.dataset,
            adjacency,
            base_port=args.base_port,
            message_loss=args.loss,
            filter=effective.config.to_json(),
        )
        return _launch_and_report(team_path, Path(args.out), effective)
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
    print(_team_table(metrics))
    for name, m in metrics.items():
        _print_health(name, m)
    if args.out is not None:
        _write_team_outputs(Path(args.out), dataset, results, metrics)
    return 0


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from teamslam.datasets import load_dataset, save_dataset
    from teamslam.msckf.calibration import calibrate
    from teamslam.msckf.settings import calibration_start

    dataset = load_dataset(args.dataset)
    # every setting from the usual layers, but the estimated noise levels start from the
    # camera-scaled defaults, not from what the dataset already says
    start = calibration_start(dataset, _settings(args, dataset, calibrate="never").config)
    result = calibrate(dataset, start, frames=args.frames, odometry_per_axis=args.odometry_per_axis)
    payload = result.to_json()
    if dataset.sensor_model is not None:
        payload["dataset_sensor_model"] = dataset.sensor_model.to_json()
    if args.json:
        print(json.dumps(_json_safe(payload), indent=2))
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
    effective = _settings(args, dataset)
    if args.json:
        print(json.dumps(_json_safe(effective.to_json()), indent=2))
    else:
        print(_settings_line(dataset, effective))
        print(effective.table())
    return 0


def _settings_arguments(parser: argparse.ArgumentParser, calibration_flags: bool = True) -> None:
    """``--config`` and ``--set`` (and, unless told otherwise, when to calibrate)."""
    parser.add_argument(
        "--config", type=Path, default=None, help="YAML file of filter settings (key: value)"
    )
    parser.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="a filter setting, e.g. --set object_std=0.01 (repeatable; wins over --config)",
    )
    if not calibration_flags:
        return
    parser.add_argument(
        "--calibrate",
        choices=("auto", "always", "never"),
        default="auto",
        help="calibrate noise levels from the data: when the dataset, file and flags lack them "
        "(auto), in place of the dataset's (always), or not at all (never)",
    )
    parser.add_argument(
        "--calibration-frames",
        type=_positive_int,
        default=None,
        help="frames per robot a calibration uses (default: ~1200/robots)",
    )


def build_parser() -> argparse.ArgumentParser:
    """The full ``teamslam`` argument parser."""
    from teamslam.eval import team_montecarlo
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

    sim = sub.add_parser(
        "simulate",
        help="simulate a stereo robot team on Lissajous curves and write a dataset",
        description="Simulate a team of stereo robots flying 3D Lissajous curves through one "
        "arena (objects, geometric feature tracks, noisy odometry) and write it in teamslam's "
        "dataset format.",
    )
    sim.add_argument("--robots", type=_positive_int, default=5, help="number of robots")
    sim.add_argument("--steps", type=_positive_int, default=300, help="motion steps per robot")
    sim.add_argument("--objects", type=_non_negative_int, default=210, help="objects in the map")
    sim.add_argument("--seed", type=_non_negative_int, default=0, help="random seed")
    sim.add_argument("--noise-free", action="store_true", help="exact measurements and odometry")
    sim.add_argument("--out", type=Path, required=True, help="dataset directory to write")
    sim.set_defaults(handler=_cmd_simulate)

    data = sub.add_parser("data", help="inspect and import team datasets")
    data_sub = data.add_subparsers(dest="data_command", metavar="ACTION", parser_class=_Parser)
    data_sub.required = True
    info = data_sub.add_parser("info", help="summary of a dataset")
    info.add_argument("dataset", type=Path, help="dataset directory")
    info.add_argument("--json", action="store_true", help="print one JSON object")
    info.set_defaults(handler=_cmd_data_info)
    imp = data_sub.add_parser(
        "import-reference",
        help="convert the distributed-MSCKF paper's published data to teamslam's format",
    )
    imp.add_argument("source", type=Path, help="directory of the published files")
    imp.add_argument("out", type=Path, help="dataset directory to write")
    imp.add_argument(
        "--inverted-odometry",
        action="store_true",
        help="the source stores inverse relative poses (the published simulated teams)",
    )
    imp.add_argument(
        "--params",
        type=Path,
        default=None,
        help="the publisher's parameter file (params.yaml): its noise variances become the "
        "dataset's sensor model, checked against a calibration from the data",
    )
    imp.set_defaults(handler=_cmd_data_import_reference)

    run = sub.add_parser(
        "run",
        help="run the distributed MSCKF (or separate MSCKFs) over a team dataset",
        description="Run one distributed-MSCKF agent per robot over a team dataset, with "
        "consensus over a communication graph (or separately), and report accuracy, agreement, "
        "consistency and timing.",
    )
    run.add_argument("dataset", type=Path, help="dataset directory (teamslam format)")
    run.add_argument("--graph", choices=GRAPH_KINDS, default="complete", help="communication graph")
    run.add_argument("--loss", type=_rate, default=0.0, help="per-frame link loss rate r")
    mode = run.add_mutually_exclusive_group()
    mode.add_argument("--separate", action="store_true", help="no consensus")
    mode.add_argument("--compare", action="store_true", help="run separate and consensus")
    mode.add_argument(
        "--centralised",
        action="store_true",
        help="one MSCKF holding every robot's window and every object (the reference)",
    )
    run.add_argument("--window", type=_positive_int, default=None, help="window size c")
    run.add_argument("--objects-only", action="store_true", help="ignore geometric features")
    _settings_arguments(run)
    run.add_argument("--seed", type=_non_negative_int, default=0, help="seed of the link loss")
    run.add_argument("--out", type=Path, default=None, help="directory for results")
    run.add_argument(
        "--processes",
        action="store_true",
        help="one process per robot talking over Zenoh on loopback",
    )
    run.add_argument(
        "--base-port",
        type=_positive_int,
        default=17400,
        help="first loopback TCP port with --processes",
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
        type=_positive_int,
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
    _settings_arguments(cal, calibration_flags=False)
    cal.set_defaults(handler=_cmd_calibrate)

    config_cmd = sub.add_parser("config", help="the settings a run would use, and their sources")
    config_sub = config_cmd.add_subparsers(
        dest="config_command", metavar="ACTION", parser_class=_Parser
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
    _settings_arguments(show)
    show.set_defaults(handler=_cmd_config_show)

    agent = sub.add_parser("agent", help="one robot's filter as a process (Zenoh)")
    agent.add_argument("--team", type=Path, required=True, help="team file (team.yaml)")
    agent.add_argument("--robot", type=int, required=True, help="robot id in the team file")
    agent.add_argument("--out", type=Path, default=Path("results/team"), help="output directory")
    agent.add_argument("--resume", action="store_true", help="continue from the last checkpoint")
    agent.set_defaults(handler=_cmd_agent)

    team_cmd = sub.add_parser("team", help="run a team of robot processes")
    team_sub = team_cmd.add_subparsers(dest="team_command", metavar="ACTION", parser_class=_Parser)
    team_sub.required = True
    launch = team_sub.add_parser("launch", help="start one process per robot and gather results")
    launch.add_argument("team_file", type=Path, help="team file (team.yaml)")
    launch.add_argument("--out", type=Path, required=True, help="output directory")
    launch.set_defaults(handler=_cmd_team_launch)

    fej = sub.add_parser("fej", help="planar multi-robot EKF: standard vs first-estimate vs ideal")
    fej_sub = fej.add_subparsers(dest="fej_command", metavar="ACTION", parser_class=_Parser)
    fej_sub.required = True
    table = fej_sub.add_parser("table", help="Monte Carlo NEES/RMSE table (paper Tables 1–2)")
    table.add_argument("--env", type=int, choices=(1, 2), default=1, help="environment")
    table.add_argument("--features", type=int, choices=(20, 60, 100), default=20)
    table.add_argument("--runs", type=_positive_int, default=100, help="Monte Carlo runs")
    table.add_argument("--seed", type=_non_negative_int, default=0, help="base seed")
    table.add_argument(
        "--workers", type=_positive_int, default=None, help="processes (default: all cores)"
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
        default=_default_data() / "victoria-park",
        help="directory of the Victoria Park files",
    )
    vp.add_argument(
        "--per-measurement-noise",
        action="store_true",
        help="use each measurement's own covariance instead of each robot's mean",
    )
    vp.add_argument("--out", type=Path, default=None, help="directory for metrics and figure")
    vp.set_defaults(handler=_cmd_fej_victoria_park)
    team_montecarlo.register(sub)
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
    except (UsageError, ValueError, OSError) as exc:
        sys.stderr.write(f"teamslam {args.command}: error: {exc}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write(f"teamslam {args.command}: interrupted\n")
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
