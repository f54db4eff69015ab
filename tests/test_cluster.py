"""Studies on a Dask cluster on loopback: a ``LocalCluster`` of two worker processes, and a
scheduler and workers started as ``dask scheduler`` / ``dask worker`` processes, give the same
result as the local run, bit for bit (a team study, paper pieces, the FEJ Monte Carlo); a worker
killed mid-study loses nothing.

Worker processes on loopback ports: a ``network`` module (tests/conftest.py), run alone.
"""

from __future__ import annotations

import json
import operator
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from teamslam.cli import main
from teamslam.eval.studies import load_arrays

pytest.importorskip("distributed")

CELL = [
    *("montecarlo", "--robots", "2", "--steps", "8", "--runs", "6"),
    *("--filters", "std,fej", "--modes", "separate,consensus", "--json"),
]
#: Bounds every wait of this module (processes starting, a study on two workers).
DEADLINE = 300.0


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=2,
        processes=True,
        threads_per_worker=1,
        host="127.0.0.1",
        dashboard_address=None,
    ) as local:
        yield local


@pytest.fixture(scope="module")
def local_study(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("local")
    assert main([*CELL, "--workers", "2", "--out", str(out)]) == 0
    return out


def _same_study(a: Path, b: Path) -> None:
    """The same montecarlo.json (its wall time aside) and the same runs, bit for bit."""
    summaries = [json.loads((d / "montecarlo.json").read_text()) for d in (a, b)]
    for s in summaries:
        s.pop("wall_seconds")
    assert json.dumps(summaries[0]) == json.dumps(summaries[1])
    names = sorted(p.name for p in (a / "runs").glob("run_*.npz"))
    assert names == sorted(p.name for p in (b / "runs").glob("run_*.npz")) and len(names) == 6
    for name in names:
        runs = [load_arrays(d / "runs" / name) for d in (a, b)]
        for key, arrays in runs[0].items():
            for field, values in arrays.items():
                np.testing.assert_array_equal(values, runs[1][key][field], strict=True)


def test_run_parallel_on_a_cluster_counts_and_keeps_every_run(cluster, monkeypatch):
    import teamslam.parallel
    from teamslam.parallel import run_parallel

    counted: list[tuple[int, int]] = []

    class Bar(teamslam.parallel.tqdm):
        def close(self):
            counted.append((self.n, self.total))
            super().close()

    monkeypatch.setattr(teamslam.parallel, "tqdm", Bar)
    seen: list[tuple[int, int]] = []
    results = run_parallel(
        operator.neg,
        [3, 1, 2],
        progress=True,
        scheduler=cluster.scheduler_address,
        on_result=lambda seed, result: seen.append((seed, result)),
    )
    assert results == [-3, -1, -2]  # in seed order, whatever order they finished in
    assert sorted(seen) == [(1, -1), (2, -2), (3, -3)]  # each once
    assert set(counted) == {(3, 3)}  # the bar counted every finished run


def test_montecarlo_on_a_cluster_is_the_local_study(cluster, local_study, tmp_path):
    assert main([*CELL, "--scheduler", cluster.scheduler_address, "--out", str(tmp_path)]) == 0
    _same_study(local_study, tmp_path)


def test_a_worker_killed_mid_study_loses_nothing(cluster, local_study, tmp_path):
    """Once the first run is kept, a worker holding a run is killed (SIGKILL): the scheduler
    gives its runs to the other worker (and to the one the nanny restarts); the study is
    complete and the same."""
    from distributed import Client

    killed: list = []
    finished = threading.Event()

    def kill_a_busy_worker() -> None:
        runs = tmp_path / "runs"
        with Client(cluster.scheduler_address, set_as_default=False) as client:
            end = time.monotonic() + DEADLINE
            while not finished.is_set() and time.monotonic() < end:
                if any(runs.glob("run_*.npz")):
                    busy = {w: keys for w, keys in client.processing().items() if keys}
                    if busy:
                        worker, keys = next(iter(busy.items()))
                        pid = client.run(os.getpid, workers=[worker])[worker]
                        os.kill(pid, signal.SIGKILL)
                        killed.append((worker, keys))
                        return
                finished.wait(0.02)

    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    try:
        argv = [*CELL, "--scheduler", cluster.scheduler_address, "--out", str(tmp_path)]
        assert main(argv) == 0
    finally:
        finished.set()
        killer.join(DEADLINE)
    assert len(killed) == 1 and killed[0][1], "no worker was killed while holding a run"
    _same_study(local_study, tmp_path)


def test_a_paper_piece_on_a_cluster_is_the_local_one(cluster, shared_data, tmp_path):
    """KITTI 00 (the import a task, the two filters tasks needing it), the link-loss sweep and
    the FEJ Monte Carlo: the same cells on the cluster as in one process."""
    from teamslam.paper import PaperSettings, reproduce_all

    keys = ["dvi-table-1", "dvi-figure-4", "fej-table-1"]
    sizes = {
        "team_sizes": (3,),
        "steps": 10,
        "loss_rates": (0.0, 0.5),
        "fej_runs": 7,
        "fej_features": (20,),
        "frames": 20,
        "progress": False,
    }
    cells = {}
    for name, where in (
        ("local", {"workers": 1}),
        ("cluster", {"scheduler": cluster.scheduler_address}),
    ):
        out = tmp_path / name
        settings = PaperSettings.quick(**sizes, **where)
        _, reproducer = reproduce_all(out, settings, shared_data, keys=keys, keep_tasks=True)
        paper = json.loads((out / "paper.json").read_text())
        cells[name] = [c for c in paper["cells"] if c["unit"] != "ms" and "time" not in c["row"]]
        assert reproducer.store.saved == 1 + 2 + 1 + 2 + 2  # tasks, each kept once
    assert reproducer.timing()["workers"] == 2
    assert json.dumps(cells["local"]) == json.dumps(cells["cluster"])
    assert sum(c["ours"] is not None for c in cells["cluster"]) == 3 * 5 + 3 * 2 + 3 * 8


def test_fej_table_on_a_cluster_is_the_local_one(cluster, tmp_path, capsys):
    """``teamslam fej table --scheduler``: the printed table and table.json as with local
    processes, and every per-step curve of every filter, bit for bit."""
    from teamslam import api

    tables = {}
    for name, where in (
        ("local", ["--workers", "2"]),
        ("cluster", ["--scheduler", cluster.scheduler_address]),
    ):
        out = tmp_path / name
        argv = ["fej", "table", "--env", "2", "--runs", "5", "--json", "--out", str(out), *where]
        assert main(argv) == 0
        tables[name] = (capsys.readouterr().out, (out / "table.json").read_text())
    assert tables["local"] == tables["cluster"]
    assert json.loads(tables["local"][0])["fej"]["r1_pose_nees"] > 0
    env = api.fej_environment(2, 20)
    local = api.fej_table(env, runs=5, workers=1)
    remote = api.fej_table(env, runs=5, scheduler=cluster.scheduler_address)
    assert local.curves.keys() == remote.curves.keys() == {"std", "fej", "ideal"}
    for name, curves in local.curves.items():
        for metric, values in curves.items():
            np.testing.assert_array_equal(values, remote.curves[name][metric], strict=True)


def _dask(*args: str, log: Path) -> subprocess.Popen:
    with log.open("w") as f:
        return subprocess.Popen(
            [sys.executable, "-m", "dask", *args],
            stdout=f,
            stderr=subprocess.STDOUT,
            env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
        )


def test_a_scheduler_and_workers_started_by_hand_give_the_local_study(local_study, tmp_path):
    """``dask scheduler`` and ``dask worker --nworkers 2 --nthreads 1`` as processes on
    loopback, the study submitted to the scheduler's address (from its scheduler file)."""
    address_file = tmp_path / "scheduler.json"
    processes = [
        _dask(
            *("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard"),
            *("--scheduler-file", str(address_file)),
            log=tmp_path / "scheduler.log",
        )
    ]
    try:
        end = time.monotonic() + DEADLINE
        while not address_file.is_file() and time.monotonic() < end:
            assert processes[0].poll() is None, (tmp_path / "scheduler.log").read_text()
            time.sleep(0.05)  # waiting for the file, not timing anything
        address = json.loads(address_file.read_text())["address"]
        processes.append(
            _dask(
                *("worker", address, "--nworkers", "2", "--nthreads", "1"),
                *("--host", "127.0.0.1", "--no-dashboard"),
                log=tmp_path / "worker.log",
            )
        )
        out = tmp_path / "study"
        assert main([*CELL, "--scheduler", address, "--out", str(out)]) == 0
        _same_study(local_study, out)
    finally:
        for p in reversed(processes):
            p.send_signal(signal.SIGTERM)
        for p in reversed(processes):
            try:
                p.wait(60)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
