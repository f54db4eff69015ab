"""Seeded Monte Carlo runs in parallel over processes or a Dask cluster, with a progress bar.

Each run is a call ``job(seed)`` returning any picklable result; runs are spread over
``workers`` processes (default: all cores), or submitted to a ``dask.distributed`` scheduler
(``scheduler``: its address, the ``cluster`` extra), each run one task. Every run has BLAS
pinned to one thread — small-matrix filters are latency-bound and multi-threaded BLAS only
slows them down — and the results come back in seed order, so a study is reproducible, bit for
bit, whatever the number of workers or where they run: a run depends on its seed only.

On a cluster a run whose worker is lost is run again on another (the scheduler does this; a
run is a pure function of its seed, so running it twice changes nothing); ``on_result`` sees
each run once, as it finishes, so that a caller can keep it (:mod:`teamslam.eval.studies`).
"""

from __future__ import annotations

import os
import socket
import sys
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from typing import Any, TypeVar

from threadpoolctl import threadpool_limits
from tqdm import tqdm

from teamslam._optional import require
from teamslam.errors import InputError

__all__ = [
    "CONNECT_SECONDS",
    "RETRIES",
    "WORKER_SECONDS",
    "cluster_client",
    "default_workers",
    "init_worker",
    "pinned",
    "run_parallel",
    "study_key",
    "worker_name",
]

T = TypeVar("T")

#: Seconds to wait for a Dask scheduler to answer.
CONNECT_SECONDS = 10.0
#: Seconds to wait then for its first worker (a worker starting may take a while to import).
WORKER_SECONDS = 120.0
#: Times a run that raised on a worker is tried again elsewhere (a worker that dies is another
#: matter: the scheduler reruns its tasks by itself, up to ``distributed.scheduler.
#: allowed-failures`` times).
RETRIES = 2


def default_workers() -> int:
    """Number of usable cores."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def init_worker() -> None:
    threadpool_limits(1)


def pinned(call: Callable[..., T], *args: Any) -> T:
    """``call(*args)`` with BLAS on one thread (a run on a Dask worker, whose BLAS is not
    pinned by an initialiser as a local pool's is)."""
    with threadpool_limits(1):
        return call(*args)


def worker_name() -> str:
    """This process's host and process id: which worker ran a task."""
    return f"{socket.gethostname()}:{os.getpid()}"


def _version() -> str:
    from teamslam._version import __version__

    return __version__


@contextmanager
def cluster_client(address: str) -> Iterator[Any]:
    """A ``distributed.Client`` of the Dask scheduler at ``address``, closed on exit.

    Raises
    ------
    MissingExtra
        The ``cluster`` extra is not installed.
    InputError
        ``address`` is no address, no scheduler answers there within :data:`CONNECT_SECONDS`,
        it has no worker within :data:`WORKER_SECONDS`, or a worker runs another version of
        teamslam.
    """
    distributed = require("distributed", "cluster", "running on a Dask cluster")
    comm = require("distributed.comm", "cluster", "running on a Dask cluster")
    try:
        scheme, location = comm.parse_address(address)
        if scheme in ("tcp", "tls", "ws", "wss"):
            comm.parse_host_port(location)
    except (ValueError, TypeError) as exc:
        raise InputError(f"--scheduler {address!r} is no Dask scheduler address ({exc})") from None
    try:
        client = distributed.Client(address, timeout=CONNECT_SECONDS, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"no Dask scheduler answers at {address}: {first}") from None
    try:
        try:
            client.wait_for_workers(1, timeout=WORKER_SECONDS)
        except (OSError, TimeoutError) as exc:
            raise InputError(
                f"the Dask scheduler at {address} has no worker after {WORKER_SECONDS:g} s"
            ) from exc
        ours = _version()
        try:
            others = {v for v in client.run(_version).values() if v != ours}
        except ImportError as exc:
            raise InputError(f"workers of {address} cannot import teamslam ({exc})") from None
        if others:
            raise InputError(
                f"workers of {address} run teamslam {', '.join(sorted(others))}, this is "
                f"{ours}: the results would not be this version's"
            )
        yield client
    finally:
        client.close()


def study_key(description: str) -> str:
    """A prefix for the Dask keys of one study's tasks: unique, so that two studies sharing a
    scheduler never share a result."""
    import uuid

    return f"teamslam-{description.replace(' ', '-')}-{uuid.uuid4().hex[:12]}"


def _on_cluster(
    address: str,
    job: Callable[[int], T],
    seeds: Sequence[int],
    bar: tqdm,
    description: str,
    on_result: Callable[[int, T], None] | None,
) -> list[T]:
    as_completed = require("distributed", "cluster", "running on a Dask cluster").as_completed
    prefix = study_key(description)
    with cluster_client(address) as client:
        futures = {
            client.submit(pinned, job, s, key=f"{prefix}-{n}", retries=RETRIES): n
            for n, s in enumerate(seeds)
        }
        results: list[Any] = [None] * len(seeds)
        try:
            for future in as_completed(futures, loop=client.loop):
                n = futures[future]
                results[n] = future.result()
                future.release()
                if on_result is not None:
                    on_result(seeds[n], results[n])
                bar.update()
        finally:
            client.cancel(list(futures))
    return results


def run_parallel(
    job: Callable[[int], T],
    seeds: Sequence[int],
    workers: int | None = None,
    progress: bool | None = None,
    description: str = "runs",
    scheduler: str | None = None,
    on_result: Callable[[int, T], None] | None = None,
) -> list[T]:
    """``[job(s) for s in seeds]``, computed in parallel, in seed order.

    Parameters
    ----------
    job
        A picklable callable (a module-level function or a ``functools.partial`` of one); on a
        cluster, importable by the workers (teamslam installed there, the same version).
    seeds
        One seed per run.
    workers
        Processes to use; ``1`` runs in this process. Ignored with ``scheduler``.
    progress
        Show a progress bar of the finished runs; default: when standard error is a terminal.
    scheduler
        The address of a Dask scheduler (``tcp://host:8786``): each run is a task there.
    on_result
        Called here with ``(seed, result)`` of each run once, as it finishes (in seed order
        on this machine, in the order they finish on a cluster).

    Raises
    ------
    InputError
        No scheduler answers at ``scheduler`` (:func:`cluster_client`).
    """
    workers = default_workers() if workers is None else max(1, int(workers))
    show = sys.stderr.isatty() if progress is None else progress
    bar = tqdm(total=len(seeds), desc=description, disable=not show, leave=False)
    results: list[T] = []
    try:
        if scheduler is not None and seeds:
            return _on_cluster(scheduler, job, seeds, bar, description, on_result)
        if workers == 1 or len(seeds) <= 1:
            with threadpool_limits(1):
                for s in seeds:
                    results.append(job(s))
                    if on_result is not None:
                        on_result(s, results[-1])
                    bar.update()
            return results
        chunk = max(1, len(seeds) // (4 * workers))
        with ProcessPoolExecutor(max_workers=workers, initializer=init_worker) as pool:
            for s, result in zip(seeds, pool.map(job, seeds, chunksize=chunk), strict=True):
                results.append(result)
                if on_result is not None:
                    on_result(s, result)
                bar.update()
        return results
    finally:
        bar.close()
