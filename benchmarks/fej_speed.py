"""Speed of the planar multi-robot EKF: time per Monte Carlo run and the whole of Table 1.

Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/fej_speed.py            # per-run times + Table 1
    OPENBLAS_NUM_THREADS=1 python benchmarks/fej_speed.py --quick    # per-run times only

Prints the median time of one Monte Carlo run per filter and feature count (one process, BLAS
pinned to one thread), the Victoria Park split per filter when the data is present, and the wall
time of the whole Table 1 (100 runs × 3 filters × 3 feature counts) over all cores.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from teamslam.ekf2d.environments import environment
from teamslam.ekf2d.experiments import monte_carlo
from teamslam.ekf2d.linearization import policy
from teamslam.ekf2d.run import run_filter
from teamslam.ekf2d.simulate import simulate, truth_of

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def per_run(repeats: int = 7) -> None:
    print(f"{'env':<5} {'features':>8} {'filter':>7} {'median s/run':>13}")
    for number in (1, 2):
        for features in (20, 60, 100):
            env = environment(number, features)
            truth = truth_of(env)
            for name in ("std", "ideal", "fej"):
                times = []
                for seed in range(repeats):
                    run = simulate(env, truth, np.random.default_rng(seed))
                    start = time.perf_counter()
                    run_filter(env, run, policy(name))
                    times.append(time.perf_counter() - start)
                print(f"{number:<5} {features:>8} {name:>7} {statistics.median(times):>13.4f}")


def victoria_park() -> None:
    if not (DATA / "victoria-park").is_dir():
        print("Victoria Park data not found; skipped")
        return
    from teamslam.datasets.victoria_park import load_victoria_park
    from teamslam.ekf2d.victoria_park import run_victoria_park

    split = load_victoria_park(DATA / "victoria-park")
    for name in ("std", "fej"):
        result = run_victoria_park(split, name)
        print(f"Victoria Park {name}: {result.seconds:.2f} s")


def table_1() -> None:
    start = time.perf_counter()
    for features in (20, 60, 100):
        monte_carlo(environment(1, features), runs=100, progress=False)
    print(
        f"Table 1 (100 runs × 3 filters × 3 feature counts, all cores): "
        f"{time.perf_counter() - start:.1f} s"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="skip the whole-table timing")
    args = parser.parse_args()
    with threadpool_limits(1):
        per_run()
        victoria_park()
    if not args.quick:
        table_1()


if __name__ == "__main__":
    main()
