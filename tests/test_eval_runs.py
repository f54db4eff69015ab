"""``teamslam eval`` and ``teamslam report`` on a real (small) team run.

One simulated 3-robot team is run once with ``--compare`` for the whole module; the tests read
what ``teamslam run`` left in its directory.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from teamslam.cli import main
from teamslam.datasets import read_tum, write_kitti
from teamslam.eval.runs import load_runs, read_series


@pytest.fixture(scope="module")
def team_run(tmp_path_factory) -> tuple[Path, Path]:
    """``(dataset, run directory)`` of a 3-robot team run separately and with consensus."""
    root = tmp_path_factory.mktemp("team")
    data, run = root / "team3", root / "team3-run"
    argv = ["simulate", "--robots", "3", "--steps", "20", "--objects", "60", "--seed", "1"]
    assert main([*argv, "--out", str(data)]) == 0
    assert main(["run", str(data), "--compare", "--set", "filter.window=5", "--out", str(run)]) == 0
    return data, run


def _eval_json(capsys, *argv: str) -> dict:
    capsys.readouterr()
    assert main(["eval", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)["runs"]


def test_run_writes_report_series_and_prints_the_report_path(team_run, capsys):
    data, run = team_run
    assert (run / "report.html").is_file()
    for variant in ("separate", "consensus"):
        series = read_series(run / variant)
        assert series is not None and len(series["nees"]) == 3
        assert all(
            len(n) == 21 and t.shape == (21, 4) for n, t in zip(*series.values(), strict=False)
        )
    # the last line `teamslam run` prints is where the report is
    other = run.parent / "single-run"
    capsys.readouterr()
    assert main(["run", str(data), "--set", "filter.window=5", "--out", str(other)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out[-1] == f"report: {other / 'report.html'}"
    assert read_series(other) is not None
    metrics = json.loads((other / "metrics.json").read_text())
    # the recorded NEES series is the one metrics.json averages
    nees = read_series(other)["nees"]
    assert [float(np.mean(v[1:])) for v in nees] == metrics["nees_pose_avg"]


def test_eval_align_none_reproduces_metrics_json_exactly(team_run, capsys):
    _, run = team_run
    metrics = json.loads((run / "metrics.json").read_text())
    stats = _eval_json(capsys, str(run), "--align", "none")
    assert set(stats) == {f"{run.name}/separate", f"{run.name}/consensus"}
    for variant, m in (("separate", metrics["separate"]), ("consensus", metrics)):
        s = stats[f"{run.name}/{variant}"]
        rmse = [r["ape_translation_m"]["rmse"] for r in s["robots"]]
        assert rmse == m["trajectory_rmse_m"]  # bit for bit
        assert s["team"]["ape_translation_rmse_avg_m"] == m["trajectory_rmse_avg_m"]
        assert s["team"]["ape_translation_rmse_max_m"] == m["trajectory_rmse_max_m"]


def _same_team(a: dict, b: dict) -> None:
    """Equal statistics: positions bit for bit, rotations up to their quaternion round trip."""
    assert a["ape_translation_m"] == b["ape_translation_m"]
    for key in ("ape_rotation_deg", "rpe_translation_m", "rpe_rotation_deg"):
        for stat in ("rmse", "mean", "median", "max"):
            assert a[key][stat] == pytest.approx(b[key][stat], rel=1e-10, abs=1e-12)


def test_eval_reference_from_dataset_tum_and_kitti_files_agree(team_run, capsys, tmp_path):
    data, run = team_run
    (recorded,) = _eval_json(capsys, str(run / "consensus"), "--align", "se3").values()
    (from_dataset,) = _eval_json(
        capsys, str(run / "consensus"), "--align", "se3", "--ref", str(data)
    ).values()
    _same_team(recorded["team"], from_dataset["team"])
    # the same team as bare files: TUM estimates with TUM references, KITTI with KITTI
    tum = [str(run / "consensus" / f"robot_{k}.tum") for k in range(3)]
    ref_tum = [str(run / "consensus" / f"robot_{k}_groundtruth.tum") for k in range(3)]
    (files,) = _eval_json(capsys, ",".join(tum), "--align", "se3", "--ref-tum", *ref_tum).values()
    assert files["team"] == recorded["team"]
    kitti, ref_kitti = [], []
    for k in (1, 2, 3):
        for source, names in ((tum, kitti), (ref_tum, ref_kitti)):
            path = tmp_path / f"{Path(source[k - 1]).stem}.txt"
            write_kitti(path, read_tum(source[k - 1])[1])
            names.append(str(path))
    (files,) = _eval_json(
        capsys, ",".join(kitti), "--align", "se3", "--ref-kitti", *ref_kitti
    ).values()
    _same_team(files["team"], recorded["team"])


def test_eval_alignment_scopes_and_table(team_run, capsys, tmp_path):
    _, run = team_run
    none = _eval_json(capsys, str(run))
    team = _eval_json(capsys, str(run), "--align", "sim3", "--team")
    robot = _eval_json(capsys, str(run), "--align", "sim3", "--per-robot", "--rpe-delta", "2")
    for name in none:
        # a least-squares alignment can only lower the pooled position RMSE; per robot lower still
        a = none[name]["team"]["ape_translation_m"]["rmse"]
        b = team[name]["team"]["ape_translation_m"]["rmse"]
        c = robot[name]["team"]["ape_translation_m"]["rmse"]
        assert c <= b <= a
        assert robot[name]["rpe_delta"] == 2
    metres = _eval_json(capsys, str(run), "--rpe-unit", "m", "--rpe-delta", "1.5")
    for name, s in metres.items():
        # pairs 1.5 m apart along the path: fewer than the pairs one frame apart
        assert s["rpe_unit"] == "m"
        pairs = s["team"]["rpe_translation_m"]["count"]
        assert 0 < pairs < none[name]["team"]["rpe_translation_m"]["count"]
    capsys.readouterr()
    assert main(["eval", str(run), "--align", "first-pose", "--out", str(tmp_path / "ev")]) == 0
    table = capsys.readouterr().out
    assert f"{run.name}/separate" in table and "robot 2 APE translation RMSE [m]" in table
    assert "robot 3 APE" not in table  # robots 0, 1, 2
    for name in ("eval.json", "trajectories.png", "ape_over_time.png", "ape_path.png"):
        assert (tmp_path / "ev" / name).stat().st_size > 1000


@pytest.mark.parametrize(
    ("make", "argv", "message"),
    [
        (None, ["eval", "{tmp}/nowhere"], "no such trajectory file"),
        ("empty_dir", ["eval", "{tmp}/empty"], "not a run directory"),
        ("bad_tum", ["eval", "{tmp}/bad.tum", "--ref-tum", "{tmp}/bad.tum"], "bad.tum"),
        ("two_files", ["eval", "{tmp}/a.tum", "--ref-tum", "{tmp}/a.tum", "{tmp}/b.tum"], "2"),
        ("bad_tum", ["eval", "{run}", "--rpe-delta", "1.5"], "whole number"),
        ("nan_tum", ["eval", "{tmp}/nan.tum", "--ref-tum", "{tmp}/nan.tum"], "non-finite"),
    ],
)
def test_eval_bad_input_is_one_line_and_exit_2(team_run, tmp_path, capsys, make, argv, message):
    _, run = team_run
    if make == "empty_dir":
        (tmp_path / "empty").mkdir()
    if make == "bad_tum":
        (tmp_path / "bad.tum").write_text("0 1 2 3 0 0 0 1\n1 1 2 3 0 0\n")
    if make == "two_files":
        shutil.copy(run / "consensus" / "robot_0.tum", tmp_path / "a.tum")
        shutil.copy(run / "consensus" / "robot_1.tum", tmp_path / "b.tum")
    if make == "nan_tum":
        (tmp_path / "nan.tum").write_text("0 1 2 3 0 0 0 1\n1 nan 2 3 0 0 0 1\n")
    capsys.readouterr()
    args = [a.format(tmp=tmp_path, run=run) for a in argv]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err


def test_report_is_self_contained_small_and_side_by_side(team_run, tmp_path, capsys):
    _, run = team_run
    single = run.parent / "single-run"
    if not single.is_dir():
        data, _ = team_run
        main(["run", str(data), "--set", "filter.window=5", "--out", str(single)])
    out = tmp_path / "both.html"
    assert main(["report", str(run), str(single), "--out", str(out)]) == 0
    text = out.read_text()
    assert out.stat().st_size < 3e6
    # nothing to fetch: no script, no stylesheet link, every src is inline data
    assert "<script" not in text and "<link" not in text
    srcs = re.findall(r"src\s*=\s*['\"]([^'\"]{0,22})", text)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)
    # three columns (separate, consensus, the single run) in the accuracy table
    header = re.search(r"<table id=\"accuracy-table\"><thead><tr>(.*?)</tr>", text).group(1)
    assert header.count("<th colspan") == 3 and "single-run" in header
    for section in ("team", "accuracy", "consistency", "health", "timing", "messages"):
        assert f"<section id='{section}'>" in text
    assert "window" in text and "(flag)" in text  # the setting and where it came from


def test_report_renders_in_headless_chromium(team_run, tmp_path, chromium):
    from matplotlib.image import imread

    _, run = team_run
    page = (run / "report.html").resolve().as_uri()
    dom = chromium("--dump-dom", page)
    assert dom.returncode == 0, dom.stderr[-2000:]
    assert (
        f"<title>teamslam report: {run.name}/separate, {run.name}/consensus</title>" in dom.stdout
    )
    metrics = json.loads((run / "metrics.json").read_text())
    assert "APE translation [m]" in dom.stdout and "RMSE per robot" in dom.stdout
    assert f"{metrics['trajectory_rmse_avg_m']:.4g}" in dom.stdout
    shot = tmp_path / "report.png"
    done = chromium(f"--screenshot={shot}", page)
    assert done.returncode == 0 and shot.is_file(), done.stderr[-2000:]
    rgb = (imread(shot)[..., :3] * 255).round().astype(int)
    assert rgb.shape[:2] == (1400, 1280)
    # non-blank: plenty of non-white pixels and many colours
    assert np.mean(np.any(rgb < 240, axis=-1)) > 0.02
    assert len(np.unique(rgb.reshape(-1, 3), axis=0)) > 50
    # the embedded communication-graph figure was decoded: robot 0 is drawn in tab:blue
    blue = np.all(np.abs(rgb - np.array([31, 119, 180])) <= 6, axis=-1)
    assert blue.sum() > 30


def test_load_runs_reads_both_layouts(team_run):
    _, run = team_run
    runs = load_runs(run)
    assert [r.name for r in runs] == [f"{run.name}/separate", f"{run.name}/consensus"]
    assert runs[0].metrics["consensus"] is False and runs[1].metrics["consensus"] is True
    assert "separate" not in runs[1].metrics
    assert all(len(r.estimates) == 3 and len(r.references) == 3 for r in runs)


def test_graph_adjacency_from_team_file_or_graph_name(tmp_path):
    from teamslam.eval.report import graph_adjacency
    from teamslam.eval.runs import TeamRun
    from teamslam.graph import random_geometric, ring
    from teamslam.runtime.team_file import write_team_file

    named = TeamRun("a", [], metrics={"graph": "ring(4)"}, directory=tmp_path)
    np.testing.assert_array_equal(graph_adjacency(named), ring(4).adjacency)
    drawn = random_geometric(5, seed=3)
    unknown = TeamRun("b", [], metrics={"graph": drawn.name}, directory=tmp_path)
    assert graph_adjacency(unknown) is None  # a random draw is not rebuilt from its name
    write_team_file(tmp_path / "team.yaml", "t", tmp_path, drawn.adjacency)
    np.testing.assert_array_equal(graph_adjacency(unknown), drawn.adjacency)
