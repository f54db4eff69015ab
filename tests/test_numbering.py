"""One robot numbering: robot ``k`` of a run is the same robot in the printed table, the TUM
files, the MCAP topics, ``metrics.json``, the report and the dataset (counted from 0)."""

from __future__ import annotations

import contextlib
import io
import json
import re

import numpy as np
import pytest

from teamslam.cli import main
from teamslam.datasets import read_tum, save_dataset
from teamslam.eval.metrics import trajectory_rmse
from teamslam.ros2 import messages as m
from teamslam.ros2.bags import _read_topics
from teamslam.sim import lissajous_team

ROBOTS = 3


@pytest.fixture(scope="module")
def compared_run(tmp_path_factory):
    """A 3-robot team run separately and with consensus, with ``--out`` and ``--mcap``."""
    root = tmp_path_factory.mktemp("numbering")
    team = lissajous_team(robots=ROBOTS, steps=15, objects=60, seed=2)
    save_dataset(team, root / "data")
    out = root / "run"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        argv = [
            "run",
            str(root / "data"),
            "--compare",
            "--set",
            "filter.window=5",
            "--out",
            str(out),
        ]
        assert main([*argv, "--mcap"]) == 0
    return team, out, stdout.getvalue()


def _table_rows(text: str) -> dict[int, tuple[float, float]]:
    """``{k: (separate, consensus)}`` of the rows "robot k trajectory RMSE [m]"."""
    rows = re.findall(r"^robot (\d+) trajectory RMSE \[m\]\s+(\S+)\s+(\S+)\s*$", text, re.M)
    return {int(k): (float(a), float(b)) for k, a, b in rows}


def _mcap_positions(bag, topic: str) -> tuple[np.ndarray, np.ndarray]:
    (items,) = _read_topics(bag, {topic}).values()
    stamps = np.array([s for s, _ in items], dtype=np.int64)
    poses = np.stack([m.pose_matrix(msg.pose) for _, msg in items])
    return stamps, poses


def test_table_rows_tum_files_and_mcap_topics_name_the_same_robot(compared_run):
    team, out, text = compared_run
    rows = _table_rows(text)
    assert sorted(rows) == list(range(ROBOTS))  # robot 0 … robot R−1, no robot R
    assert not (out / "consensus" / f"robot_{ROBOTS}.tum").exists()
    metrics = json.loads((out / "metrics.json").read_text())
    for column, variant, prefix in ((0, "separate", "/separate"), (1, "consensus", "")):
        rmse_of_file = []
        for k in range(ROBOTS):
            stamps, estimate = read_tum(out / variant / f"robot_{k}.tum")
            truth_stamps, truth = read_tum(out / variant / f"robot_{k}_groundtruth.tum")
            # the ground-truth file is robot k of the dataset
            np.testing.assert_allclose(truth_stamps, team.robots[k].timestamps, atol=1e-9)
            np.testing.assert_allclose(
                truth[:, :3, 3], team.robots[k].T_world_body[:, :3, 3], atol=1e-9
            )
            # /robot_k/pose of the MCAP is robot_k.tum
            mcap_stamps, mcap = _mcap_positions(out / "run.mcap", f"{prefix}/robot_{k}/pose")
            np.testing.assert_array_equal(mcap_stamps, np.rint(stamps * 1e9).astype(np.int64))
            np.testing.assert_allclose(mcap[:, :3, 3], estimate[:, :3, 3], atol=1e-9)
            np.testing.assert_allclose(mcap[:, :3, :3], estimate[:, :3, :3], atol=1e-9)
            if not prefix:  # the main run carries the ground truth too
                _, mcap_truth = _mcap_positions(out / "run.mcap", f"/ground_truth/robot_{k}/pose")
                np.testing.assert_allclose(mcap_truth[:, :3, 3], truth[:, :3, 3], atol=1e-9)
            # the table row "robot k" is the RMSE of robot_k.tum against robot k's ground truth
            rmse = trajectory_rmse(estimate, truth)
            rmse_of_file.append(rmse)
            assert rows[k][column] == pytest.approx(rmse, abs=5e-4 + 1e-12)
        recorded = metrics["separate"] if variant == "separate" else metrics
        np.testing.assert_allclose(recorded["trajectory_rmse_m"], rmse_of_file, rtol=1e-9)
    # the robots are told apart: each starts where its own ground truth starts, far from others
    starts = np.stack([r.T_world_body[0, :3, 3] for r in team.robots])
    assert (
        np.min(np.linalg.norm(starts[:, None] - starts[None], axis=-1)[~np.eye(ROBOTS, dtype=bool)])
        > 1.0
    )


def test_report_and_eval_rows_are_the_same_robots(compared_run, capsys):
    _, out, _ = compared_run
    rmse = [
        trajectory_rmse(
            read_tum(out / "consensus" / f"robot_{k}.tum")[1],
            read_tum(out / "consensus" / f"robot_{k}_groundtruth.tum")[1],
        )
        for k in range(ROBOTS)
    ]
    capsys.readouterr()
    assert main(["eval", str(out), "--per-robot", "--json"]) == 0
    evaluated = json.loads(capsys.readouterr().out)
    (consensus,) = (s for name, s in evaluated["runs"].items() if name.endswith("/consensus"))
    ape = [r["ape_translation_m"]["rmse"] for r in consensus["robots"]]
    np.testing.assert_allclose(ape, rmse, rtol=1e-9)  # --align none: the trajectory RMSE
    assert main(["eval", str(out), "--per-robot"]) == 0
    table = capsys.readouterr().out
    for k in range(ROBOTS):
        row = re.search(rf"^robot {k} APE translation RMSE \[m\]\s+(\S+)\s+(\S+)", table, re.M)
        assert row is not None, table
        assert float(row.group(2)) == pytest.approx(rmse[k], rel=1e-3, abs=1e-4)
    assert f"robot {ROBOTS} APE" not in table
    report = (out / "report.html").read_text()
    assert [f"robot {k}" for k in range(ROBOTS)] == re.findall(
        r"<tr><td class='l'>(robot \d+)</td>", report
    )
