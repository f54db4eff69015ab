"""Studies kept run by run as they finish, and ``--resume``: an interrupted Monte Carlo study
or paper run keeps what finished, a resumed one runs only the rest and gives the same result as
one run at once; another study's runs are refused, never mixed in. A scheduler address that does
not answer is one line and exit 2 (the runs on a cluster are tests/test_cluster.py)."""

from __future__ import annotations

import json
import socket
from dataclasses import replace

import numpy as np
import pytest

import teamslam.eval.team_montecarlo as tm
from teamslam.cli import EXIT_INTERRUPTED, main
from teamslam.errors import InputError
from teamslam.eval.studies import RunStore, load_arrays, save_arrays

CELL = [
    *("montecarlo", "--robots", "2", "--steps", "8", "--runs", "4"),
    *("--filters", "std,fej", "--modes", "separate,consensus", "--workers", "1", "--json"),
]


ONE_RUN = tm.one_run


def _summary(path) -> dict:
    summary = json.loads(path.read_text())
    summary.pop("wall_seconds")
    return summary


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """The study run at once: its folder and montecarlo.json (without the wall time)."""
    out = tmp_path_factory.mktemp("whole")
    assert main([*CELL, "--out", str(out)]) == 0
    return out, _summary(out / "montecarlo.json")


def _counting(monkeypatch, stop_at: int | None = None) -> list[int]:
    """Record the runs ``one_run`` is called for (``--workers 1`` runs them here); interrupt
    the study (as Ctrl-C would) when it reaches run ``stop_at``."""
    calls: list[int] = []
    real = ONE_RUN

    def counted(run, spec):
        if run == stop_at:
            raise KeyboardInterrupt
        calls.append(run)
        return real(run, spec)

    monkeypatch.setattr(tm, "one_run", counted)
    return calls


def test_every_run_is_kept_as_it_finishes_and_reads_back_bit_for_bit(whole):
    out, _ = whole
    runs = out / "runs"
    assert sorted(p.name for p in runs.iterdir()) == [
        *(f"run_{k:06d}.npz" for k in range(4)),
        "study.json",
    ]
    spec = tm.MonteCarloSpec(
        robots=2, steps=8, runs=4, filters=("std", "fej"), modes=("separate", "consensus")
    )
    assert json.loads((runs / "study.json").read_text()) == json.loads(json.dumps(tm.study(spec)))
    direct = tm.one_run(2, spec)
    stored = load_arrays(runs / "run_000002.npz")
    assert stored.keys() == direct.keys()
    for key, arrays in direct.items():
        for name, a in arrays.items():
            assert stored[key][name].dtype == a.dtype
            np.testing.assert_array_equal(stored[key][name], a, strict=True)


def test_an_interrupted_study_resumes_with_only_the_missing_runs(
    whole, tmp_path, monkeypatch, capsys
):
    _, summary = whole
    calls = _counting(monkeypatch, stop_at=2)
    assert main([*CELL, "--out", str(tmp_path)]) == EXIT_INTERRUPTED
    assert calls == [0, 1]
    runs = tmp_path / "runs"
    kept = {p.name: p.stat().st_mtime_ns for p in runs.glob("run_*.npz")}
    assert sorted(kept) == ["run_000000.npz", "run_000001.npz"]
    assert not (tmp_path / "montecarlo.json").exists()
    # a partial file an interruption may leave is no run
    (runs / "run_000002.npz.tmp.npz").write_bytes(b"PK\x03\x04 partial")
    capsys.readouterr()

    calls = _counting(monkeypatch)
    assert main([*CELL, "--out", str(tmp_path), "--resume"]) == 0
    assert calls == [2, 3]
    assert "resumed: 2 of 4 runs read back" in capsys.readouterr().err
    assert {p.name: p.stat().st_mtime_ns for p in runs.glob("run_00000[01].npz")} == kept
    assert _summary(tmp_path / "montecarlo.json") == summary
    # resumed again with every run kept: nothing runs, the same JSON
    calls = _counting(monkeypatch)
    assert main([*CELL, "--out", str(tmp_path), "--resume"]) == 0
    assert calls == [] and _summary(tmp_path / "montecarlo.json") == summary
    # more runs than kept: only the new ones run
    assert main([*CELL, "--runs", "5", "--out", str(tmp_path), "--resume"]) == 0
    assert calls == [4]


def test_a_study_started_again_without_resume_replaces_the_kept_runs(whole, tmp_path, monkeypatch):
    _, summary = whole
    calls = _counting(monkeypatch, stop_at=1)
    assert main([*CELL, "--steps", "9", "--out", str(tmp_path)]) == EXIT_INTERRUPTED
    assert calls == [0]
    calls = _counting(monkeypatch)
    assert main([*CELL, "--out", str(tmp_path)]) == 0
    assert calls == [0, 1, 2, 3]
    assert _summary(tmp_path / "montecarlo.json") == summary


def test_resuming_another_study_is_refused_in_one_line(whole, tmp_path, monkeypatch, capsys):
    calls = _counting(monkeypatch, stop_at=1)
    assert main([*CELL, "--out", str(tmp_path)]) == EXIT_INTERRUPTED
    capsys.readouterr()
    for change, named in (
        (["--steps", "9"], "steps is 8 there, 9 here"),
        (["--filters", "std"], 'filters is ["std", "fej"] there, ["std"] here'),
        (["--set", "filter.gate_probability=0.9"], "settings is [] there"),
    ):
        assert main([*CELL, *change, "--out", str(tmp_path), "--resume"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err
        assert "holds runs of another study" in err and named in err, err
    assert calls == [0]  # nothing ran
    assert sorted(p.name for p in (tmp_path / "runs").glob("run_*")) == ["run_000000.npz"]


def test_a_run_store_refuses_runs_without_their_study_and_unreadable_runs(tmp_path):
    store = RunStore(tmp_path, {"steps": 8})
    store.save(0, {"a": {"x": np.arange(3.0)}})
    (tmp_path / "run_000001.npz").write_bytes(b"not a zip")
    resumed = RunStore(tmp_path, {"steps": 8}, resume=True)
    assert 0 in resumed and 1 in resumed and 2 not in resumed
    np.testing.assert_array_equal(resumed.load(0)["a"]["x"], np.arange(3.0))
    with pytest.raises(InputError, match=r"run_000001\.npz: not a readable stored run"):
        resumed.load(1)
    (tmp_path / "study.json").unlink()
    with pytest.raises(InputError, match=r"holds runs but no study\.json"):
        RunStore(tmp_path, {"steps": 8}, resume=True)
    save_arrays(tmp_path / "other.npz", {"g": {"y": np.zeros((0,))}})
    assert load_arrays(tmp_path / "other.npz")["g"]["y"].shape == (0,)


def test_a_paper_run_resumes_with_only_the_missing_tasks(shared_data, tmp_path, monkeypatch):
    """DVI Fig. 4 (its separate and consensus tasks) and the FEJ Monte Carlo (two tasks of
    runs): one task's file lost, the resumed run computes that one only and the same cells; a
    run that keeps no tasks (local, not resuming) writes none."""
    from teamslam.eval import schedule
    from teamslam.paper import PaperSettings, reproduce_all

    settings = PaperSettings.quick(
        team_sizes=(2,), steps=6, fej_runs=7, fej_features=(20,), workers=1, progress=False
    )
    keys = ["fej-table-1", "dvi-figure-4"]
    reproduce_all(tmp_path, settings, shared_data, keys=keys, keep_tasks=True)
    before = json.loads((tmp_path / "paper.json").read_text())["cells"]
    tasks = sorted((tmp_path / "tasks").glob("run_*.pkl"))
    assert len(tasks) == 2 + 1 + 3  # FEJ: runs 0–4 and 5–6; separate; consensus at 3 rates
    tasks[0].unlink()

    ran: list = []
    real = schedule._timed
    monkeypatch.setattr(schedule, "_timed", lambda call, *a: ran.append(call) or real(call, *a))
    _, reproducer = reproduce_all(tmp_path, settings, shared_data, keys=keys, resume=True)
    assert len(ran) == 1 and reproducer.store.loaded == 5 and reproducer.store.saved == 1
    after = json.loads((tmp_path / "paper.json").read_text())["cells"]
    assert after == before
    with pytest.raises(InputError, match="holds runs of another study"):
        reproduce_all(tmp_path, replace(settings, steps=7), shared_data, keys=keys, resume=True)
    _, reproducer = reproduce_all(tmp_path / "plain", settings, shared_data, keys=["fej-table-1"])
    assert reproducer.store is None and not (tmp_path / "plain" / "tasks").exists()


def test_paper_resume_needs_an_output_directory(capsys):
    assert main(["paper", "fej", "--table", "1", "--runs", "2", "--resume"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--resume continues the tasks kept in an output" in err


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_scheduler_that_does_not_answer_is_one_line_exit_2(tmp_path, monkeypatch, capsys):
    pytest.importorskip("distributed")
    import teamslam.parallel

    monkeypatch.setattr(teamslam.parallel, "CONNECT_SECONDS", 2.0)
    for address, says in (
        (f"tcp://127.0.0.1:{_closed_port()}", "no Dask scheduler answers at tcp://127.0.0.1:"),
        ("not an address", "'not an address' is no Dask scheduler address"),
    ):
        out = tmp_path / "out"
        assert main([*CELL, "--scheduler", address, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err, err
        assert err.startswith("teamslam montecarlo: error: ") and says in err, err
        assert not out.exists()  # nothing written
