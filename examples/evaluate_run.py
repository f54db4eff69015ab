"""Evaluate a run: APE and RPE of every robot's trajectory against ground truth, the figures,
and the HTML report.

    python examples/evaluate_run.py --run results/team5-run --out results/team5-eval
    python examples/evaluate_run.py --steps 100 --out results/example-eval   # makes a run first

A run directory (``teamslam run --out``, or :func:`teamslam.write_run`) holds TUM trajectories
and the ground truth they estimate. APE is the error of each pose after an alignment of the
estimate to the truth (``none``: a filter that starts at the true pose should need none;
``se3``: a rigid motion fitted to the whole team); RPE is the error of the motion over
``rpe_delta`` frames, free of drift.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import teamslam as ts
from teamslam import api
from teamslam.eval.report import evaluation_table, write_report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=None, help="a run directory to evaluate")
    parser.add_argument("--robots", type=int, default=3, help="without --run: team size")
    parser.add_argument("--steps", type=int, default=100, help="without --run: steps per robot")
    parser.add_argument("--out", type=Path, default=Path("results/example-eval"))
    args = parser.parse_args(argv)

    run_dir = args.run
    if run_dir is None:
        # no run at hand: simulate a team and run both filters into out/run
        dataset = ts.sim.lissajous_team(robots=args.robots, steps=args.steps, seed=1)
        run_dir = args.out / "run"
        ts.run(dataset, mode="compare", out=run_dir, report=False, progress=False)
        print(f"ran {dataset.name} into {run_dir}")

    for align in ("none", "se3"):
        # eval.json (every statistic) and three figures: trajectories, APE over time and
        # along the path; the returned dict also holds them for the table
        result = api.evaluate([run_dir], out=args.out / f"align-{align}", align=align)
        print(f"\nalignment: {align}")
        print(evaluation_table(result["names"], result["statistics"]))

    # one self-contained HTML page: summary, accuracy (APE/RPE with figures), consistency
    # (NEES), health, timing and messages of every filter of the run
    report = write_report([run_dir], args.out / "report.html")
    print(f"\nwrote {args.out}/align-*/eval.json and figures, and {report}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
