"""The ``teamslam`` command line."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from teamslam import __version__
from teamslam.cli import main


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert __version__ in capsys.readouterr().out


def test_dvi_demo_writes_metrics(tmp_path, capsys):
    assert (
        main(
            [
                "dvi-demo",
                "--agents",
                "4",
                "--graph",
                "ring",
                "--loss",
                "0.2",
                "--steps",
                "25",
                "--seed",
                "3",
                "--out",
                str(tmp_path),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "centralized" in out and "distributed" in out and "separate" in out
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["agents"] == 4
    # consensus brings the agents' maps together; separate filters stay apart
    assert metrics["final_disagreement"] < 0.2 * metrics["final_disagreement_separate"]
    assert metrics["max_error_vs_centralized"] > 0
    assert (
        metrics["landmark_rmse_final"]["distributed"] < metrics["landmark_rmse_final"]["separate"]
    )


@pytest.mark.parametrize(
    "argv",
    [
        ["dvi-demo", "--agents", "zero"],
        ["dvi-demo", "--agents", "1"],
        ["dvi-demo", "--loss", "1.5"],
        ["dvi-demo", "--graph", "mesh"],
        ["dvi-demo", "--steps", "-3"],
        ["no-such-command"],
        ["dvi-demo", "--unknown-flag"],
        ["fej", "table", "--layout", "-1"],
        ["fej", "table", "--layout", "1", "--environment", "a.mat", "b.mat"],
    ],
)
def test_bad_arguments_give_one_line_and_exit_2(argv):
    proc = subprocess.run(
        [sys.executable, "-m", "teamslam", *argv], capture_output=True, text=True, check=False
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "error" in lines[0]
    assert "Traceback" not in proc.stderr


def test_simulate_and_info(tmp_path, capsys):
    out = tmp_path / "team"
    assert (
        main(["simulate", "--robots", "3", "--steps", "30", "--seed", "1", "--out", str(out)]) == 0
    )
    capsys.readouterr()
    assert main(["data", "info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["robots"] == 3
    assert info["frames_per_robot"] == [31, 31, 31]
    assert info["objects_observed"] >= info["objects_shared"] > 0


def test_import_reference_cli(kitti00_dir, tmp_path, capsys):
    assert main(["data", "import-reference", str(kitti00_dir), str(tmp_path / "k")]) == 0
    capsys.readouterr()
    assert main(["data", "info", str(tmp_path / "k"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames_per_robot"] == [2001, 2001, 2041]
    assert info["objects_observed"] == 405


def test_data_errors_are_one_line(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "teamslam", "data", "info", str(tmp_path / "missing")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2
    assert len(proc.stderr.strip().splitlines()) == 1
    assert "no manifest.json" in proc.stderr


def test_fej_table_json(capsys, tmp_path):
    argv = [
        "fej",
        "table",
        "--env",
        "2",
        "--features",
        "20",
        "--runs",
        "4",
        "--workers",
        "1",
        "--json",
        "--out",
        str(tmp_path),
    ]
    assert main(argv) == 0
    table = json.loads(capsys.readouterr().out)
    for name in ("std", "ideal", "fej"):
        for key in (
            "r1_pose_nees",
            "r1_position_rmse",
            "r1_heading_rmse",
            "r2_pose_nees",
            "r2_position_rmse",
            "r2_heading_rmse",
            "feature_nees",
            "feature_rmse",
        ):
            assert np.isfinite(table[name][key])
    assert (tmp_path / "nees_rmse.png").stat().st_size > 10_000
    assert (tmp_path / "sigma_bounds.png").stat().st_size > 10_000


def test_fej_table_bad_environment_file(tmp_path):
    bad = tmp_path / "env.json"
    bad.write_text("[]")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "teamslam",
            "fej",
            "table",
            "--runs",
            "2",
            "--environment",
            str(bad),
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 2
    assert len(proc.stderr.strip().splitlines()) == 1
    assert "env.json" in proc.stderr


def test_a_diverging_filter_exits_1_naming_robot_and_frame(tmp_path, capsys, monkeypatch):
    from teamslam.gaussian import NotPositiveDefiniteError
    from teamslam.msckf.agent import MsckfAgent

    assert main(["simulate", "--robots", "2", "--steps", "8", "--out", str(tmp_path / "d")]) == 0
    capsys.readouterr()
    original = MsckfAgent._step

    def failing(self, t):
        if self.robot == 1 and t == 3:
            raise NotPositiveDefiniteError("innovation covariance is not positive definite")
        return original(self, t)

    monkeypatch.setattr(MsckfAgent, "_step", failing)
    code = main(["run", str(tmp_path / "d"), "--separate", "--calibrate", "never"])
    err = capsys.readouterr().err
    assert code == 1
    assert "robot 1, frame 3" in err and "not positive definite" in err
    assert "error:" not in err  # a failure, not a usage error
    # a dataset that is not there is the user's input: exit 2
    assert main(["run", str(tmp_path / "missing"), "--separate"]) == 2


@pytest.mark.parametrize("inherited", ["ignored", "blocked", "default"])
def test_ctrl_c_interrupts_only_inside_its_block(inherited):
    """The commands that run until stopped raise KeyboardInterrupt on SIGINT even when the
    process inherited it ignored or blocked, and leave the process's SIGINT as it was after."""
    import signal

    from teamslam.cli._common import ctrl_c_interrupts

    def state():
        return signal.getsignal(signal.SIGINT), signal.SIGINT in signal.pthread_sigmask(
            signal.SIG_BLOCK, []
        )

    before = state()
    try:
        if inherited == "ignored":
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        elif inherited == "blocked":
            signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGINT])
        else:
            signal.signal(signal.SIGINT, signal.SIG_DFL)
        outside = state()
        with ctrl_c_interrupts():
            assert state() == (signal.default_int_handler, False)
            with pytest.raises(KeyboardInterrupt):
                signal.raise_signal(signal.SIGINT)
        assert state() == outside
    finally:
        how = signal.SIG_BLOCK if before[1] else signal.SIG_UNBLOCK
        signal.pthread_sigmask(how, [signal.SIGINT])
        signal.signal(signal.SIGINT, before[0])
    assert state() == before
