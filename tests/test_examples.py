"""Every script of ``examples/`` runs on a small size and produces what it says.

Each example runs as a user would run it, in a fresh interpreter, and a property of what it
wrote is checked here against the files themselves (not against what the script printed
about them). The example with robot processes listens on loopback ports: it is marked
``network`` like the other process tests (``make test`` runs those alone, after the rest).
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import teamslam as ts

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
PNG = b"\x89PNG\r\n\x1a\n"


def _example(name: str, *args, cwd: Path) -> str:
    """Run ``examples/NAME.py ARGS``; its standard output (it must exit 0)."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]),
        "OPENBLAS_NUM_THREADS": "1",
    }
    done = subprocess.run(
        [sys.executable, str(EXAMPLES / f"{name}.py"), *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
        timeout=900,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def _module(name: str):
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_example_is_listed_in_the_readme_and_tested_here():
    scripts = sorted(p.stem for p in EXAMPLES.glob("*.py"))
    readme = (EXAMPLES / "README.md").read_text()
    tests = Path(__file__).read_text()
    assert len(scripts) == 5, scripts
    for name in scripts:
        assert f"`{name}.py`" in readme, name
        assert f'_example("{name}"' in tests, name


def test_simulate_team_consensus_agrees_on_one_map_and_beats_odometry(tmp_path):
    out = tmp_path / "team"
    printed = _example("simulate_team", "--robots", 3, "--steps", 40, "--out", out, cwd=tmp_path)
    run = ts.load_run(out)
    separate, consensus = run.by_mode["separate"], run.by_mode["consensus"]
    assert consensus["trajectory_rmse_avg_m"] < consensus["odometry_rmse_avg_m"]
    assert separate["trajectory_rmse_avg_m"] < separate["odometry_rmse_avg_m"]
    # alone every robot builds its own map; with consensus the maps agree
    assert consensus["object_disagreement_avg_m"] < 0.1 * separate["object_disagreement_avg_m"]
    assert separate["bytes_per_robot_step"] == 0 < consensus["bytes_per_robot_step"]
    # the printed table is the run's metrics
    row = re.search(r"trajectory RMSE \[m\]\s+(\S+)\s+(\S+)", printed)
    assert float(row[1]) == pytest.approx(separate["trajectory_rmse_avg_m"], abs=1e-4)
    assert float(row[2]) == pytest.approx(consensus["trajectory_rmse_avg_m"], abs=1e-4)


def test_own_data_is_loaded_back_as_written_and_runs(tmp_path):
    out = tmp_path / "own"
    _example("own_data", "--robots", 2, "--steps", 30, "--seed", 4, "--out", out, cwd=tmp_path)
    written = _module("own_data").make_dataset(2, 30, 4)
    loaded = ts.datasets.load_dataset(out / "dataset")
    assert loaded.name == written.name and loaded.n_robots == 2
    assert loaded.sensor_model == written.sensor_model
    assert loaded.calibration.image_size == written.calibration.image_size
    np.testing.assert_array_equal(loaded.calibration.T_cam_body, written.calibration.T_cam_body)
    np.testing.assert_array_equal(loaded.object_positions, written.object_positions)
    for a, b in zip(loaded.robots, written.robots, strict=True):
        np.testing.assert_array_equal(a.T_world_body, b.T_world_body)
        np.testing.assert_array_equal(a.odometry, b.odometry)
        np.testing.assert_array_equal(a.timestamps, b.timestamps)
        for name in ("offsets", "ids", "measurements"):
            np.testing.assert_array_equal(getattr(a.objects, name), getattr(b.objects, name))
        assert a.objects.ids.size > 0 and a.features.ids.size == 0
    run = ts.load_run(out / "run")
    for metrics in run.by_mode.values():
        assert metrics["trajectory_rmse_avg_m"] < metrics["odometry_rmse_avg_m"]


def test_evaluate_run_writes_ape_rpe_figures_and_the_html_report(tmp_path):
    out = tmp_path / "eval"
    _example("evaluate_run", "--robots", 2, "--steps", 30, "--out", out, cwd=tmp_path)
    metrics = json.loads((out / "run" / "metrics.json").read_text())
    for align in ("none", "se3"):
        runs = json.loads((out / f"align-{align}" / "eval.json").read_text())["runs"]
        assert set(runs) == {"run/separate", "run/consensus"}
        for stats in runs.values():
            assert stats["align"] == align
            assert stats["team"]["rpe_translation_m"]["count"] > 0
        for figure in ("trajectories", "ape_over_time", "ape_path"):
            assert (out / f"align-{align}" / f"{figure}.png").read_bytes()[:8] == PNG
    # unaligned APE of each filter is the trajectory RMSE the run itself reported
    runs = json.loads((out / "align-none" / "eval.json").read_text())["runs"]
    for name, own in (("run/separate", metrics["separate"]), ("run/consensus", metrics)):
        ape = runs[name]["team"]["ape_translation_rmse_avg_m"]
        assert ape == pytest.approx(own["trajectory_rmse_avg_m"], rel=1e-9)
    html = (out / "report.html").read_text()
    assert html.startswith("<!DOCTYPE html>") and html.rstrip().endswith("</html>")
    assert html.count("src='data:image/png;base64,") >= 3
    for section in ("Accuracy", "Consistency", "Messages"):
        assert f"<h2>{section}" in html


def test_images_to_map_maps_markers_near_their_true_positions(tmp_path):
    pytest.importorskip("cv2", reason="the images extra (OpenCV) is not installed")
    out = tmp_path / "images"
    _example("images_to_map", "--robots", 2, "--steps", 20, "--out", out, cwd=tmp_path)
    dataset = ts.datasets.load_dataset(out / "dataset")
    assert dataset.metadata["images"]["robots"][0]["stereo_observations_per_frame"] > 50
    run = ts.load_run(out / "run", dataset)
    result = run.results["consensus"]
    for ids, positions in zip(result.object_ids, result.objects, strict=True):
        assert ids.size >= 2
        error = np.linalg.norm(positions - dataset.object_position(ids), axis=1)
        assert np.median(error) < 0.2, error  # markers are 0.9 m wide
    metrics = run.metrics
    assert metrics["trajectory_rmse_avg_m"] < metrics["odometry_rmse_avg_m"]


@pytest.mark.network
def test_team_of_processes_equals_the_team_in_one_process(tmp_path):
    pytest.importorskip("zenoh", reason="the network extra (Zenoh) is not installed")
    port = 28000 + (os.getpid() % 500) * 8  # below the ephemeral range, distinct per run
    out = tmp_path / "processes"
    args = ("--robots", 2, "--steps", 15, "--base-port", port, "--out", out)
    printed = _example("team_of_processes", *args, cwd=tmp_path)
    metrics = json.loads((out / "processes" / "metrics.json").read_text())
    assert len(metrics["transport"]) == 2
    assert all(t["bytes_per_step"] > 0 for t in metrics["transport"])
    assert (out / "processes" / "team.yaml").is_file()
    assert float(re.search(r"between the two: (\S+) m", printed)[1]) < 1e-6
    # the same estimates as the team in one process (lock-step, no loss), computed here
    from teamslam.msckf.team import load_result

    gathered = load_result(out / "processes")
    dataset = ts.datasets.load_dataset(out / "dataset")
    alone = ts.run(dataset, mode="consensus", progress=False).results["consensus"]
    for p, q in zip(gathered.poses, alone.poses, strict=True):
        np.testing.assert_allclose(p, q, rtol=0, atol=1e-9)
