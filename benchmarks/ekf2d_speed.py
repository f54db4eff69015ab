"""Speed of the planar multi-robot EKF on the two workloads of the FEJ paper.

Run on demand::

    python benchmarks/ekf2d_speed.py                          # medians
    python benchmarks/ekf2d_speed.py --save before.json       # keep the medians
    python benchmarks/ekf2d_speed.py --baseline before.json   # medians and ratios to a saved run

Prints the median wall time and, on a ``(cpu)`` row, the median CPU time of the process (less
sensitive to other jobs on a shared machine), BLAS pinned to one thread, of

* one Monte Carlo run of environment 1 with 20 features (315 steps, :func:`run_filter`: start,
  every step, every step's scoring), for each of the standard, first-estimate and ideal EKFs,
  each over ``--repeats`` seeds;
* one Victoria Park filter run (2 robots, 2,545 steps, 287 features; loading excluded) for the
  standard and first-estimate EKFs, when the data is at ``../shared/data/victoria-park``.

Targets: one environment-1 run ≤ 0.02 s, one Victoria Park run ≤ 1 s. Every workload is run
once untimed first, so one-time costs (imports, loading the compiled kernels of
:mod:`teamslam.ekf2d.kernels`) are not in the medians.

With ``--baseline`` a column gives ``baseline / now`` (the speed-up) for every row both runs
measured; to compare with an older version, run this script with that version importable
(e.g. ``PYTHONPATH=<its src>``) and ``--save``. The machine may be shared: medians of several
repeats, not single times.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from teamslam.ekf2d.environments import environment
from teamslam.ekf2d.linearization import policy
from teamslam.ekf2d.run import run_filter
from teamslam.ekf2d.simulate import simulate, truth_of

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def _timed(fn, *args) -> tuple[float, float]:
    """Wall and CPU seconds of one call."""
    wall, cpu = time.perf_counter(), time.process_time()
    fn(*args)
    return time.perf_counter() - wall, time.process_time() - cpu


def _store(out: dict[str, float], key: str, times: list[tuple[float, float]]) -> None:
    out[key] = statistics.median(t[0] for t in times)
    out[f"{key} (cpu)"] = statistics.median(t[1] for t in times)


def monte_carlo_runs(repeats: int) -> dict[str, float]:
    """Median seconds of one env-1 / 20-feature run per filter."""
    env = environment(1, 20)
    truth = truth_of(env)
    runs = [simulate(env, truth, np.random.default_rng(seed)) for seed in range(repeats)]
    out = {}
    for name in ("std", "fej", "ideal"):
        run_filter(env, runs[0], policy(name))  # warm-up (imports, first-call caches)
        times = []
        for run in runs:
            times.append(_timed(run_filter, env, run, policy(name)))
        _store(out, f"env1-20f {name}", times)
    return out


def victoria_park_runs(repeats: int) -> dict[str, float]:
    """Median seconds of one Victoria Park run per filter (empty without the data)."""
    directory = DATA / "victoria-park"
    if not directory.is_dir():
        print(f"Victoria Park data not found at {directory}; skipped")
        return {}
    from teamslam.datasets.victoria_park import load_victoria_park
    from teamslam.ekf2d.victoria_park import run_victoria_park

    split = load_victoria_park(directory)
    out = {}
    for name in ("std", "fej"):
        run_victoria_park(split, name)  # warm-up
        times = []
        for _ in range(repeats):
            times.append(_timed(run_victoria_park, split, name))
        _store(out, f"victoria-park {name}", times)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15, help="Monte Carlo seeds timed")
    parser.add_argument("--vp-repeats", type=int, default=3, help="Victoria Park runs timed")
    parser.add_argument("--save", type=Path, help="write the medians to this JSON file")
    parser.add_argument("--baseline", type=Path, help="JSON of an earlier run to compare with")
    args = parser.parse_args()
    with threadpool_limits(1):
        medians = monte_carlo_runs(args.repeats)
        medians.update(victoria_park_runs(args.vp_repeats))
    baseline = json.loads(args.baseline.read_text()) if args.baseline else {}
    head = f"{'workload':<28} {'median s':>10}"
    if baseline:
        head += f" {'baseline s':>11} {'speed-up':>9}"
    print(head)
    for key, seconds in medians.items():
        line = f"{key:<28} {seconds:>10.4f}"
        if key in baseline:
            line += f" {baseline[key]:>11.4f} {baseline[key] / seconds:>8.1f}×"
        print(line)
    if args.save:
        args.save.write_text(json.dumps(medians, indent=1) + "\n")


if __name__ == "__main__":
    main()
