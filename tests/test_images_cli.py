"""The image commands end to end: ``simulate --images`` renders a small team, ``data
from-images`` (one command for the whole team, or robot by robot) and ``data import-bag
--images`` give the same dataset, front-end settings are set and shown with their source, and
without OpenCV the commands name the extra to install and exit 2."""

from __future__ import annotations

import builtins
import sys

import numpy as np
import pytest

pytest.importorskip("cv2", reason="the images extra (OpenCV) is not installed")

from teamslam.cli import main
from teamslam.datasets import load_dataset


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "team"
    args = ["simulate", "--images", "--robots", "2", "--steps", "5", "--image-width", "320"]
    assert main([*args, "--seed", "3", "--out", str(out), "--quiet"]) == 0
    return out


def _same(a, b) -> None:
    assert a.n_robots == b.n_robots
    for ra, rb in zip(a.robots, b.robots, strict=True):
        np.testing.assert_array_equal(ra.features.ids, rb.features.ids)
        np.testing.assert_array_equal(ra.features.measurements, rb.features.measurements)
        np.testing.assert_array_equal(ra.objects.ids, rb.objects.ids)
        np.testing.assert_array_equal(ra.objects.measurements, rb.objects.measurements)
        np.testing.assert_allclose(ra.T_world_body, rb.T_world_body, atol=1e-9)
        np.testing.assert_allclose(ra.odometry, rb.odometry, atol=1e-9)


def test_simulate_images_writes_folders_truth_and_a_bag(rendered):
    for k in range(2):
        robot = rendered / f"robot_{k}"
        assert len(list((robot / "left").glob("*.png"))) == 6
        assert len(list((robot / "right").glob("*.png"))) == 6
        for name in ("camera.yaml", "timestamps.txt", "odometry.tum", "groundtruth.tum"):
            assert (robot / name).is_file()
    assert (rendered / "images.mcap").stat().st_size > 0
    assert len((rendered / "markers.txt").read_text().splitlines()) > 1


def test_from_images_one_command_for_the_team_and_the_bag_path_agree(rendered, tmp_path, capsys):
    assert (
        main(
            [
                "data",
                "from-images",
                "--rendered",
                str(rendered),
                "--out",
                str(tmp_path / "a"),
                "--quiet",
            ]
        )
        == 0
    )
    team = load_dataset(tmp_path / "a")
    assert team.n_robots == 2
    assert all(r.frames == 6 for r in team.robots)
    assert min(r.features.counts().min() for r in team.robots) >= 50
    assert team.object_ids.size > 0
    # the same team, every folder and file given explicitly in team order
    folders, files = [], []
    for k in range(2):
        r = rendered / f"robot_{k}"
        folders += [str(r / "left"), str(r / "right")]
        files += [
            "--timestamps",
            str(r / "timestamps.txt"),
            "--odometry",
            str(r / "odometry.tum"),
            "--ground-truth",
            str(r / "groundtruth.tum"),
            "--robot",
            f"robot_{k}",
        ]
    camera = str(rendered / "robot_0" / "camera.yaml")
    assert (
        main(
            [
                "data",
                "from-images",
                *folders,
                "--camera",
                camera,
                *files,
                "--markers",
                str(rendered / "markers.txt"),
                "--out",
                str(tmp_path / "b"),
                "--quiet",
            ]
        )
        == 0
    )
    _same(team, load_dataset(tmp_path / "b"))
    # the bag through import-bag --images, the rig from camera_info
    assert (
        main(
            [
                "data",
                "import-bag",
                str(rendered / "images.mcap"),
                "--images",
                "/{name}/left/image_raw,/{name}/right/image_raw",
                "--camera-info",
                "/{name}/left/camera_info,/{name}/right/camera_info",
                "--robot",
                "robot_0:/robot_0/odom:/robot_0/ground_truth",
                "--robot",
                "robot_1:/robot_1/odom:/robot_1/ground_truth",
                "--markers",
                str(rendered / "markers.txt"),
                "--out",
                str(tmp_path / "c"),
                "--quiet",
            ]
        )
        == 0
    )
    from_bag = load_dataset(tmp_path / "c")
    _same(team, from_bag)
    assert from_bag.metadata["images"]["robots"][0]["odometry"] == "topic /robot_0/odom"


def test_frontend_settings_are_applied_and_shown_with_their_source(rendered, tmp_path, capsys):
    out = tmp_path / "few"
    assert (
        main(
            [
                "data",
                "from-images",
                "--rendered",
                str(rendered),
                "--out",
                str(out),
                "--quiet",
                "--frontend-set",
                "max_features=40",
                "--frontend-set",
                "frontend.ncc_min=0.8",
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    rows = {line.split()[0]: line.split()[1:] for line in text.splitlines() if line.strip()}
    assert rows["max_features"] == ["40", "--frontend-set"]
    assert rows["ncc_min"] == ["0.8", "--frontend-set"]
    assert rows["lk_levels"] == ["2", "default"]
    dataset = load_dataset(out)
    assert max(r.features.counts().max() for r in dataset.robots) <= 40
    assert dataset.metadata["images"]["frontend"]["max_features"] == 40
    command = ["data", "from-images", "--rendered", str(rendered), "--out", str(out)]
    for setting, named in (
        ("max_features=many", "max_features"),
        ("no_such=1", "unknown front-end setting 'no_such'"),
    ):
        assert main([*command, "--frontend-set", setting]) == 2
        assert named in capsys.readouterr().err


def test_bad_inputs_name_what_is_wrong(rendered, tmp_path, capsys):
    left = rendered / "robot_0" / "left"
    camera = rendered / "robot_0" / "camera.yaml"
    assert (
        main(
            [
                "data",
                "from-images",
                str(left),
                "--camera",
                str(camera),
                "--out",
                str(tmp_path / "x"),
            ]
        )
        == 2
    )
    assert "LEFT_DIR RIGHT_DIR per robot" in capsys.readouterr().err
    # a bad image names its file
    bad = tmp_path / "bad"
    (bad / "left").mkdir(parents=True)
    (bad / "right").mkdir()
    for name in ("000000.png", "000001.png"):
        for side in ("left", "right"):
            (bad / side / name).write_bytes((left / name).read_bytes())
    (bad / "right" / "000001.png").write_bytes(b"not an image")
    assert (
        main(
            [
                "data",
                "from-images",
                str(bad / "left"),
                str(bad / "right"),
                "--camera",
                str(camera),
                "--out",
                str(tmp_path / "y"),
                "--quiet",
            ]
        )
        == 2
    )
    assert "right/000001.png: cannot read the image" in capsys.readouterr().err
    assert (
        main(
            [
                "data",
                "import-bag",
                str(rendered / "images.mcap"),
                "--robot",
                "a:b",
                "--out",
                str(tmp_path / "z"),
            ]
        )
        == 2
    )
    assert "--observations and --camera needed" in capsys.readouterr().err


def test_without_opencv_the_commands_name_the_extra(rendered, tmp_path, monkeypatch, capsys):
    real_import = builtins.__import__

    def no_cv2(name, *args, **kwargs):
        if name == "cv2":
            raise ModuleNotFoundError("No module named 'cv2'", name="cv2")
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, "cv2")
    monkeypatch.setattr(builtins, "__import__", no_cv2)
    commands = [
        ["simulate", "--images", "--robots", "1", "--steps", "1", "--out", str(tmp_path / "s")],
        ["data", "from-images", "--rendered", str(rendered), "--out", str(tmp_path / "d")],
        [
            "data",
            "import-bag",
            str(rendered / "images.mcap"),
            "--images",
            "/a,/b",
            "--camera",
            str(rendered / "robot_0" / "camera.yaml"),
            "--robot",
            "r",
            "--out",
            str(tmp_path / "b"),
        ],
    ]
    for argv in commands:
        assert main(argv) == 2
        assert "needs the 'images' extra: pip install 'teamslam[images]'" in capsys.readouterr().err
    assert not (tmp_path / "s" / "robot_0" / "left").exists()
