"""Monte Carlo consistency of the 3D team filter on the long route, per route seed.

Run on demand (BLAS pinned to one thread)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/long_route.py --seeds 37 43 0 --runs 10 \\
        [--robots 3] [--steps 600] [--filters std fej] [--modes separate consensus] \\
        [--set objects.retire_after=10] [--workers 2]

For each route seed: ``teamslam montecarlo --route long --seed S`` (the same route and map in
every run, each run its own noise) with the window of ``teamslam run`` (20) and the noise levels a
user's ``teamslam run`` takes from the simulated dataset's sensor model. Prints and, with
``--markdown FILE``, writes one row per seed, linearisation and mode: pose ANEES/6 and object
ANEES/3 with their 95 % χ² bands over the runs, the pose ANEES over each third of the route's frames
(overconfidence that builds up along the route shows as a rising sequence), the runs above the pose
band, position and heading RMSE, and how long the seed took.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from _markdown import Markdown, add_option
from teamslam.eval.team_montecarlo import MonteCarloSpec, run_montecarlo
from teamslam.msckf.settings.sources import parse_assignments

COLUMNS = [
    "route seed",
    "linearisation",
    "mode",
    "pose ANEES/6",
    "pose ANEES/6 by third of the route",
    "pose band",
    "runs above band",
    "object ANEES/3",
    "object band",
    "position RMSE [m]",
    "heading RMSE [rad]",
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[37, 43, 0], help="route seeds")
    parser.add_argument("--runs", type=int, default=10, help="noise realisations per seed")
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--steps", type=int, default=600, help="metres of route per robot")
    parser.add_argument("--window", type=int, default=20, help="MSCKF window (teamslam run's)")
    parser.add_argument("--filters", nargs="+", default=["std", "fej"])
    parser.add_argument("--modes", nargs="+", default=["separate", "consensus"])
    parser.add_argument("--set", action="append", default=[], metavar="GROUP.NAME=VALUE")
    parser.add_argument("--workers", type=int, default=None, help="processes (all cores)")
    add_option(parser)
    args = parser.parse_args()
    settings = tuple(parse_assignments(args.set).items())
    md = Markdown(args.markdown)
    md.table(
        f"Long route: {args.robots} robots × {args.steps} m, {args.runs} noise realisations per "
        "route seed",
        COLUMNS,
        note="Each route seed draws the route and its map; every run of it draws its own noise "
        "(`teamslam montecarlo --route long`). ANEES: the NEES per degree of freedom averaged "
        "over runs, robots and frames (pose) or over runs and objects (object); 1 is "
        "consistent, above the band overconfident. Window "
        f"{args.window}, noise levels of the dataset's sensor model (as `teamslam run`)"
        + (f", {', '.join(args.set)}" if args.set else "")
        + ".",
    )
    print(
        f"{'seed':>5} {'filter':<6} {'mode':<10} {'pose':>6} {'by third':>18} {'band':>11} "
        f"{'above':>5} "
        f"{'object':>7} {'band':>11} {'RMSE m':>7} {'head rad':>8} {'s':>6}"
    )
    for seed in args.seeds:
        spec = MonteCarloSpec(
            robots=args.robots,
            steps=args.steps,
            runs=args.runs,
            filters=tuple(args.filters),
            modes=tuple(args.modes),
            seed=seed,
            window=args.window,
            settings=settings,
            route="long",
        )
        begin = time.perf_counter()
        summary = run_montecarlo(spec, args.workers, progress=False)
        took = time.perf_counter() - begin
        for filt in args.filters:
            for mode in args.modes:
                r = summary["results"][filt][mode]
                thirds = np.array_split(np.asarray(r["anees_pose_per_frame"]), 3)
                by_third = " / ".join(f"{t.mean():.2f}" for t in thirds)
                band = "{:.2f}–{:.2f}".format(*r["band"])
                band_object = "{:.2f}–{:.2f}".format(*r["band_object"])
                print(
                    f"{seed:>5} {filt:<6} {mode:<10} {r['anees_pose']:6.2f} {by_third:>18} "
                    f"{band:>11} {r['runs_above_band']:>5} {r['anees_object']:7.2f} "
                    f"{band_object:>11} "
                    f"{r['position_rmse_m']:7.3f} {r['heading_rmse_rad']:8.4f} {took:6.0f}",
                    flush=True,
                )
                objects = bool(np.isfinite(r["anees_object"]))  # none with features only
                md.row(
                    str(seed),
                    f"`{filt}`",
                    mode,
                    f"{r['anees_pose']:.2f}",
                    by_third,
                    band,
                    f"{r['runs_above_band']} of {args.runs}",
                    f"{r['anees_object']:.2f}" if objects else "—",
                    band_object if objects else "—",
                    f"{r['position_rmse_m']:.3f}",
                    f"{r['heading_rmse_rad']:.4f}",
                )
    md.end()
    md.write()


if __name__ == "__main__":
    with threadpool_limits(1):
        main()
