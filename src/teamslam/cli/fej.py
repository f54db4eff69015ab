"""``teamslam fej``: the planar multi-robot EKF (standard, first-estimate, ideal)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from teamslam.cli._common import Parser, UsageError, default_data, non_negative_int, positive_int
from teamslam.eval.outputs import write_json

__all__ = ["register"]


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
        write_json(
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
        write_json(out / "metrics.json", summary)
        trajectories = {"reference (Gauss–Newton)": [r.reference_poses for r in split.robots]}
        features = {"reference (Gauss–Newton)": split.reference_features}
        for name, r in results.items():
            label = {"std": "Std-EKF", "fej": "FEJ-EKF"}[name]
            trajectories[label] = [r.poses[:, i] for i in range(r.poses.shape[1])]
            features[label] = r.features
        plot_planar_map(trajectories, features, out / "victoria_park.png", "Victoria Park")
        print(f"\nwrote {out}/metrics.json, victoria_park.png")
    return 0


def register(sub) -> None:
    """Add this group's commands to the ``teamslam`` subparsers."""
    fej = sub.add_parser("fej", help="planar multi-robot EKF: standard vs first-estimate vs ideal")
    fej_sub = fej.add_subparsers(dest="fej_command", metavar="ACTION", parser_class=Parser)
    fej_sub.required = True
    table = fej_sub.add_parser("table", help="Monte Carlo NEES/RMSE table (paper Tables 1–2)")
    table.add_argument("--env", type=int, choices=(1, 2), default=1, help="environment")
    table.add_argument("--features", type=int, choices=(20, 60, 100), default=20)
    table.add_argument("--runs", type=positive_int, default=100, help="Monte Carlo runs")
    table.add_argument("--seed", type=non_negative_int, default=0, help="base seed")
    table.add_argument(
        "--workers", type=positive_int, default=None, help="processes (default: all cores)"
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
