"""Independent jobs of different lengths, some needing another's result, in one process pool.

Each :class:`Task` is a picklable callable; a task with ``needs`` is called with the result of
the task it names. Tasks start by the longest chain first — the estimated cost of the task plus
the longest chain of tasks that wait on it (list scheduling by "bottom level", Adam, Chandy &
Dickson 1974, "A comparison of list schedules for parallel processing systems", CACM 17(12)) —
and never more than ``workers`` at a time, so a long chain does not start last and the pool
ends with the short tasks. Every worker has BLAS pinned to one thread, as in
:func:`~teamslam.parallel.run_parallel`.

On a Dask cluster (``scheduler``) every task is submitted at once, its chain length as its
priority and the task it needs as its dependency; the scheduler runs a task again when its
worker is lost. With a :class:`~teamslam.eval.studies.RunStore` each task's result is kept as it
finishes, and the tasks stored already are read back instead of run (``--resume``).

Results do not depend on the order, the number of workers or where they run (each task is
deterministic on its inputs); only the times do. :class:`Schedule` keeps each task's CPU and
wall seconds and the worker that ran it.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Hashable, Iterable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from typing import Any

from threadpoolctl import threadpool_limits
from tqdm import tqdm

from teamslam._optional import require
from teamslam.errors import InputError
from teamslam.eval.studies import RunStore
from teamslam.parallel import (
    RETRIES,
    cluster_client,
    default_workers,
    init_worker,
    pinned,
    study_key,
    worker_name,
)

__all__ = ["Schedule", "Task", "run_tasks"]


@dataclass(frozen=True)
class Task:
    """One job of :func:`run_tasks`.

    Attributes
    ----------
    key
        Its name (unique among the tasks).
    call
        A picklable callable (a module-level function or a ``functools.partial`` of one),
        called without arguments, or with the result of ``needs``.
    cost
        Estimated CPU time, in any unit common to the tasks (only the order uses it).
    needs
        The key of the task whose result ``call`` takes, or ``None``.
    """

    key: Hashable
    call: Callable[..., Any]
    cost: float = 1.0
    needs: Hashable | None = None


@dataclass
class Schedule:
    """Where and how long each task ran.

    Attributes
    ----------
    cpu, wall
        Per task key: CPU seconds of its process and wall seconds.
    worker
        Per task key: the worker (0, 1, …) that ran it.
    order
        The task keys in the order they started.
    seconds
        Wall seconds of the whole run.
    workers
        Processes used.
    """

    cpu: dict[Hashable, float] = field(default_factory=dict)
    wall: dict[Hashable, float] = field(default_factory=dict)
    worker: dict[Hashable, int] = field(default_factory=dict)
    order: list[Hashable] = field(default_factory=list)
    seconds: float = 0.0
    workers: int = 1

    def worker_cpu(self) -> list[float]:
        """CPU seconds of the tasks each worker ran."""
        out = [0.0] * max(self.workers, 1 + max(self.worker.values(), default=0))
        for key, w in self.worker.items():
            out[w] += self.cpu[key]
        return out

    def critical_path(self) -> float:
        """The most CPU seconds one worker was given: the wall time of the run on a machine
        with a free core per worker (pool start and the results' transfer aside)."""
        return max(self.worker_cpu(), default=0.0)


def _timed(call: Callable[..., Any], *args: Any) -> tuple[Any, float, float, str]:
    cpu, wall = time.process_time(), time.perf_counter()
    result = call(*args)
    return result, time.process_time() - cpu, time.perf_counter() - wall, worker_name()


def _result(outcome: tuple[Any, float, float, str]) -> Any:
    return outcome[0]


def _priorities(tasks: dict[Hashable, Task]) -> dict[Hashable, float]:
    """Per task: its cost plus the longest chain of costs of the tasks waiting on it."""
    waiting: dict[Hashable, list[Hashable]] = {k: [] for k in tasks}
    for t in tasks.values():
        if t.needs is not None:
            waiting[t.needs].append(t.key)
    level: dict[Hashable, float] = {}

    def bottom(key: Hashable, seen: tuple = ()) -> float:
        if key in seen:
            raise InputError(f"tasks wait on each other in a cycle through {key!r}")
        if key not in level:
            below = [bottom(k, (*seen, key)) for k in waiting[key]]
            level[key] = tasks[key].cost + max(below, default=0.0)
        return level[key]

    for key in tasks:
        bottom(key)
    return level


def _after(call: Callable[..., Any], outcome: tuple) -> tuple[Any, float, float, str]:
    """:func:`_timed` of ``call`` on the result of the task it needs (on a cluster, whose
    tasks hand each other their whole outcome)."""
    return _timed(call, outcome[0])


def run_tasks(
    tasks: Iterable[Task],
    workers: int | None = None,
    progress: bool | None = None,
    description: str = "tasks",
    scheduler: str | None = None,
    store: RunStore | None = None,
) -> tuple[dict[Hashable, Any], Schedule]:
    """Run every task, longest chain first, at most ``workers`` at a time.

    Parameters
    ----------
    tasks
        The tasks; a task's ``needs`` must name another of them.
    workers
        Processes to use (default: all cores); ``1`` runs every task in this process. Ignored
        with ``scheduler``.
    progress
        Show a progress bar of the finished tasks; default: when standard error is a terminal.
    scheduler
        The address of a Dask scheduler: every task is submitted there at once, with its chain
        length as priority and the task it needs as a dependency (the ``cluster`` extra).
    store
        Keeps each task's result (and times) as it finishes; the tasks it holds already
        (``resume``) are read back, not run.

    Returns
    -------
    results, schedule
        Per task key its result, and where and how long each task ran.
    """
    by_key: dict[Hashable, Task] = {}
    for t in tasks:
        if t.key in by_key:
            raise InputError(f"two tasks named {t.key!r}")
        by_key[t.key] = t
    for t in by_key.values():
        if t.needs is not None and t.needs not in by_key:
            raise InputError(f"task {t.key!r} needs {t.needs!r}, which is not a task")
    level = _priorities(by_key)
    position = {k: n for n, k in enumerate(by_key)}
    workers = default_workers() if workers is None else max(1, int(workers))
    show = sys.stderr.isatty() if progress is None else progress
    bar = tqdm(total=len(by_key), desc=description, disable=not show, leave=False)
    results: dict[Hashable, Any] = {}
    schedule = Schedule(workers=workers)
    pids: dict[str, int] = {}
    waiting: dict[Hashable, list[Hashable]] = {k: [] for k in by_key}
    ready: list[Hashable] = []

    def next_task() -> Task:
        best = max(ready, key=lambda k: (level[k], -position[k]))
        ready.remove(best)
        schedule.order.append(best)
        return by_key[best]

    def finish(task: Task, outcome: tuple[Any, float, float, str], keep: bool = True) -> None:
        result, cpu, wall, pid = outcome
        if keep and store is not None:
            store.save(task.key, outcome)
        results[task.key] = result
        schedule.cpu[task.key] = cpu
        schedule.wall[task.key] = wall
        schedule.worker[task.key] = pids.setdefault(pid, len(pids))
        ready.extend(waiting[task.key])
        bar.update()

    def args(task: Task) -> tuple:
        return () if task.needs is None else (results[task.needs],)

    begin = time.perf_counter()
    try:
        stored = [k for k in by_key if store is not None and k in store]
        for key in stored:
            schedule.order.append(key)
            finish(by_key[key], store.load(key), keep=False)
        for t in by_key.values():
            if t.key in results:
                continue
            (ready if t.needs is None or t.needs in results else waiting[t.needs]).append(t.key)
        if scheduler is not None and not ready:
            pass  # every task was read back from the store
        elif scheduler is not None:
            with cluster_client(scheduler) as client:
                schedule.workers = sum(client.nthreads().values())
                prefix = study_key(description)
                submitted: dict[Hashable, Any] = {}
                try:
                    while ready:
                        task = next_task()
                        if task.needs is None:
                            call: tuple = (_timed, task.call)
                        elif task.needs in submitted:
                            call = (_after, task.call, submitted[task.needs])
                        else:  # its need was read back from the store
                            call = (_timed, task.call, client.scatter([results[task.needs]])[0])
                        submitted[task.key] = client.submit(
                            pinned,
                            *call,
                            key=f"{prefix}-{position[task.key]}",
                            priority=level[task.key],
                            retries=RETRIES,
                        )
                        # the tasks waiting on it go in now: the scheduler holds them back
                        ready.extend(waiting[task.key])
                        waiting[task.key] = []
                    keys = {future: key for key, future in submitted.items()}
                    what = "running on a Dask cluster"
                    as_completed = require("distributed", "cluster", what).as_completed
                    for future in as_completed(list(keys), loop=client.loop):
                        finish(by_key[keys[future]], future.result())
                finally:
                    client.cancel(list(submitted.values()))
        elif workers == 1:
            with threadpool_limits(1):
                while ready:
                    task = next_task()
                    finish(task, _timed(task.call, *args(task)))
        else:
            with ProcessPoolExecutor(max_workers=workers, initializer=init_worker) as pool:
                running: dict[Future, Task] = {}
                try:
                    while ready or running:
                        while ready and len(running) < workers:
                            task = next_task()
                            running[pool.submit(_timed, task.call, *args(task))] = task
                        done, _ = wait(running, return_when=FIRST_COMPLETED)
                        for future in done:
                            finish(running.pop(future), future.result())
                finally:
                    for future in running:
                        future.cancel()
    finally:
        bar.close()
    schedule.seconds = time.perf_counter() - begin
    return results, schedule
