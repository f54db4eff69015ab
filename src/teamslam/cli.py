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


def _default_data() -> Path:
    """``$TEAMSLAM_DATA`` or ``../shared/data`` relative to the working directory."""
    import os

    return Path(os.environ.get("TEAMSLAM_DATA", Path("..") / "shared" / "data"))


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

    dataset = import_reference(args.source, inverted_odometry=args.inverted_odometry)
    path = save_dataset(dataset, args.out)
    print(format_info(dataset_info(dataset)))
    print(f"\nwrote {path}")
    return 0


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
    imp.set_defaults(handler=_cmd_data_import_reference)

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


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
