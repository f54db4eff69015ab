"""The command line of objects without shared ids: strip-ids, --object-ids, run --association."""

from __future__ import annotations

import json

import numpy as np

from teamslam.cli import main
from teamslam.datasets.storage import load_dataset


def test_strip_ids_then_run_with_own_association(tmp_path, capsys):
    data, stripped = tmp_path / "data", tmp_path / "stripped"
    assert (
        main(["simulate", "--robots", "3", "--steps", "40", "--seed", "4", "--out", str(data)]) == 0
    )
    assert main(["data", "strip-ids", str(data), "--out", str(stripped), "--seed", "3"]) == 0
    before, after = load_dataset(data), load_dataset(stripped)
    assert before.object_id_scope == "global" and after.object_id_scope == "per-robot"
    assert not set(after.robots[0].objects.ids.tolist()) & set(after.robots[1].objects.ids.tolist())
    assert after.object_identity.shape[0] > 0
    # the same seed gives the same dataset
    again = tmp_path / "again"
    assert main(["data", "strip-ids", str(data), "--out", str(again), "--seed", "3"]) == 0
    np.testing.assert_array_equal(load_dataset(again).object_identity, after.object_identity)
    # only global ids can be stripped
    assert main(["data", "strip-ids", str(stripped), "--out", str(tmp_path / "x")]) == 2
    assert "already 'per-robot'" in capsys.readouterr().err
    # oracle ids are refused on per-robot data, naming why
    assert main(["run", str(stripped), "--association", "oracle", "--window", "6"]) == 2
    assert "needs team-wide object ids" in capsys.readouterr().err
    # per-robot data run with own association by default, measured in metrics.json
    out = tmp_path / "run"
    assert main(["run", str(stripped), "--window", "6", "--out", str(out), "--no-report"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["config"]["association"]["mode"] == "own"
    team = metrics["association"]["team"]
    assert team["wrong"] == 0 and team["precision"] == 1.0
    assert set(metrics["association"]["links"]) == {"0-1", "0-2", "1-2"}
    assert team["held"] > 0
    # the MCAP draws a line between the two estimates of every matched pair
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from teamslam.ros2.mcap_export import export_mcap

    export_mcap(out, tmp_path / "run.mcap", path_messages=2)
    with (tmp_path / "run.mcap").open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        lines = [d for _, c, _, d in reader.iter_decoded_messages() if c.topic == "/association"]
    assert len(lines) == 1
    markers = lines[0].markers
    assert {m.ns for m in markers} <= {"link_0_1", "link_0_2", "link_1_2"}
    assert sum(len(m.points) for m in markers) == 2 * team["held"]


def test_simulate_with_per_robot_object_ids(tmp_path):
    out = tmp_path / "sim"
    args = ["simulate", "--robots", "2", "--steps", "10", "--object-ids", "per-robot"]
    assert main([*args, "--out", str(out)]) == 0
    dataset = load_dataset(out)
    assert dataset.object_id_scope == "per-robot"
    assert dataset.object_identity.shape[0] > 0


def test_import_reference_with_per_robot_object_ids(kitti00_dir, tmp_path):
    out = tmp_path / "k"
    assert (
        main(["data", "import-reference", str(kitti00_dir), str(out), "--object-ids", "per-robot"])
        == 0
    )
    dataset = load_dataset(out)
    assert dataset.object_id_scope == "per-robot"
    # 405 team objects stand for more per-robot ones; the identity maps them back
    assert np.unique(dataset.object_identity[:, 2]).size == 405
    assert dataset.object_identity.shape[0] > 405


def test_detections_without_ids_from_the_command_line(tmp_path):
    """``simulate --object-ids none --clutter --miss`` and ``strip-ids --to none`` give per-frame
    detections without ids: false ones among them (truth −1), none carrying an object id."""
    noisy = tmp_path / "noisy"
    args = ["simulate", "--robots", "2", "--steps", "25", "--seed", "2", "--out", str(noisy)]
    extra = ["--object-ids", "none", "--clutter", "0.2", "--miss", "0.1", "--classes", "3"]
    assert main(args + extra) == 0
    dataset = load_dataset(noisy)
    assert dataset.object_id_scope == "none"
    for robot in dataset.robots:
        assert robot.objects.ids.size == 0  # the filter sees no id
        truth = robot.detections.truth
        assert np.any(truth == -1) and np.any(truth >= 0)  # clutter and true detections
        assert set(np.unique(robot.detections.classes).tolist()) <= {0, 1, 2}
    clean, stripped = tmp_path / "clean", tmp_path / "stripped"
    assert main([*args[:-1], str(clean)]) == 0
    assert main(["data", "strip-ids", str(clean), "--out", str(stripped), "--to", "none"]) == 0
    before, after = load_dataset(clean), load_dataset(stripped)
    assert after.object_id_scope == "none"
    for b, a in zip(before.robots, after.robots, strict=True):
        assert a.objects.ids.size == 0
        # every observation became a detection whose truth is the object it came from
        assert np.array_equal(np.sort(a.detections.truth), np.sort(b.objects.ids))
    # clutter only on the Lissajous route
    assert main([*args[:-1], str(tmp_path / "x"), "--route", "long", "--clutter", "0.1"]) == 2


def test_a_run_on_detections_reports_its_tracking(tmp_path, capsys):
    """A run on detections without ids writes ``metrics.json["tracking"]`` (scored against the
    truth of each detection) and prints it in the run table."""
    data, out = tmp_path / "data", tmp_path / "run"
    args = ["simulate", "--robots", "2", "--steps", "30", "--seed", "5", "--out", str(data)]
    assert main([*args, "--object-ids", "none", "--clutter", "0.1", "--miss", "0.05"]) == 0
    assert main(["run", str(data), "--separate", "--out", str(out), "--no-report"]) == 0
    printed = capsys.readouterr().out
    assert "tracking IDF1 | MOTA" in printed
    tracking = json.loads((out / "metrics.json").read_text())["tracking"]
    team = tracking["team"]
    # the trackers' merges, judged by the truth, in metrics.json and in the table
    merges = team["merges"]
    assert merges["right"] + merges["wrong"] + merges["unjudged"] == merges["merges"]
    assert f"{merges['right']} | {merges['wrong']}" in printed.split("object merges right")[1]
    assert all(r["object_overconfidence"] >= 1.0 for r in tracking["robots"])
    dataset = load_dataset(data)
    truth = np.concatenate([r.detections.truth for r in dataset.robots])
    assert team["gt"] == int(np.sum(truth >= 0))  # every true detection is scored
    assert team["fp"] + team["idtp"] <= team["gt"] + np.sum(truth < 0)
    assert 0.0 < team["idf1"] <= 1.0 and team["false_objects"] == 0
    assert len(tracking["robots"]) == 2
