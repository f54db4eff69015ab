"""Seeded Monte Carlo runs in parallel over processes, with a progress bar.

Each run is a call ``job(seed)`` returning any picklable result; runs are spread over
``workers`` processes (default: all cores), each with BLAS pinned to one thread — small-matrix
filters are latency-bound and multi-threaded BLAS only slows them down — and come back in seed
order, so a study is reproducible whatever the number of workers.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import TypeVar

from threadpoolctl import threadpool_limits
from tqdm import tqdm

__all__ = ["default_workers", "init_worker", "run_parallel"]

T = TypeVar("T")


def default_workers() -> int:
    """Number of usable cores."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def init_worker() -> None:
    threadpool_limits(1)


def run_parallel(
    job: Callable[[int], T],
    seeds: Sequence[int],
    workers: int | None = None,
    progress: bool | None = None,
    description: str = "runs",
) -> list[T]:
    """``[job(s) for s in seeds]``, computed in parallel, in seed order.

    Parameters
    ----------
    job
        A picklable callable (a module-level function or a ``functools.partial`` of one).
    seeds
        One seed per run.
    workers
        Processes to use; ``1`` runs in this process.
    progress
        Show a progress bar; default: when standard error is a terminal.
    """
    workers = default_workers() if workers is None else max(1, int(workers))
    show = sys.stderr.isatty() if progress is None else progress
    bar = tqdm(total=len(seeds), desc=description, disable=not show, leave=False)
    results: list[T] = []
    try:
        if workers == 1 or len(seeds) <= 1:
            with threadpool_limits(1):
                for s in seeds:
                    results.append(job(s))
                    bar.update()
            return results
        chunk = max(1, len(seeds) // (4 * workers))
        with ProcessPoolExecutor(max_workers=workers, initializer=init_worker) as pool:
            for result in pool.map(job, seeds, chunksize=chunk):
                results.append(result)
                bar.update()
        return results
    finally:
        bar.close()
