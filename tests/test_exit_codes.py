"""The exit status of ``teamslam`` follows the cause of a failure (2: fix your input; 1: the run
failed) and the message says what happened."""

from __future__ import annotations

import errno
import subprocess
import sys

import pytest

import teamslam.cli
from teamslam.cli._common import Parser, UsageError
from teamslam.errors import EstimationError, InputError, InternalError, OutputError
from teamslam.gaussian import NotPositiveDefiniteError
from teamslam.msckf.settings.sources import ConfigError


def _run_raising(monkeypatch, capsys, exc: BaseException) -> tuple[int, str]:
    """``teamslam boom`` whose handler raises ``exc``: the status and the stderr text."""

    def handler(args):
        raise exc

    def build_parser():
        parser = Parser(prog="teamslam")
        sub = parser.add_subparsers(dest="command", parser_class=Parser)
        sub.add_parser("boom").set_defaults(handler=handler)
        return parser

    monkeypatch.setattr(teamslam.cli, "build_parser", build_parser)
    status = teamslam.cli.main(["boom"])
    return status, capsys.readouterr().err


@pytest.mark.parametrize(
    "exc",
    [
        InputError("--robots: expected a positive integer, got 0"),
        UsageError("--window must be at least 2"),
        ConfigError("window = 1 (flag): expected an integer ≥ 2"),
        FileNotFoundError(errno.ENOENT, "No such file or directory", "data/manifest.json"),
        PermissionError(errno.EACCES, "Permission denied", "data/robot_0.npz"),
        IsADirectoryError(errno.EISDIR, "Is a directory", "data/team.yaml"),
    ],
    ids=lambda e: type(e).__name__,
)
def test_wrong_input_and_unreadable_files_exit_2(monkeypatch, capsys, exc):
    status, err = _run_raising(monkeypatch, capsys, exc)
    assert status == 2
    assert err == f"teamslam boom: error: {exc}\n"


def test_an_estimation_failure_exits_1_with_its_message(monkeypatch, capsys):
    exc = NotPositiveDefiniteError("robot 2, frame 41: object covariance not positive definite")
    assert isinstance(exc, ValueError)  # also a ValueError, still not a usage error
    status, err = _run_raising(monkeypatch, capsys, exc)
    assert status == 1
    assert (
        err == "teamslam boom: failed: robot 2, frame 41: object covariance not positive definite\n"
    )
    status, err = _run_raising(monkeypatch, capsys, EstimationError("robot 0, frame 3: NaN"))
    assert (status, err) == (1, "teamslam boom: failed: robot 0, frame 3: NaN\n")


def test_an_internal_error_exits_1_asking_for_a_report(monkeypatch, capsys):
    exc = InternalError("consensus: object 17 in the common set but not in the state")
    status, err = _run_raising(monkeypatch, capsys, exc)
    assert status == 1
    assert err.startswith("teamslam boom: internal error: consensus: object 17")
    assert "please report" in err
    assert len(err.splitlines()) == 1


@pytest.mark.parametrize(
    "exc",
    [
        OutputError(errno.ENOENT, "cannot write the run", "results/run/metrics.json"),
        OutputError("cannot write results/run/robot_0.tum: disk full"),
        OSError(errno.ENOSPC, "No space left on device", "results/run/estimates.npz"),
        OSError(errno.EROFS, "Read-only file system", "results/run/report.html"),
    ],
    ids=["OutputError-errno", "OutputError-text", "ENOSPC", "EROFS"],
)
def test_a_result_that_cannot_be_written_exits_1_naming_the_path(monkeypatch, capsys, exc):
    # OutputError is an OSError: it must not be taken for an unreadable input (status 2)
    assert isinstance(exc, OSError)
    status, err = _run_raising(monkeypatch, capsys, exc)
    assert status == 1
    assert err.startswith("teamslam boom: failed: ")
    assert "results/run/" in err


def test_an_unexpected_exception_is_not_hidden(monkeypatch, capsys):
    with pytest.raises(ZeroDivisionError):
        _run_raising(monkeypatch, capsys, ZeroDivisionError("a bug"))


def test_interrupted_exits_130(monkeypatch, capsys):
    status, err = _run_raising(monkeypatch, capsys, KeyboardInterrupt())
    assert (status, err) == (130, "teamslam boom: interrupted\n")


def test_real_commands_map_wrong_input_to_2(tmp_path, capsys):
    # a dataset directory whose manifest is not JSON: a malformed input file
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "manifest.json").write_text("{not json")
    assert teamslam.cli.main(["run", str(bad), "--separate"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("teamslam run: error: ") and len(err.splitlines()) == 1


@pytest.mark.parametrize(
    "mode", [[], ["--separate"], ["--compare"], ["--centralised"], ["--processes"]]
)
def test_a_configuration_error_exits_2_in_every_mode(tmp_path, capsys, mode):
    from teamslam.datasets import save_dataset
    from teamslam.sim import lissajous_team

    save_dataset(lissajous_team(robots=2, steps=6, seed=0, landmarks=60), tmp_path / "data")
    argv = [
        "run",
        str(tmp_path / "data"),
        *mode,
        "--set",
        "filter.window=0",
        "--out",
        str(tmp_path / "o"),
    ]
    assert teamslam.cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("teamslam run: error: ") and "window" in err
    assert len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()  # nothing was run


def test_the_console_entry_point_returns_the_status_to_the_shell(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "teamslam", "run", str(tmp_path / "missing"), "--separate"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 2
    assert proc.stderr.startswith("teamslam run: error: ")
