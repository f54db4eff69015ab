"""One team driver, one result, the library first.

Every run goes through :class:`teamslam.msckf.team.RobotDriver`: the robot process gives the
in-process run's result — object covariances, the ``ideal`` linearisation and link-loss
counts included —, :mod:`teamslam.api` writes what the command line writes, a configuration
error exits 2 whether robots run in this process or as processes, and a filter failing mid-run
exits 1 naming robot and frame after writing what was computed.
"""

from __future__ import annotations

import json
import os
import subprocess

import numpy as np
import pytest

from teamslam import api
from teamslam.cli import main
from teamslam.datasets import save_dataset
from teamslam.errors import EstimationError, InputError, OutputError
from teamslam.eval.outputs import json_safe
from teamslam.graph import EdgeLoss, from_edges, metropolis_weight, metropolis_weights, ring
from teamslam.msckf import config_for, run_team
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.consensus.protocol import ConsensusProtocol
from teamslam.msckf.consensus.transport import MemoryNetwork
from teamslam.msckf.team import PartialRunError, load_result, merge_results, save_result
from teamslam.runtime.agent_process import load_robot_result, run_agent
from teamslam.runtime.launch import agent_command
from teamslam.runtime.team_file import load_team_file, write_team_file
from teamslam.sim import lissajous_team
from test_protocol import _threads_over_memory  # the robot-process driver in threads


@pytest.fixture(scope="module")
def team3(tmp_path_factory):
    directory = tmp_path_factory.mktemp("team3") / "data"
    dataset = lissajous_team(robots=3, steps=24, seed=4, landmarks=500)
    save_dataset(dataset, directory)
    return dataset, directory


def _port(offset: int) -> int:
    """Loopback ports below the ephemeral range, distinct per test (offsets 0–15)."""
    return 27000 + (os.getpid() % 300) * 16 + offset


def _ring_team(tmp_path, directory, port: int, timeout_s: float = 5.0, settings=None):
    """A team file of the 3-robot ring on loopback (``port``: offset), filter window 6."""
    return write_team_file(
        tmp_path / "team.yaml",
        f"driver-{os.getpid()}-{port}",
        directory,
        ring(3).adjacency,
        base_port=_port(port),
        timeout_s=timeout_s,
        settings={"filter.window": 6, **(settings or {})},
    )


@pytest.mark.parametrize("linearization", ["ideal", "fej"])
def test_process_driver_gives_the_in_process_result_with_object_covariances(
    team3, tmp_path, linearization
):
    dataset, directory = team3
    n, loss = dataset.n_robots, 0.35
    graph = ring(n)
    draws = EdgeLoss(graph, loss, seed=3)
    schedule = [draws.step()[0] for _ in range(dataset.robots[0].frames)]
    config = config_for(dataset, {"filter.window": 6, "filter.linearization": linearization})
    reference = run_team(dataset, config, graph=graph, loss=loss, seed=3, progress=False)
    team_path = _ring_team(
        tmp_path, directory, 0, timeout_s=60.0, settings={"filter.linearization": linearization}
    )
    _threads_over_memory(team_path, tmp_path / "out", lambda t: schedule[t], n)
    parts = [load_result(tmp_path / "out" / f"robot_{r}") for r in range(n)]
    for r, part in enumerate(parts):
        assert part.robots == [r] and part.complete
        np.testing.assert_array_equal(part.poses[0], reference.poses[r])
        np.testing.assert_array_equal(part.pose_covs[0], reference.pose_covs[r])
        np.testing.assert_array_equal(part.object_ids[0], reference.object_ids[r])
        np.testing.assert_array_equal(part.objects[0], reference.objects[r])
        assert part.object_covs[0].shape == (reference.objects[r].shape[0], 3, 3)
        np.testing.assert_array_equal(part.object_covs[0], reference.object_covs[r])
        assert part.frame_times[0].shape == reference.frame_times[r].shape
        for key in ("objects_averaged", "links_lost", "bytes", "messages", "updates"):
            assert part.counters[0].get(key, 0) == reference.counters[r].get(key, 0), key
    # the links the draws took down, counted at both ends by both drivers
    upper = np.triu_indices(n, 1)
    lost = sum(int((~a[upper] & graph.adjacency[upper]).sum()) for a in schedule[1:])
    assert lost > 0
    assert sum(c.get("links_lost", 0) for c in reference.counters) == 2 * lost
    # joined as a launch joins them: the team's health is the in-process run's
    merged = merge_results(parts, "memory", loss)
    assert merged.health == reference.health
    assert merged.robots == list(range(n))


def test_robot_processes_keep_object_covariances_and_run_ideal(team3, tmp_path):
    """Real processes over Zenoh on loopback, launched and gathered by the library."""
    dataset, directory = team3
    team_path = _ring_team(
        tmp_path, directory, 0, timeout_s=20.0, settings={"filter.linearization": "ideal"}
    )
    run = api.launch(team_path, tmp_path / "out", progress=False)
    assert run.exit_status == 0, run.notes
    reference = run_team(
        dataset,
        config_for(dataset, {"filter.window": 6, "filter.linearization": "ideal"}),
        ring(3),
        progress=False,
    )
    result = run.results["consensus"]
    # equal to the last bits: arrays decoded from the wire may be reduced in another order
    for r in range(3):
        for name in ("poses", "pose_covs", "objects", "object_covs"):
            np.testing.assert_allclose(
                getattr(result, name)[r], getattr(reference, name)[r], rtol=1e-8, atol=1e-9
            )
        np.testing.assert_array_equal(result.object_ids[r], reference.object_ids[r])
    assert run.metrics["objects_in_map"] == [int(i.size) for i in reference.object_ids]
    # the run directory is the in-process run's: estimates with covariances for the MCAP
    with np.load(tmp_path / "out" / "estimates.npz") as npz:
        assert npz["robot_0_object_covs"].shape == (reference.object_ids[0].size, 3, 3)


def test_a_configuration_error_exits_2_in_process_and_with_processes(team3, tmp_path, capsys):
    _, directory = team3
    for extra in ([], ["--processes", "--base-port", str(_port(4))]):
        out = tmp_path / f"run{len(extra)}"
        argv = ["run", str(directory), "--set", "filter.window=1", "--out", str(out), *extra]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "window" in err
        assert not (out / "robot_0.log").exists()  # refused before any process started
    # a team file whose filter settings no robot can use: refused before launching ...
    team_path = _ring_team(tmp_path, directory, 6, settings={"filter.window": 1})
    assert main(["team", "launch", str(team_path), "--out", str(tmp_path / "team")]) == 2
    assert "window" in capsys.readouterr().err
    assert not (tmp_path / "team" / "robot_0.log").exists()
    # ... and the robot process itself exits 2
    proc = subprocess.run(
        agent_command(team_path, 0, tmp_path / "agent"),
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 2, proc.stderr
    assert "window" in proc.stderr


def _files(directory):
    return sorted(
        str(p.relative_to(directory))
        for p in directory.rglob("*")
        if p.is_file() and p.suffix not in (".png", ".log")
    )


def _strip_times(value):
    if isinstance(value, dict):
        return {
            k: _strip_times(v)
            for k, v in value.items()
            # kernels_loaded: how many compiled kernels this process had still to load from
            # the cache, which depends on what ran before in the same process
            if not any(s in k for s in ("time", "seconds", "_ms", "kernels_loaded"))
        }
    if isinstance(value, list):
        return [_strip_times(v) for v in value]
    return value


def test_the_library_writes_what_the_command_line_writes(team3, tmp_path, capsys):
    _, directory = team3
    cli_out, lib_out = tmp_path / "cli", tmp_path / "lib"
    argv = ["run", str(directory), "--compare", "--set", "filter.window=6", "--no-report"]
    assert main([*argv, "--out", str(cli_out)]) == 0
    capsys.readouterr()
    run = api.run(directory, "compare", settings={"filter.window": 6}, progress=False)
    api.write_run(run, lib_out, report=False)
    assert _files(cli_out) == _files(lib_out)
    assert "consensus/estimates.npz" in _files(lib_out)
    metrics = json.loads((lib_out / "metrics.json").read_text())
    assert _strip_times(metrics) == _strip_times(json.loads((cli_out / "metrics.json").read_text()))
    # the run's metrics are what metrics.json holds (NaN written as null)
    assert _strip_times(json.loads(json.dumps(json_safe(run.metrics)))) == _strip_times(metrics)
    for name in ("separate", "consensus"):
        for k in range(3):
            tum = f"{name}/robot_{k}.tum"
            assert (cli_out / tum).read_bytes() == (lib_out / tum).read_bytes()
        with (
            np.load(cli_out / name / "estimates.npz") as a,
            np.load(lib_out / name / "estimates.npz") as b,
        ):
            assert a.files == b.files
            for key in a.files:
                np.testing.assert_array_equal(a[key], b[key])
    # and reads back: the same results and metrics
    loaded = api.load_run(lib_out)
    assert list(loaded.results) == ["separate", "consensus"]
    for name, result in run.results.items():
        for k in range(3):
            np.testing.assert_array_equal(loaded.results[name].poses[k], result.poses[k])
            np.testing.assert_array_equal(
                loaded.results[name].object_covs[k], result.object_covs[k]
            )
        assert loaded.results[name].counters == result.counters
    assert _strip_times(loaded.metrics) == _strip_times(metrics)
    assert loaded.source == directory


def test_a_result_that_cannot_be_written_names_the_path(team3, tmp_path):
    dataset, _ = team3
    result = run_team(
        dataset.subset([0]), config_for(dataset, {"filter.window": 6}), progress=False
    )
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    with pytest.raises(OutputError, match="file"):
        save_result(result, blocker / "out")
    run = api.Run(dataset.subset([0]), {"consensus": result}, {"consensus": {"robots": 1}})
    # a run directory is refused before anything is written, naming what is in the way
    with pytest.raises(InputError, match=f"{blocker} exists and is not a directory"):
        api.write_run(run, blocker / "run", report=False)


def _fail_robot_1_at_frame_5(monkeypatch):
    """Robot 1's filter loses positive definiteness at frame 5 (as a diverging filter)."""
    from teamslam.gaussian import NotPositiveDefiniteError

    original = MsckfAgent._step

    def failing(self, t):
        if self.robot == 1 and t == 5:
            raise NotPositiveDefiniteError("innovation covariance is not positive definite")
        return original(self, t)

    monkeypatch.setattr(MsckfAgent, "_step", failing)


def test_a_filter_failing_mid_run_exits_1_and_keeps_the_frames_done(
    team3, tmp_path, capsys, monkeypatch
):
    dataset, directory = team3
    _fail_robot_1_at_frame_5(monkeypatch)
    out = tmp_path / "run"
    code = main(["run", str(directory), "--set", "filter.window=6", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1
    assert "robot 1, frame 5" in err and "error:" not in err
    partial = load_result(out)
    assert not partial.complete
    assert [p.shape[0] for p in partial.poses] == [5, 5, 5]  # frames 0-4 of every robot
    for k in range(3):
        assert np.all(np.isfinite(partial.poses[k]))
        lines = (out / f"robot_{k}.tum").read_text().strip().splitlines()
        assert len(lines) == 5
    # the library raises with the same frames
    with pytest.raises(PartialRunError, match="robot 1, frame 5") as caught:
        run_team(dataset, config_for(dataset, {"filter.window": 6}), progress=False)
    for k in range(3):
        np.testing.assert_array_equal(caught.value.result.poses[k], partial.poses[k])


def test_a_robot_process_failing_mid_run_keeps_its_frames(team3, tmp_path, monkeypatch):
    _, directory = team3
    _fail_robot_1_at_frame_5(monkeypatch)
    team_path = tmp_path / "solo.yaml"
    team_path.write_text(
        f"team: solo\ndataset: {directory}\nsettings: {{filter: {{window: 6}}}}\nrobots:\n"
        "  - {id: 0}\n  - {id: 1}\n"
    )
    team = load_team_file(team_path)
    with pytest.raises(EstimationError, match="robot 1, frame 5"):
        run_agent(team, 1, tmp_path / "out", transport=MemoryNetwork(2).endpoint(1))
    arrays, summary = load_robot_result(tmp_path / "out", 1)
    assert arrays["poses"].shape == (5, 4, 4) and np.all(np.isfinite(arrays["poses"]))
    assert summary["frames"] == team3[0].robots[1].frames
    assert not load_result(tmp_path / "out" / "robot_1").complete


def test_a_nan_measurement_mid_run_exits_1_naming_robot_and_frame(
    team3, tmp_path, capsys, monkeypatch
):
    _, directory = team3
    original = MsckfAgent._feature_rows

    def poisoned(self, t):
        rows = original(self, t)
        if self.robot == 1 and t == 5 and rows.rows:
            rows.residual[0] = np.nan
        return rows

    monkeypatch.setattr(MsckfAgent, "_feature_rows", poisoned)
    out = tmp_path / "run"
    code = main(["run", str(directory), "--set", "filter.window=6", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 1, err
    assert "robot 1" in err and "frame 5" in err
    partial = load_result(out)
    assert not partial.complete and all(np.all(np.isfinite(p)) for p in partial.poses)


def test_the_metropolis_weight_is_written_once():
    adjacency = from_edges(5, [(0, 1), (0, 2), (0, 3), (1, 2), (3, 4)]).adjacency
    weights = metropolis_weights(adjacency)
    degree = adjacency.sum(axis=1)
    for i, j in zip(*np.nonzero(adjacency), strict=True):
        assert weights[i, j] == metropolis_weight(degree[i], degree[j])
    np.testing.assert_allclose(weights.sum(axis=0), 1.0)
    # the protocol's weights of the links heard are the graph's
    agent = MsckfAgent(0, *_one_robot())
    protocol = ConsensusProtocol(agent, [1, 2])
    protocol.heard = {1, 2}
    own, others = protocol.weights({1: 3, 2: 1})
    assert others == {1: metropolis_weight(2, 3), 2: metropolis_weight(2, 1)}
    assert own == 1.0 - sum(others.values())


def _one_robot():
    dataset = lissajous_team(robots=1, steps=4, seed=0, landmarks=50)
    return dataset.calibration, dataset.robots[0], config_for(dataset, {"filter.window": 4})
