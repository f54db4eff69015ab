"""A lying member: the honest robots' accuracy with the consensus innovation check on and off.

Run on demand (BLAS pinned to one thread)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/lying_member.py [--robots 4] [--steps 150] \\
        [--seed 0] [--window 10] [--liar 2]

A simulated team with global object ids; robot ``liar`` has valid credentials and sends, in its
own name, every marginal 20 m off with a 1 mm standard deviation
(:class:`~teamslam.msckf.consensus.transport.LyingNetwork`). Prints, with the check off and on
(``consensus.innovation_check``), the honest robots' mean trajectory RMSE in the clean team (the
liar honest), in the attacked team, and in the team without the liar — the best any check can
give, since the liar sends nothing true — and the marginals left out.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from teamslam.eval.metrics import trajectory_rmse
from teamslam.graph import complete
from teamslam.msckf import config_for, run_team
from teamslam.msckf.consensus.transport import LyingNetwork
from teamslam.msckf.team import lockstep_drivers, run_drivers
from teamslam.sim import lissajous_team


def _team_run(dataset, config, liar):
    network = LyingNetwork(dataset.n_robots, liar)
    graph = complete(dataset.n_robots)
    drivers = lockstep_drivers(dataset, [config] * dataset.n_robots, network, graph)
    return run_drivers(drivers, graph.name, 0.0, progress=False)


def _rmse(result, dataset, robots) -> float:
    return float(
        np.mean([trajectory_rmse(result.poses[k], dataset.robots[k].T_world_body) for k in robots])
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=4)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--window", type=int, default=10)
    parser.add_argument("--liar", type=int, default=2)
    args = parser.parse_args()
    team = lissajous_team(robots=args.robots, steps=args.steps, seed=args.seed)
    honest = [i for i in range(args.robots) if i != args.liar]
    without = team.subset(honest)
    print(f"{args.robots} robots x {args.steps} steps (seed {args.seed}), liar robot {args.liar}")
    for check in (False, True):
        config = config_for(
            team, {"filter.window": args.window, "consensus.innovation_check": check}
        )
        begin = time.perf_counter()
        clean = _team_run(team, config, None)
        seconds = time.perf_counter() - begin
        lied = _team_run(team, config, args.liar)
        alone = run_team(without, config, progress=False)
        c, a = _rmse(clean, team, honest), _rmse(alone, without, range(len(honest)))
        lie = _rmse(lied, team, honest)
        left = [x.get("consensus_marginals_left_out", 0) for x in lied.counters]
        left_clean = [x.get("consensus_marginals_left_out", 0) for x in clean.counters]
        print(
            f"check {'on ' if check else 'off'}: honest robots' RMSE clean {c:.4f} m "
            f"({seconds:.1f} s), attacked {lie:.4f} m (x{lie / c:.3f} of clean, x{lie / a:.3f} "
            f"of the team without the liar, {a:.4f} m); marginals left out attacked {left}, "
            f"clean {left_clean}"
        )


if __name__ == "__main__":
    with threadpool_limits(limits=1):
        main()
