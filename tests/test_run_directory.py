"""A run never shows another run's numbers: run directories are written whole or not at all.

``teamslam run --out R`` writes into a staging folder beside ``R`` and moves it into place at
the end, ``run.json`` last; a non-empty ``R`` that is no run is refused, an earlier run is
replaced only with ``--overwrite`` and then entirely; ``R`` is checked before any data is read;
an interrupted write leaves what was there before; every reader refuses a directory without
``run.json``.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from teamslam import api
from teamslam.cli import main
from teamslam.datasets import save_dataset
from teamslam.errors import InputError
from teamslam.sim import lissajous_team
from teamslam.staging import StagedDirectory


@pytest.fixture(scope="module")
def dataset_dir(tmp_path_factory):
    directory = tmp_path_factory.mktemp("run-directory") / "team2"
    save_dataset(lissajous_team(robots=2, steps=12, seed=1, landmarks=300), directory)
    return directory


def _files(directory: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(directory)): p.read_bytes()
        for p in sorted(directory.rglob("*"))
        if p.is_file()
    }


def _run(capsys, *argv) -> tuple[int, str, str]:
    code = main(["run", *map(str, argv), "--no-report"])
    out, err = capsys.readouterr()
    return code, out, err


def _no_staging_left(parent: Path) -> None:
    assert [p.name for p in parent.iterdir() if p.name.startswith(".")] == []


def test_an_earlier_run_is_refused_then_replaced_whole_with_overwrite(
    dataset_dir, tmp_path, capsys
):
    out = tmp_path / "R"
    assert _run(capsys, dataset_dir, "--compare", "--out", out)[0] == 0
    before = _files(out)
    # without --overwrite: exit 2, one line naming the directory, nothing changed
    code, _, err = _run(capsys, dataset_dir, "--separate", "--set", "filter.window=3", "--out", out)
    assert code == 2
    assert f"{out} holds an earlier run" in err and "--overwrite" in err
    assert len(err.strip().splitlines()) == 1
    assert _files(out) == before
    # with it: no file of the old run survives
    code, _, _ = _run(
        capsys, dataset_dir, "--separate", "--set", "filter.window=3", "--out", out, "--overwrite"
    )
    assert code == 0
    after = _files(out)
    assert not (out / "separate").exists() and not (out / "consensus").exists()
    assert {"robot_0.tum", "estimates.npz", "run.json", "metrics.json"} <= set(after)
    assert json.loads((out / "run.json").read_text())["modes"] == ["separate"]
    assert json.loads((out / "metrics.json").read_text())["config"]["filter"]["window"] == 3
    assert main(["eval", str(out), "--json"]) == 0
    runs = json.loads(capsys.readouterr().out)["runs"]
    assert list(runs) == ["R"]  # one column: the new run's
    # the other order: a comparison replaces a single run, leaving no top-level trajectory
    code, _, _ = _run(capsys, dataset_dir, "--compare", "--out", out, "--overwrite")
    assert code == 0
    top = {p.name for p in out.iterdir() if p.is_file()}
    assert not any(name.endswith((".tum", ".npz")) for name in top), top
    assert (out / "separate" / "robot_0.tum").is_file()
    _no_staging_left(tmp_path)


@pytest.mark.parametrize("kind", ["dataset", "other"])
def test_a_non_empty_directory_that_is_no_run_is_refused(dataset_dir, tmp_path, capsys, kind):
    if kind == "dataset":
        target = tmp_path / "copy"
        shutil.copytree(dataset_dir, target)
    else:
        target = tmp_path / "notes"
        target.mkdir()
        (target / "todo.txt").write_text("keep me\n")
    before = _files(target)
    for overwrite in ([], ["--overwrite"]):
        code, _, err = _run(capsys, dataset_dir, "--out", target, *overwrite)
        assert code == 2
        assert f"{target} is not empty and holds no run.json" in err
        assert _files(target) == before
    _no_staging_left(tmp_path)


def _never_load(monkeypatch) -> list:
    """Replace the dataset loader by one that records being called."""
    import teamslam.datasets

    calls = []

    def load(*args, **kwargs):
        calls.append(args)
        raise AssertionError("the dataset was read before --out was checked")

    monkeypatch.setattr(teamslam.datasets, "load_dataset", load)
    return calls


def test_an_out_that_is_a_file_is_refused_before_any_data_is_read(
    dataset_dir, tmp_path, capsys, monkeypatch
):
    calls = _never_load(monkeypatch)
    blocker = tmp_path / "file"
    blocker.write_text("not a directory\n")
    for target, message in (
        (blocker, f"{blocker} exists and is not a directory"),
        (blocker / "R", f"{blocker} exists and is not a directory; cannot make"),
    ):
        code, _, err = _run(capsys, dataset_dir, "--compare", "--out", target)
        assert code == 2 and message in err, err
    assert calls == []
    assert blocker.read_text() == "not a directory\n"


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_an_out_in_a_read_only_folder_is_refused_before_any_data_is_read(
    dataset_dir, tmp_path, capsys, monkeypatch
):
    calls = _never_load(monkeypatch)
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        code, _, err = _run(capsys, dataset_dir, "--out", locked / "R")
    finally:
        locked.chmod(0o755)
    assert code == 2 and f"{locked / 'R'}: cannot write a run directory there" in err
    assert calls == []


def test_an_unwritable_parent_is_refused_before_any_data_is_read(
    dataset_dir, tmp_path, capsys, monkeypatch
):
    """The staging folder is made first: the parent's refusal (as a read-only folder's, also
    for root) comes before the dataset is touched."""
    import teamslam.staging

    calls = _never_load(monkeypatch)

    def refuse(*args, dir=None, **kwargs):
        raise PermissionError(13, "Permission denied", str(dir))

    monkeypatch.setattr(teamslam.staging.tempfile, "mkdtemp", refuse)
    code, _, err = _run(capsys, dataset_dir, "--out", tmp_path / "R")
    assert code == 2 and "cannot write a run directory there" in err and "Permission" in err
    assert calls == []
    assert not (tmp_path / "R").exists()


def _interrupt_the_figures(monkeypatch) -> None:
    """Ctrl-C while the final write is under way (metrics and trajectories written, the
    figures not)."""
    import teamslam.eval.plots

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(teamslam.eval.plots, "plot_team_errors", interrupted)


def test_an_interrupted_write_leaves_no_run_and_keeps_the_earlier_one(
    dataset_dir, tmp_path, capsys, monkeypatch
):
    fresh = tmp_path / "fresh"
    earlier = tmp_path / "earlier"
    assert _run(capsys, dataset_dir, "--out", earlier)[0] == 0
    before = _files(earlier)
    _interrupt_the_figures(monkeypatch)
    code, _, err = _run(capsys, dataset_dir, "--compare", "--out", fresh)
    assert code == 130 and "interrupted" in err
    assert not fresh.exists()
    code, _, _ = _run(capsys, dataset_dir, "--compare", "--out", earlier, "--overwrite")
    assert code == 130
    assert _files(earlier) == before  # the earlier run, whole
    with pytest.raises(KeyboardInterrupt):
        api.run(dataset_dir, "compare", out=fresh, progress=False)
    assert not fresh.exists()
    _no_staging_left(tmp_path)


def test_a_staged_directory_is_removed_on_an_exception_and_swapped_whole():
    import tempfile

    with tempfile.TemporaryDirectory() as parent:
        target = Path(parent) / "out"
        target.mkdir()
        (target / "old.txt").write_text("old")
        with pytest.raises(RuntimeError), StagedDirectory(target) as stage:
            (stage.path / "new.txt").write_text("new")
            raise RuntimeError("midway")
        assert _files(target) == {"old.txt": b"old"}
        with StagedDirectory(target) as stage:
            (stage.path / "new.txt").write_text("new")
        assert _files(target) == {"new.txt": b"new"}
        assert sorted(p.name for p in Path(parent).iterdir()) == ["out"]


def test_readers_refuse_a_directory_without_run_json(dataset_dir, tmp_path, capsys):
    out = tmp_path / "R"
    assert main(["run", str(dataset_dir), "--compare", "--out", str(out)]) == 0
    capsys.readouterr()
    (out / "run.json").unlink()  # what an interrupted write of old left: all but run.json
    for argv in (
        ["eval", str(out)],
        ["report", str(out), "--out", str(tmp_path / "report.html")],
        ["export", "mcap", str(out), "--out", str(tmp_path / "run.mcap")],
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert f"{out}: not a run directory (no run.json" in err
        assert len(err.strip().splitlines()) == 1
    with pytest.raises(InputError, match=r"no run\.json"):
        api.load_run(out)
    assert not (tmp_path / "report.html").exists() and not (tmp_path / "run.mcap").exists()


def test_a_run_failing_midway_is_moved_into_place_marked_incomplete(
    dataset_dir, tmp_path, capsys, monkeypatch
):
    from test_driver import _fail_robot_1_at_frame_5

    _fail_robot_1_at_frame_5(monkeypatch)
    out = tmp_path / "R"
    code, _, err = _run(capsys, dataset_dir, "--out", out)
    assert code == 1 and "robot 1, frame 5" in err
    meta = json.loads((out / "run.json").read_text())
    assert meta["complete"] is False and meta["modes"] == ["consensus"]
    assert len((out / "robot_0.tum").read_text().strip().splitlines()) == 5
    with pytest.raises(InputError, match="stopped early"):
        api.load_run(out)
    _no_staging_left(tmp_path)
