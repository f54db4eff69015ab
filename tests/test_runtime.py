"""Robots as processes: wire format, team file, Zenoh teams (all traffic on loopback)."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from teamslam.datasets import save_dataset
from teamslam.graph import complete, path
from teamslam.msckf import config_for, run_team
from teamslam.msckf.consensus.messages import CommonMarginalMessage, MapIdsMessage
from teamslam.msckf.consensus.transport import MemoryNetwork
from teamslam.runtime.agent_process import load_robot_result, run_agent
from teamslam.runtime.launch import agent_command, frames_done
from teamslam.runtime.team_file import TeamFileError, load_team_file, write_team_file
from teamslam.runtime.wire import WireError, decode, encode, team_id
from teamslam.runtime.zenoh_transport import ZenohTransport
from teamslam.sim import lissajous_team

TEAM = team_id("test-team")


def _marginal(k: int = 2) -> CommonMarginalMessage:
    rng = np.random.default_rng(k)
    a = rng.normal(size=(3 * k, 3 * k))
    return CommonMarginalMessage(
        1, 2, 17, np.arange(10, 10 + k), rng.normal(size=3 * k), a @ a.T + np.eye(3 * k)
    )


def test_wire_round_trip_is_exact():
    msg = _marginal(3)
    back = decode(encode(msg, TEAM), TEAM, 4)
    assert isinstance(back, CommonMarginalMessage)
    assert (back.sender, back.receiver, back.step) == (1, 2, 17)
    np.testing.assert_array_equal(back.ids, msg.ids)
    np.testing.assert_array_equal(back.mean, msg.mean)
    np.testing.assert_array_equal(back.cov, msg.cov)
    ids = MapIdsMessage(0, 3, 5, np.array([4, 8, 15]))
    back = decode(encode(ids, TEAM), TEAM, 4)
    assert isinstance(back, MapIdsMessage)
    np.testing.assert_array_equal(back.ids, ids.ids)
    # compact: header + ids (one byte each here) + mean + upper triangle only
    assert len(encode(msg, TEAM)) == 36 + 3 + 8 * (9 + 45)


@pytest.mark.parametrize(
    ("mutate", "reason"),
    [
        (lambda b: b[:20], "truncated header"),
        (lambda b: b[:-1], "length"),
        (lambda b: b + b"\x00" * 8, "length"),
        (lambda b: b"XXXX" + b[4:], "bad magic"),
        (lambda b: b[:4] + bytes([9]) + b[5:], "unknown format version"),
        (lambda b: b[:5] + bytes([255]) + b[6:], "unknown message kind"),
    ],
)
def test_wire_rejections_are_named(mutate, reason):
    with pytest.raises(WireError, match=reason):
        decode(mutate(encode(_marginal(), TEAM)), TEAM, 4)


def test_wire_rejects_other_team_unknown_robot_and_oversize():
    data = encode(_marginal(), TEAM)
    with pytest.raises(WireError, match="another team"):
        decode(data, team_id("other"), 4)
    with pytest.raises(WireError, match="unknown robot"):
        decode(data, TEAM, 2)
    with pytest.raises(WireError, match="oversized"):
        decode(data, TEAM, 4, max_bytes=64)
    nan = _marginal()
    bad = CommonMarginalMessage(1, 2, 3, nan.ids, np.full(6, np.nan), nan.cov)
    with pytest.raises(WireError, match="non-finite"):
        decode(encode(bad, TEAM), TEAM, 4)


def _only_message_or_wire_error(data: bytes) -> None:
    try:
        msg = decode(data, TEAM, 4)
    except WireError:
        return
    assert isinstance(msg, MapIdsMessage | CommonMarginalMessage)


@given(st.binary(max_size=600))
@settings(max_examples=400, deadline=None)
def test_decoder_on_random_bytes(data):
    _only_message_or_wire_error(data)


@given(st.integers(0, 10_000), st.data())
@settings(max_examples=400, deadline=None)
def test_decoder_on_truncated_and_bit_flipped_messages(seed, data):
    raw = bytearray(encode(_marginal(1 + seed % 3), TEAM))
    cut = data.draw(st.integers(0, len(raw)))
    _only_message_or_wire_error(bytes(raw[:cut]))
    for _ in range(data.draw(st.integers(1, 4))):
        pos = data.draw(st.integers(0, len(raw) - 1))
        raw[pos] ^= 1 << data.draw(st.integers(0, 7))
    _only_message_or_wire_error(bytes(raw))


def test_team_file_validation(tmp_path):
    good = write_team_file(tmp_path / "team.yaml", "t", tmp_path, path(3).adjacency)
    team = load_team_file(good)
    assert team.n == 3 and team.robots[1].neighbours == [0, 2]
    assert team.robots[2].listen == "tcp/127.0.0.1:17402"
    cases = {
        "team: a/b\nrobots: [{id: 0}]\n": "'team'",
        "team: t\nrobots: []\n": "'robots'",
        "team: t\nrobots: [{id: 1}]\n": "robots\\[0\\].id",
        "team: t\nrobots: [{id: 0, neighbours: [1]}, {id: 1}]\n": "not by robot 1",
        "team: t\nrobots: [{id: 0, neighbours: [5]}]\n": "not another robot",
        "team: t\nsync: sometimes\nrobots: [{id: 0}]\n": "'sync'",
        "team: t\ntimeout_s: -1\nrobots: [{id: 0}]\n": "timeout_s",
        "team: t\ncolour: red\nrobots: [{id: 0}]\n": "unknown field",
        "team: [unclosed\n": "not valid YAML",
    }
    for text, reason in cases.items():
        f = tmp_path / "bad.yaml"
        f.write_text(text)
        with pytest.raises(TeamFileError, match=reason):
            load_team_file(f)


# ------------------------------------------------------------------ processes over Zenoh
@pytest.fixture(scope="module")
def small_team(tmp_path_factory):
    directory = tmp_path_factory.mktemp("team") / "data"
    dataset = lissajous_team(robots=3, steps=40, seed=1, landmarks=600)
    save_dataset(dataset, directory)
    return dataset, directory


def _port(offset: int) -> int:
    """Loopback ports below the ephemeral range, distinct per test (offsets 0–31)."""
    return 18000 + (os.getpid() % 400) * 32 + offset


def _team_file(tmp_path: Path, name: str, directory: Path, base_port: int, **settings) -> Path:
    """A complete-graph team file of the 3-robot test team on loopback."""
    return write_team_file(
        tmp_path / "team.yaml",
        name,
        directory,
        complete(3).adjacency,
        base_port=base_port,
        **settings,
    )


@pytest.mark.parametrize(
    ("settings", "offset"),
    [
        ({}, 0),
        ({"consensus.rule": "increments"}, 21),
        ({"consensus.rule": "increments", "consensus.iterations": 2}, 24),
    ],
    ids=["plain", "incr", "incr-L2"],
)
def test_three_processes_equal_the_in_process_runner(small_team, tmp_path, settings, offset):
    """Also with consensus on information increments, whose marginals carry the sender's prior
    (wire kinds 10, 11), and with two consensus exchanges per frame."""
    dataset, directory = small_team
    team_path = _team_file(
        tmp_path,
        f"eq-{os.getpid()}-{offset}",
        directory,
        _port(offset),
        timeout_s=20.0,
        settings={"filter.window": 8, **settings},
    )
    procs = [
        subprocess.Popen(
            agent_command(team_path, r, tmp_path / "out"),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        for r in range(3)
    ]
    for p in procs:
        out, _ = p.communicate(timeout=240)
        assert p.returncode == 0, out.decode()
    reference = run_team(
        dataset, config_for(dataset, {"filter.window": 8, **settings}), progress=False
    )
    # equal to the last few bits: arrays decoded from the wire sit at other addresses, and
    # numpy's SIMD reductions may then add in another order (seen: 1e-12 m after 40 frames)
    for r in range(3):
        arrays, summary = load_robot_result(tmp_path / "out", r)
        np.testing.assert_allclose(arrays["poses"], reference.poses[r], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(arrays["objects"], reference.objects[r], rtol=1e-9, atol=1e-9)
        assert summary["counters"].get("links_lost", 0) == 0
        assert summary["counters"]["bytes"] > 0
        assert summary["counters"]["objects_averaged"] > 0


def test_killed_agent_lets_the_others_finish(small_team, tmp_path):
    _, directory = small_team
    team_path = _team_file(
        tmp_path,
        f"kill-{os.getpid()}",
        directory,
        _port(3),
        timeout_s=0.5,
        settings={"filter.window": 8},
    )
    out = tmp_path / "out"
    procs = [
        subprocess.Popen(
            agent_command(team_path, r, out), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        for r in range(3)
    ]
    progress = out / "robot_2" / "progress.json"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        try:
            if json.loads(progress.read_text())["frame"] >= 5:
                break
        except (OSError, ValueError, KeyError):
            pass
        time.sleep(0.05)
    procs[2].send_signal(signal.SIGKILL)
    procs[2].wait(timeout=10)
    for p in procs[:2]:
        assert p.wait(timeout=180) == 0
    for r in (0, 1):
        _, summary = load_robot_result(out, r)
        assert summary["lost_neighbours"] == [2]
        assert summary["counters"]["links_lost"] >= 1
    assert not (out / "robot_2" / "result.json").exists()


def test_resume_from_checkpoint_reproduces_the_run(small_team, tmp_path, monkeypatch):
    """A robot without neighbours crashes after a checkpoint and resumes: same result."""
    from teamslam.msckf.agent import MsckfAgent

    _, directory = small_team
    team_path = tmp_path / "solo.yaml"
    team_path.write_text(
        f"team: solo\ndataset: {directory}\ncheckpoint_every: 10\n"
        "settings: {filter: {window: 8}}\nrobots:\n  - id: 0\n    listen: "
        f"tcp/127.0.0.1:{_port(6)}\n"
    )
    team = load_team_file(team_path)

    def quiet():
        return MemoryNetwork(1).endpoint(0)

    whole = run_agent(team, 0, tmp_path / "whole", transport=quiet())
    original_step = MsckfAgent.step

    def crashing(self, t):
        if t == 15:
            raise RuntimeError("simulated crash")
        return original_step(self, t)

    monkeypatch.setattr(MsckfAgent, "step", crashing)
    with pytest.raises(RuntimeError, match="simulated crash"):
        run_agent(team, 0, tmp_path / "crash", transport=quiet())
    monkeypatch.setattr(MsckfAgent, "step", original_step)
    assert (tmp_path / "crash" / "robot_0" / "checkpoint.npz").exists()
    run_agent(team, 0, tmp_path / "crash", resume=True, transport=quiet())
    a, _ = load_robot_result(tmp_path / "whole", 0)
    b, _ = load_robot_result(tmp_path / "crash", 0)
    np.testing.assert_array_equal(a["poses"], b["poses"])
    np.testing.assert_array_equal(a["objects"], b["objects"])
    assert whole["frames"] == 41


def test_run_with_processes_writes_the_same_metrics(small_team, tmp_path, capsys):
    from teamslam.cli import main

    _, directory = small_team
    out = tmp_path / "proc"
    argv = [
        "run",
        str(directory),
        "--processes",
        "--window",
        "8",
        "--base-port",
        str(_port(9)),
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    for key in (
        "trajectory_rmse_m",
        "object_error_m",
        "object_disagreement_avg_m",
        "nees_pose_avg",
        "time_per_robot_step_ms",
    ):
        assert key in metrics
    assert len(metrics["transport"]) == 3
    assert all(t["bytes_per_step"] > 0 for t in metrics["transport"])
    assert (out / "topview.png").exists() and (out / "robot_0.tum").exists()


@pytest.mark.parametrize("mode", ["async", "lossy"])
def test_async_and_lossy_teams_finish_with_sane_estimates(small_team, tmp_path, mode):
    dataset, directory = small_team
    settings = (
        {"sync": "async", "max_age_steps": 2}
        if mode == "async"
        else {"message_loss": 0.3, "message_delay_ms": 1.0, "timeout_s": 0.3}
    )
    team_path = _team_file(
        tmp_path,
        f"{mode}-{os.getpid()}",
        directory,
        _port(12 if mode == "async" else 15),
        settings={"filter.window": 8},
        **settings,
    )
    procs = [
        subprocess.Popen(
            agent_command(team_path, r, tmp_path / "out"),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.STDOUT,
        )
        for r in range(3)
    ]
    for p in procs:
        assert p.wait(timeout=240) == 0
    for r in range(3):
        arrays, summary = load_robot_result(tmp_path / "out", r)
        truth = dataset.robots[r].T_world_body
        err = np.linalg.norm(arrays["poses"][:, :3, 3] - truth[:, :3, 3], axis=1)
        assert np.all(np.isfinite(err)) and err.max() < 1.0
        if mode == "lossy":
            assert summary["counters"]["injected_drops"] > 0
            assert summary["counters"]["links_lost"] > 0


def test_ctrl_c_stops_every_agent(tmp_path):
    # a team long enough (1000 frames) to be interrupted mid-run on a fast, idle machine: with
    # the 40-frame test team the robots could finish before the signal arrived (exit code 0)
    directory = tmp_path / "long"
    save_dataset(lissajous_team(robots=3, steps=1000, seed=1, landmarks=600), directory)
    team_path = _team_file(
        tmp_path,
        f"int-{os.getpid()}",
        directory,
        _port(18),
        timeout_s=5.0,
        settings={"filter.window": 8},
    )
    out = tmp_path / "out"
    launcher = subprocess.Popen(
        [sys.executable, "-m", "teamslam", "team", "launch", str(team_path), "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # started with SIGINT ignored, as a shell without job control starts a background job
        # (`make test &`) and what it runs: the launcher still stops on it
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    deadline = time.monotonic() + 120

    def staged(r: int) -> list[Path]:  # the run is written into a staging folder beside out
        return list(tmp_path.glob(f".out.*/robot_{r}/progress.json"))

    def progress(r: int) -> int:
        return max((frames_done(p.parent.parent, r) for p in staged(r)), default=0)

    # interrupted while the robots are filtering (frame 5 written), not while they start
    while time.monotonic() < deadline and launcher.poll() is None and progress(0) < 6:
        time.sleep(0.05)
    assert launcher.poll() is None, "the team ended before it could be interrupted"
    pids = []
    for r in range(3):
        for found in staged(r):
            try:
                pids.append(json.loads(found.read_text())["pid"])
            except (OSError, ValueError):
                continue
    launcher.send_signal(signal.SIGINT)
    try:
        _, err = launcher.communicate(timeout=60)
    finally:  # a launcher that did not stop leaves no team running after the test
        if launcher.poll() is None:
            for pid in [launcher.pid, *pids]:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            launcher.wait()
    assert launcher.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    # an interrupted run leaves nothing that looks like a run
    assert not out.exists() and list(tmp_path.glob(".out.*")) == []
    time.sleep(0.5)
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


class _SlowReceiver(ZenohTransport):
    """A transport whose subscriber takes a while per message (a robot busy with its filter)."""

    received = 0

    def _on_sample(self, sample) -> None:
        time.sleep(0.002)
        super()._on_sample(sample)
        self.received += 1


def test_lockstep_transport_delivers_a_burst_to_a_slow_receiver(small_team, tmp_path):
    """Lock-step needs every message: a burst larger than Zenoh's link queue is not dropped.

    With Zenoh's default congestion control for puts (drop) most of this burst is lost.
    """
    _, directory = small_team
    team = load_team_file(
        _team_file(tmp_path, f"burst-{os.getpid()}", directory, _port(27), sync="lockstep")
    )
    sender, receiver = ZenohTransport(team, 0), _SlowReceiver(team, 1)
    try:
        deadline = time.monotonic() + 30.0
        while 1 not in sender.alive_neighbours() and time.monotonic() < deadline:
            time.sleep(0.05)
        identity = np.eye(120)  # 40 objects: 115 kB a message
        for step in range(1, 201):
            sender.send(CommonMarginalMessage(0, 1, step, np.arange(40), np.zeros(120), identity))
        deadline = time.monotonic() + 60.0
        while receiver.received < 200 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert receiver.received == 200
        assert [m.step for m in receiver.collect(200, CommonMarginalMessage, {0}, 1.0)] == [200]
    finally:
        sender.close()
        receiver.close()


def test_a_robot_tracking_detections_resumes_with_the_same_ids(tmp_path, monkeypatch):
    """A robot that names its objects itself (detections without ids, loop closure, appearance)
    crashes after a checkpoint and resumes: the same estimate and the same id for every
    detection as the uninterrupted run."""
    from teamslam.datasets.identity import strip_object_ids
    from teamslam.msckf.agent import MsckfAgent

    team_data = lissajous_team(
        robots=1, steps=60, objects=80, seed=3, clutter=0.05, miss=0.1, classes=3, appearance=8
    )
    save_dataset(strip_object_ids(team_data, to="none"), tmp_path / "data")
    team_path = tmp_path / "solo.yaml"
    team_path.write_text(
        f"team: solo\ndataset: {tmp_path / 'data'}\ncheckpoint_every: 20\n"
        "settings: {filter: {window: 10, object_std: 2.0}, tracking: {loop_closure: true}}\n"
        f"robots:\n  - id: 0\n    listen: tcp/127.0.0.1:{_port(7)}\n"
    )
    team = load_team_file(team_path)
    whole = run_agent(team, 0, tmp_path / "whole", transport=MemoryNetwork(1).endpoint(0))
    original_step = MsckfAgent.step

    def crashing(self, t):
        if t == 50:
            raise RuntimeError("simulated crash")
        return original_step(self, t)

    monkeypatch.setattr(MsckfAgent, "step", crashing)
    with pytest.raises(RuntimeError, match="simulated crash"):
        run_agent(team, 0, tmp_path / "crash", transport=MemoryNetwork(1).endpoint(0))
    monkeypatch.setattr(MsckfAgent, "step", original_step)
    resumed = run_agent(
        team, 0, tmp_path / "crash", resume=True, transport=MemoryNetwork(1).endpoint(0)
    )
    a, _ = load_robot_result(tmp_path / "whole", 0)
    b, _ = load_robot_result(tmp_path / "crash", 0)
    np.testing.assert_array_equal(a["poses"], b["poses"])
    np.testing.assert_array_equal(a["object_ids"], b["object_ids"])
    np.testing.assert_array_equal(a["objects"], b["objects"])
    assert whole["counters"]["tracks_confirmed"] > 10
    assert resumed["tracking_hypotheses"] == whole["tracking_hypotheses"]
