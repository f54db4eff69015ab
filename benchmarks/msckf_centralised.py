"""Why one distributes: the centralised MSCKF's cost per team step against team size.

One server holding every robot's window and every object (``teamslam run --centralised``) vs
the distributed MSCKF with consensus, where each robot computes only its own filter. Run on
demand (BLAS pinned to one thread)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_centralised.py [--robots 3 5 10 20 30] \\
        [--steps 60] [--window 10] [--objects-only]

Prints per team size: the centralised filter's median wall time per team step (every robot's
frame processed in one state), the distributed filter's median time per robot-step (what each
robot's computer does, in parallel with the others) and its sum over the team, the ratio of
centralised to per-robot time, and both trajectory RMSEs (team average). The graph is complete
for the distributed team, the setting where consensus costs most.
"""

from __future__ import annotations

import argparse

import numpy as np

from teamslam.eval.metrics import team_metrics
from teamslam.msckf import config_for, run_team
from teamslam.msckf.centralised import run_centralised
from teamslam.sim import lissajous_team


def _per_step_ms(result) -> tuple[np.ndarray, np.ndarray]:
    """Per robot-step times (ms, first frame left out) and per team step sums (ms)."""
    times = [1e3 * f[1:].sum(axis=1) for f in result.frame_times]
    steps = min(t.size for t in times)
    team = np.sum([t[:steps] for t in times], axis=0)
    return np.concatenate(times), team


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, nargs="+", default=[3, 5, 10, 20, 30])
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--window", type=int, default=10)
    parser.add_argument("--objects-only", action="store_true")
    args = parser.parse_args()
    print(
        f"{args.steps} steps, window {args.window}, "
        f"{'objects only' if args.objects_only else 'geometric features and objects'}"
    )
    print(
        f"{'robots':>6} {'central ms/team-step':>21} {'dist ms/robot-step':>19} "
        f"{'dist ms/team-step':>18} {'central/robot':>14} {'central RMSE':>13} "
        f"{'dist RMSE':>10}"
    )
    for n in args.robots:
        ds = lissajous_team(robots=n, steps=args.steps, seed=0)
        cfg = config_for(
            ds,
            {"filter.window": args.window, "filter.use_geometric_features": not args.objects_only},
        )
        central = run_centralised(ds, cfg, progress=False)
        distributed = run_team(ds, cfg, consensus=True, progress=False)
        _, central_team = _per_step_ms(central)
        per_robot, dist_team = _per_step_ms(distributed)
        c, r = float(np.median(central_team)), float(np.median(per_robot))
        print(
            f"{n:>6} {c:21.1f} {r:19.2f} {float(np.median(dist_team)):18.1f} "
            f"{c / r:14.1f} {team_metrics(ds, central)['trajectory_rmse_avg_m']:13.4f} "
            f"{team_metrics(ds, distributed)['trajectory_rmse_avg_m']:10.4f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
