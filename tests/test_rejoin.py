"""A robot killed mid-run and restarted with ``--resume`` rejoins its running team (loopback).

Ports 30800–32767 as in test_security (offsets 16–31 here).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np

from teamslam.datasets import save_dataset
from teamslam.graph import complete
from teamslam.runtime.agent_process import load_robot_result
from teamslam.runtime.launch import agent_command, frames_done
from teamslam.runtime.team_file import write_team_file
from teamslam.sim import lissajous_team


def _port(offset: int) -> int:
    return 30800 + (os.getpid() % 60) * 32 + offset


def _checkpoint(out: Path, robot: int) -> int:
    try:
        return int(json.loads((out / f"robot_{robot}" / "checkpoint.json").read_text())["frame"])
    except (OSError, ValueError, KeyError):
        return -1


def _wait_until(condition, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def test_killed_robot_resumes_and_rejoins_the_running_team(tmp_path):
    dataset = lissajous_team(robots=3, steps=60, seed=1, landmarks=300)
    save_dataset(dataset, tmp_path / "data")
    team_path = write_team_file(
        tmp_path / "team.yaml",
        f"rejoin-{os.getpid()}",
        tmp_path / "data",
        complete(3).adjacency,
        base_port=_port(16),
        timeout_s=0.5,
        checkpoint_every=12,
        message_delay_ms=60.0,  # a slow radio: the team is paced by its messages
        settings={"filter.window": 8, "filter.use_geometric_features": False},
    )
    out = tmp_path / "out"
    procs = {
        r: subprocess.Popen(
            agent_command(team_path, r, out), stdout=subprocess.PIPE, stderr=subprocess.STDOUT
        )
        for r in range(3)
    }
    try:
        # robots 0 and 1 average with robot 2 from frames 18 and 22 on: kill it after that
        _wait_until(lambda: _checkpoint(out, 2) >= 23, 120)
        procs[2].send_signal(signal.SIGKILL)
        procs[2].wait(timeout=10)
        killed_at = _checkpoint(out, 2)
        # long enough for the others to report it lost (3 silent frames of 0.5 s)
        time.sleep(3 * 0.5 + 0.5)
        restarted_at = min(frames_done(out, 0), frames_done(out, 1)) - 1
        assert restarted_at < dataset.robots[0].frames - 10, "the team finished too early"
        procs[2] = subprocess.Popen(
            agent_command(team_path, 2, out, "--resume"),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        outputs = {r: p.communicate(timeout=240)[0].decode() for r, p in procs.items()}
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
    for r, p in procs.items():
        assert p.returncode == 0, outputs[r]
    last = dataset.robots[0].frames - 1
    for r in (0, 1):
        _, summary = load_robot_result(out, r)
        assert summary["lost_neighbours"] == [2]
        with_2 = summary["averaged_with"]["2"]
        # averaged with robot 2 before it died and again after it came back
        assert min(with_2) <= killed_at
        assert any(t > restarted_at for t in with_2), (restarted_at, with_2)
        assert max(with_2) >= last - 5
    arrays, summary = load_robot_result(out, 2)
    assert max(max(summary["averaged_with"][str(j)]) for j in (0, 1)) >= last - 5
    truth = dataset.robots[2].T_world_body[:, :3, 3]
    err = np.linalg.norm(arrays["poses"][:, :3, 3] - truth, axis=1)
    assert np.all(np.isfinite(err)) and err.max() < 1.0
