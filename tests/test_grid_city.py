"""The grid city simulator: streets, regularly spaced kerb objects, cars sharing objects."""

from __future__ import annotations

import json

import numpy as np
import pytest

from teamslam.cli import main
from teamslam.datasets import load_dataset
from teamslam.errors import InputError
from teamslam.sim import grid_city_team

BLOCK, WIDTH, SPACING = 60.0, 12.0, 8.0


@pytest.fixture(scope="module")
def city():
    return grid_city_team(robots=4, steps=300, seed=3)


def _seen(robot) -> set[int]:
    return set(np.concatenate([robot.objects.frame(k)[0] for k in range(robot.frames)]).tolist())


def test_the_same_seed_gives_the_same_city_and_another_seed_other_routes(city):
    again = grid_city_team(robots=4, steps=300, seed=3)
    np.testing.assert_array_equal(city.object_positions, again.object_positions)
    np.testing.assert_array_equal(city.landmark_positions, again.landmark_positions)
    for one, two in zip(city.robots, again.robots, strict=True):
        np.testing.assert_array_equal(one.T_world_body, two.T_world_body)
        np.testing.assert_array_equal(one.odometry, two.odometry)
        np.testing.assert_array_equal(one.objects.measurements, two.objects.measurements)
    other = grid_city_team(robots=4, steps=300, seed=4)
    assert not np.allclose(other.robots[0].T_world_body, city.robots[0].T_world_body)


def test_objects_stand_along_the_kerbs_one_spacing_apart(city):
    p = city.object_positions
    # every object is about half a street width from the centreline of its street
    offset = np.abs((p[:, :2] + BLOCK / 2) % BLOCK - BLOCK / 2)  # distance to the nearest line
    kerb = np.min(np.abs(offset - WIDTH / 2), axis=1)
    assert np.all(kerb < 1.0)
    # a neighbour one spacing away along the kerb, give or take the jitter
    gaps = np.sort(np.linalg.norm(p[:, None, :2] - p[None, :, :2], axis=2), axis=1)[:, 1]
    assert abs(np.median(gaps) - SPACING) < 0.5
    assert np.percentile(gaps, 90) < SPACING + 1.5
    assert np.std(p[:, 2]) < 0.3  # one height, a little jitter: nothing tells them apart
    assert city.metadata["simulation"]["objects"] == len(p)


def test_cars_drive_the_streets_and_turn_at_intersections(city):
    for robot in city.robots:
        xy = robot.T_world_body[:, :2, 3]
        # within the street: never further from a centreline than the kerb
        offset = np.abs((xy + BLOCK / 2) % BLOCK - BLOCK / 2)
        assert np.all(offset.min(axis=1) < WIDTH / 2)
        heading = robot.T_world_body[:, :2, 0]
        assert np.allclose(np.linalg.norm(heading, axis=1), 1.0)
        step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        assert np.allclose(step, 1.0, atol=0.05)
        # along a street the car heads along an axis; it turns somewhere on a 300 m drive
        axis = np.abs(heading).max(axis=1) > 0.999
        assert axis.mean() > 0.6
        directions = {tuple(np.round(h).astype(int)) for h in heading[axis]}
        assert len(directions) >= 2


def test_cars_share_objects(city):
    seen = [_seen(r) for r in city.robots]
    shared = [len(seen[i] & seen[j]) for i in range(4) for j in range(i + 1, 4)]
    assert max(shared) > 20
    assert sum(s > 0 for s in shared) >= 3


def test_the_camera_is_a_pixel_camera_of_700_px(city):
    assert city.calibration.camera.intrinsics[0, 0] == 700.0
    assert city.calibration.image_size == (1241, 376)
    # every frame sees objects and features
    for robot in city.robots:
        assert min(len(robot.features.frame(k)[0]) for k in range(robot.frames)) > 10


@pytest.mark.parametrize(
    ("setting", "match"),
    [
        ({"blocks": (0, 3)}, "blocks"),
        ({"blocks": (2,)}, "blocks"),
        ({"object_spacing": 0.0}, "object_spacing"),
        ({"block_size": float("nan")}, "block_size"),
        ({"street_width": 70.0}, "street_width"),
        ({"lane": 7.0}, "lane"),
        ({"turn_radius": 1.0}, "turn_radius"),
        ({"object_jitter": (0.1, -1.0, 0.0)}, "object_jitter"),
        ({"objects": 10}, "objects"),
        ({"miss": 1.5}, "miss"),
    ],
)
def test_bad_settings_are_refused_naming_them(setting, match):
    with pytest.raises(InputError, match=match):
        grid_city_team(robots=2, steps=10, **setting)


def test_simulate_a_grid_city_from_the_command_line(tmp_path, capsys):
    out = tmp_path / "grid"
    argv = ["simulate", "--route", "grid", "--steps", "60", "--object-ids", "per-robot"]
    assert main([*argv, "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["data", "info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["frames_per_robot"] == [61] * 4  # four cars by default
    team = load_dataset(out)
    assert team.object_id_scope == "per-robot"
    expected = grid_city_team(robots=4, steps=60)
    for one, two in zip(team.robots, expected.robots, strict=True):
        np.testing.assert_allclose(one.T_world_body, two.T_world_body, atol=1e-9)
    for bad, word in (
        (["--objects", "5"], "--objects"),
        (["--object-spacing", "0"], "object_spacing"),
    ):
        assert main([*argv, *bad, "--out", str(tmp_path / "x")]) == 2
        err = capsys.readouterr().err.strip()
        assert word in err and "Traceback" not in err and len(err.splitlines()) == 1
    with pytest.raises(SystemExit) as exit_:  # refused by the parser
        main([*argv, "--blocks", "0", "2", "--out", str(tmp_path / "x")])
    assert exit_.value.code == 2
    assert "--blocks" in capsys.readouterr().err
    # the grid's settings are refused on the other routes
    assert main(["simulate", "--blocks", "2", "2", "--out", str(tmp_path / "y")]) == 2
    assert "--route grid" in capsys.readouterr().err
