"""A Monte Carlo cell on a Dask cluster against the same cell on local processes: wall time and
bit-identity.

Run from the repository root (the ``cluster`` extra installed)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/cluster.py [--robots 3] [--steps 40] [--runs 20] \
        [--workers 2] [--repeats 2] [--markdown FILE]

Each repeat runs ``teamslam montecarlo`` (a fresh process, as a user would) three ways, one
after another: ``--workers N`` (local processes); ``--scheduler`` of a ``LocalCluster`` of ``N``
worker processes with one thread each; ``--scheduler`` of a ``dask scheduler`` and a
``dask worker --nworkers N --nthreads 1`` started as processes, as a user starts them by hand.
Both clusters are started before the first repeat and kept up (their workers import teamslam
with the first study). Prints and writes per way the wall times, their median, the overhead
of the median over the local one, and whether ``montecarlo.json`` (its ``wall_seconds`` aside)
and every run's arrays are those of the first local run, bit for bit.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _markdown import Markdown, add_option
from teamslam.eval.studies import load_arrays

#: Seconds to wait for the hand-started scheduler to write its address.
START_SECONDS = 120.0


def _same(a: Path, b: Path) -> bool:
    """The same summary (wall time aside) and the same runs, bit for bit."""
    summaries = []
    for d in (a, b):
        s = json.loads((d / "montecarlo.json").read_text())
        s.pop("wall_seconds")
        summaries.append(json.dumps(s))
    if summaries[0] != summaries[1]:
        return False
    names = sorted(p.name for p in (a / "runs").glob("run_*.npz"))
    if names != sorted(p.name for p in (b / "runs").glob("run_*.npz")):
        return False
    for name in names:
        x, y = (load_arrays(d / "runs" / name) for d in (a, b))
        for key, arrays in x.items():
            for field, values in arrays.items():
                if not np.array_equal(values, y[key][field]) or values.dtype != y[key][field].dtype:
                    return False
    return True


def _dask(args: list[str], log: Path) -> subprocess.Popen:
    with log.open("w") as f:
        return subprocess.Popen(
            [sys.executable, "-m", "dask", *args], stdout=f, stderr=subprocess.STDOUT
        )


def _hand_started(workers: int, tmp: Path) -> tuple[str, list[subprocess.Popen]]:
    """``dask scheduler`` and ``dask worker --nworkers N --nthreads 1`` on loopback."""
    address_file = tmp / "scheduler.json"
    scheduler = _dask(
        [
            *("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard"),
            *("--scheduler-file", str(address_file)),
        ],
        tmp / "scheduler.log",
    )
    end = time.monotonic() + START_SECONDS
    while not address_file.is_file():
        if scheduler.poll() is not None or time.monotonic() > end:
            raise SystemExit(f"dask scheduler did not start: {(tmp / 'scheduler.log').read_text()}")
        time.sleep(0.1)
    address = json.loads(address_file.read_text())["address"]
    worker = _dask(
        [
            *("worker", address, "--nworkers", str(workers), "--nthreads", "1"),
            *("--host", "127.0.0.1", "--no-dashboard"),
        ],
        tmp / "worker.log",
    )
    return address, [scheduler, worker]


def _study(cell: list[str], where: list[str], out: Path) -> float:
    """Wall seconds of one ``teamslam montecarlo`` process."""
    begin = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "teamslam", "montecarlo", *cell, *where, "--out", str(out)],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return time.perf_counter() - begin


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--filters", default="std,fej")
    parser.add_argument("--modes", default="separate,consensus")
    parser.add_argument("--workers", type=int, default=2, help="local processes, cluster workers")
    parser.add_argument("--repeats", type=int, default=2)
    add_option(parser)
    args = parser.parse_args()
    md = Markdown(args.markdown)
    from distributed import LocalCluster

    cell = [
        *("--robots", str(args.robots), "--steps", str(args.steps), "--runs", str(args.runs)),
        *("--filters", args.filters, "--modes", args.modes),
    ]
    n = args.workers
    ways = {
        f"local, --workers {n}": None,
        f"LocalCluster, {n} worker processes × 1 thread": "local-cluster",
        f"dask scheduler + dask worker --nworkers {n} --nthreads 1": "processes",
    }
    times: dict[str, list[float]] = {way: [] for way in ways}
    same: dict[str, bool] = {way: True for way in ways}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        hand_address, processes = _hand_started(n, tmp)
        try:
            with LocalCluster(
                n_workers=n,
                processes=True,
                threads_per_worker=1,
                host="127.0.0.1",
                dashboard_address=None,
            ) as local_cluster:
                address = {"local-cluster": local_cluster.scheduler_address}
                address["processes"] = hand_address
                reference = None
                for repeat in range(args.repeats):
                    for way, kind in ways.items():
                        where = ["--workers", str(n)] if kind is None else []
                        where += [] if kind is None else ["--scheduler", address[kind]]
                        out = tmp / f"{kind or 'local'}-{repeat}"
                        seconds = _study(cell, where, out)
                        times[way].append(seconds)
                        reference = reference or out
                        same[way] &= _same(reference, out)
                        print(f"{way}: {seconds:.1f} s", flush=True)
        finally:
            for p in reversed(processes):
                p.send_signal(signal.SIGTERM)
            for p in reversed(processes):
                try:
                    p.wait(60)
                except subprocess.TimeoutExpired:
                    p.kill()
    base = statistics.median(times[next(iter(ways))])
    md.table(
        f"teamslam montecarlo {' '.join(cell)}: wall seconds per study",
        ["run on", "wall s (each repeat)", "median s", "over local", "same JSON and runs"],
        note=f"{args.repeats} repeats, the ways in turn; each study a fresh `teamslam` process; "
        "the clusters started before the first study and kept up; same: `montecarlo.json` "
        "(wall time aside) and every run's arrays equal to the first local study's, bit for bit",
    )
    print(f"{'run on':<58}{'median s':>10}{'over local':>12}  same")
    for way in ways:
        median = statistics.median(times[way])
        over = f"{100 * (median / base - 1):+.1f}%"
        print(f"{way:<58}{median:>10.1f}{over:>12}  {'yes' if same[way] else 'NO'}")
        each = ", ".join(f"{t:.1f}" for t in times[way])
        md.row(way, each, f"{median:.1f}", over, "yes" if same[way] else "no")
    md.end()
    md.write()
    if not all(same.values()):
        raise SystemExit("a cluster study differs from the local one")


if __name__ == "__main__":
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    main()
