"""A team of robot processes on loopback: one process per robot, consensus messages over Zenoh,
the same estimates as the team run in one process.

    python examples/team_of_processes.py --robots 3 --steps 60 --out results/example-processes

Needs the ``network`` extra (Zenoh): ``pip install 'teamslam[network]'``.

``ts.run(..., processes=True)`` writes a team file (``OUT/team.yaml``: the dataset, each
robot's endpoint ``tcp/127.0.0.1:PORT`` and its neighbours, the filter settings), starts
``teamslam agent`` once per robot, waits for them and gathers their results. On real robots
each runs ``teamslam agent --team team.yaml --robot I`` with its own endpoint in the file
(``teamslam team launch`` starts them all on one machine). The robots step in lock-step, so
without message loss they compute what the in-process team computes.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import teamslam as ts


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=3, help="team size (default 3)")
    parser.add_argument("--steps", type=int, default=60, help="steps per robot (default 60)")
    parser.add_argument("--base-port", type=int, default=17400, help="robot i listens on +i")
    parser.add_argument("--out", type=Path, default=Path("results/example-processes"))
    args = parser.parse_args(argv)

    # robot processes read the dataset from disk: save it first
    dataset = ts.sim.lissajous_team(robots=args.robots, steps=args.steps, seed=3)
    directory = ts.datasets.save_dataset(dataset, args.out / "dataset")

    # one process per robot on loopback (consensus over a complete graph, the default)
    run = ts.run(directory, processes=True, out=args.out / "processes", base_port=args.base_port)
    codes = dict(sorted(run.exit_codes.items()))
    print(f"robot processes exited with {codes}; team file {args.out}/processes/team.yaml")
    for line in run.warnings + run.notes:
        print(f"  {line}")
    if run.exit_status != 0:
        return run.exit_status

    # the same team in this process, for comparison
    alone = ts.run(dataset, mode="consensus", progress=False)
    gap = max(
        float(np.abs(p[:, :3, 3] - q[:, :3, 3]).max())
        for p, q in zip(
            run.results["consensus"].poses, alone.results["consensus"].poses, strict=True
        )
    )
    for name, metrics in (("processes", run.metrics), ("one process", alone.metrics)):
        print(
            f"{name:>12}: trajectory RMSE {metrics['trajectory_rmse_avg_m']:.4f} m "
            f"(odometry {metrics['odometry_rmse_avg_m']:.4f} m), "
            f"map disagreement {metrics['object_disagreement_avg_m']:.4f} m"
        )
    print(f"largest difference of a position between the two: {gap:.2e} m")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
