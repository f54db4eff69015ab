"""Throughput of the batched Lie-group maps against scipy's Rotation.

Run on demand: ``OPENBLAS_NUM_THREADS=1 python benchmarks/geometry_speed.py``.
Prints the median time per call over repeated runs and the ratio to scipy.
"""

from __future__ import annotations

import statistics
import time

import numpy as np
from scipy.spatial.transform import Rotation

from teamslam.geometry import se3, so3


def median_time(fn, arg, repeats: int = 15) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn(arg)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    rng = np.random.default_rng(0)
    print(f"{'operation':<28} {'batch':>7} {'teamslam':>12} {'scipy':>12} {'ratio':>7}")
    for batch in (1, 100, 10_000):
        phi = rng.normal(size=(batch, 3))
        mats = so3.exp(phi)
        rows = [
            ("so3.exp", phi, so3.exp, lambda p: Rotation.from_rotvec(p).as_matrix()),
            ("so3.log", mats, so3.log, lambda m: Rotation.from_matrix(m).as_rotvec()),
        ]
        for name, arg, ours, theirs in rows:
            a, b = median_time(ours, arg), median_time(theirs, arg)
            print(f"{name:<28} {batch:>7} {a * 1e6:>10.1f}µs {b * 1e6:>10.1f}µs {a / b:>7.2f}")
        xi = rng.normal(size=(batch, 6))
        poses = se3.exp(xi)
        for name, arg, fn in (
            ("se3.exp", xi, se3.exp),
            ("se3.log", poses, se3.log),
            ("se3.right_jacobian", xi, se3.right_jacobian),
            ("se3.adjoint", poses, se3.adjoint),
        ):
            a = median_time(fn, arg)
            print(f"{name:<28} {batch:>7} {a * 1e6:>10.1f}µs {'-':>12} {'-':>7}")


if __name__ == "__main__":
    main()
