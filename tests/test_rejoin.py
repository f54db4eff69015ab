"""A robot killed mid-run and restarted with ``--resume`` rejoins its running team (loopback).

Each step of the scenario waits on an event (a robot's checkpoint or progress file), never on
the clock, so the machine's load cannot reorder it: robot 2 is killed after its checkpoint;
it is restarted only once the progress of robots 0 and 1 proves they went ``lost_after``
frames past robot 2's last possible frame (so they reported it lost). It resumes behind the
running team, catches up without waiting (its neighbours have spoken in later steps) and meets
it; the team has frames enough left for that on a loaded machine. The team is never paused: a
process held while its links are being opened can lose them for good (the link layer's open
and lease timeouts), which is not what this test is about. The lock-step timeout is what tells
a dead robot; it is long enough that a live robot stalled by the load is not taken for one
(and the time a robot was itself held does not count).

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

#: how long a robot waits for a neighbour's message in lock-step: what tells a dead robot, and
#: far beyond any stall of a live one on a loaded machine (each stall past it loses a link)
_TIMEOUT_S = 2.0


def _port(offset: int) -> int:
    return 30800 + (os.getpid() % 60) * 32 + offset


def _checkpoint(out: Path, robot: int) -> int:
    try:
        return int(json.loads((out / f"robot_{robot}" / "checkpoint.json").read_text())["frame"])
    except (OSError, ValueError, KeyError):
        return -1


def _wait_until(condition, guard: float = 600.0) -> None:
    """Wait for an event (``condition`` true); ``guard`` seconds only catch a hung run."""
    deadline = time.monotonic() + guard
    while not condition():
        assert time.monotonic() < deadline, "the event never came"
        time.sleep(0.05)


def test_killed_robot_resumes_and_rejoins_the_running_team(tmp_path):
    frames, lost_after, progress_every = 111, 3, 5
    dataset = lissajous_team(robots=3, steps=frames - 1, seed=1, landmarks=300)
    assert dataset.robots[0].frames == frames
    save_dataset(dataset, tmp_path / "data")
    team_path = write_team_file(
        tmp_path / "team.yaml",
        f"rejoin-{os.getpid()}",
        tmp_path / "data",
        complete(3).adjacency,
        base_port=_port(16),
        timeout_s=_TIMEOUT_S,
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
    survivors = (0, 1)

    def reached(robots, frame: int):
        return lambda: all(frames_done(out, r) >= frame for r in robots)

    try:
        # robots 0 and 1 average with robot 2 from frames 18 and 22 on: kill it after that
        _wait_until(lambda: _checkpoint(out, 2) >= 23)
        procs[2].send_signal(signal.SIGKILL)
        procs[2].wait(timeout=60)
        killed_at = _checkpoint(out, 2)  # where it resumes from
        # the last frame robot 2 can have filtered (progress.json is written every 5 frames)
        last_alive = frames_done(out, 2) - 1 + progress_every
        # robots 0 and 1 heard nothing from it for lost_after frames: it is reported lost
        _wait_until(reached(survivors, last_alive + lost_after + 1))
        restarted_at = min(frames_done(out, r) for r in survivors) - 1
        assert restarted_at < frames - 60, "the team was too fast to restart robot 2 in time"
        procs[2] = subprocess.Popen(
            agent_command(team_path, 2, out, "--resume"),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        outputs = {r: p.communicate(timeout=600)[0].decode() for r, p in procs.items()}
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
    for r, p in procs.items():
        assert p.returncode == 0, outputs[r]
    last = frames - 1
    for r in survivors:
        _, summary = load_robot_result(out, r)
        assert summary["lost_neighbours"] == [2]
        with_2 = summary["averaged_with"]["2"]
        # averaged with robot 2 before it died and again after it came back
        assert min(with_2) <= killed_at
        assert any(t > restarted_at for t in with_2), (restarted_at, with_2)
        assert max(with_2) >= last - 5
    arrays, summary = load_robot_result(out, 2)
    assert max(max(summary["averaged_with"][str(j)]) for j in survivors) >= last - 5
    truth = dataset.robots[2].T_world_body[:, :3, 3]
    err = np.linalg.norm(arrays["poses"][:, :3, 3] - truth, axis=1)
    assert np.all(np.isfinite(err)) and err.max() < 1.0
