"""Object ids per robot: stripping global ids, the identity truth, and the format that keeps it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from teamslam.datasets import DatasetError, export_reference, import_reference
from teamslam.datasets.identity import strip_object_ids
from teamslam.datasets.storage import load_dataset, save_dataset
from teamslam.sim import lissajous_team


@pytest.fixture(scope="module")
def team():
    return lissajous_team(robots=3, steps=40, objects=30, seed=4, landmarks=300)


def test_stripped_robots_share_no_id_and_the_truth_maps_them_back(team):
    stripped = strip_object_ids(team, seed=1)
    assert stripped.object_id_scope == "per-robot"
    seen = [set(r.objects.ids.tolist()) for r in stripped.robots]
    for i in range(3):
        for j in range(i + 1, 3):
            assert not seen[i] & seen[j]
    original_shared = set(team.robots[0].objects.ids.tolist()) & set(
        team.robots[1].objects.ids.tolist()
    )
    assert original_shared  # the team does share objects
    for i, (before, after) in enumerate(zip(team.robots, stripped.robots, strict=True)):
        ids, team_ids = stripped.true_objects(i)
        back = dict(zip(ids.tolist(), team_ids.tolist(), strict=True))
        # every observation, renumbered back, is the original one (same frame, same pixels)
        assert [back[int(v)] for v in after.objects.ids] == before.objects.ids.tolist()
        assert np.array_equal(after.objects.offsets, before.objects.offsets)
        assert np.array_equal(after.objects.measurements, before.objects.measurements)
        # the other robots' data are untouched
        assert np.array_equal(after.features.ids, before.features.ids)
        assert np.array_equal(after.odometry, before.odometry)
    # truth by the new ids: equal positions mean the same object
    ids0, true0 = stripped.true_objects(0)
    assert np.array_equal(stripped.object_position(ids0), team.object_position(true0))
    # the same seed gives the same dataset, another seed other ids
    again = strip_object_ids(team, seed=1)
    assert np.array_equal(again.object_identity, stripped.object_identity)
    other = strip_object_ids(team, seed=2)
    assert not np.array_equal(other.object_identity[:, 1], stripped.object_identity[:, 1])


def test_per_robot_identity_round_trips_through_the_format(team, tmp_path):
    stripped = strip_object_ids(team, seed=0)
    save_dataset(stripped, tmp_path / "team")
    manifest = json.loads((tmp_path / "team" / "manifest.json").read_text())
    assert manifest["version"] == 3 and manifest["object_ids"] == "per-robot"
    back = load_dataset(tmp_path / "team")
    assert back.object_id_scope == "per-robot"
    assert np.array_equal(back.object_identity, stripped.object_identity)
    assert np.array_equal(back.object_ids, stripped.object_ids)
    for a, b in zip(back.robots, stripped.robots, strict=True):
        assert np.array_equal(a.objects.ids, b.objects.ids)


def test_global_ids_stay_the_default(team, tmp_path):
    save_dataset(team, tmp_path / "team")
    manifest_path = tmp_path / "team" / "manifest.json"
    manifest = json.loads(manifest_path.read_text())
    assert manifest["object_ids"] == "global"
    # a file of an older version says nothing: its ids are global
    del manifest["object_ids"]
    manifest["version"] = 2
    manifest_path.write_text(json.dumps(manifest))
    back = load_dataset(tmp_path / "team")
    assert back.object_id_scope == "global" and back.object_identity.shape == (0, 3)
    ids, team_ids = back.true_objects(1)
    assert np.array_equal(ids, team_ids)
    assert np.array_equal(ids, np.unique(team.robots[1].objects.ids))


def test_malformed_identity_is_refused_naming_what_is_wrong(team, tmp_path):
    stripped = strip_object_ids(team, seed=0)
    save_dataset(stripped, tmp_path / "team")
    manifest_path = tmp_path / "team" / "manifest.json"
    manifest = json.loads(manifest_path.read_text())
    manifest_path.write_text(json.dumps(dict(manifest, object_ids="by-colour")))
    with pytest.raises(DatasetError, match="object_ids must be one of global, per-robot"):
        load_dataset(tmp_path / "team")
    manifest_path.write_text(json.dumps(manifest))
    map_path = tmp_path / "team" / "map.npz"
    with np.load(map_path) as npz:
        arrays = dict(npz)
    bad = dict(arrays, object_identity=arrays["object_identity"][:, :2])
    np.savez_compressed(map_path, **bad)
    with pytest.raises(DatasetError, match=r"map.npz: field 'object_identity' must be \(K, 3\)"):
        load_dataset(tmp_path / "team")
    robot9 = arrays["object_identity"].copy()
    robot9[0, 0] = 9
    np.savez_compressed(map_path, **dict(arrays, object_identity=robot9))
    with pytest.raises(DatasetError, match="object_identity names robot 9"):
        load_dataset(tmp_path / "team")
    twice = arrays["object_identity"].copy()
    twice[1, :2] = twice[0, :2]
    np.savez_compressed(map_path, **dict(arrays, object_identity=twice))
    with pytest.raises(DatasetError, match="names one robot's object twice"):
        load_dataset(tmp_path / "team")
    np.savez_compressed(map_path, **dict(arrays, object_identity=arrays["object_identity"] * 1.0))
    with pytest.raises(DatasetError, match="'object_identity' has dtype float64"):
        load_dataset(tmp_path / "team")


def test_identity_only_for_per_robot_ids_and_strip_only_from_global(team):
    stripped = strip_object_ids(team)
    with pytest.raises(DatasetError, match="these ids are global"):
        type(team)(**{**vars(team), "object_identity": stripped.object_identity})
    with pytest.raises(DatasetError, match="already 'per-robot'"):
        strip_object_ids(stripped)
    with pytest.raises(DatasetError, match="only renumber to 'per-robot'"):
        strip_object_ids(team, to="global")


def test_subset_renumbers_the_robots_of_the_identity(team):
    stripped = strip_object_ids(team, seed=0)
    two = stripped.subset([2, 0])
    assert set(two.object_identity[:, 0].tolist()) == {0, 1}
    assert np.array_equal(two.true_objects(0)[0], stripped.true_objects(2)[0])
    assert np.array_equal(two.true_objects(1)[1], stripped.true_objects(0)[1])


def test_class_labels_are_renumbered_and_saved(team, tmp_path):
    from dataclasses import replace

    robots = []
    for r in team.robots:
        ids = np.unique(r.objects.ids)
        robots.append(replace(r, object_classes=np.column_stack([ids, ids % 3])))
    labelled = replace(team, robots=robots)
    stripped = strip_object_ids(labelled, seed=0)
    for i, r in enumerate(stripped.robots):
        ids, team_ids = stripped.true_objects(i)
        label = dict(r.object_classes.tolist())
        assert all(label[int(a)] == int(b) % 3 for a, b in zip(ids, team_ids, strict=True))
    save_dataset(stripped, tmp_path / "team")
    back = load_dataset(tmp_path / "team")
    assert np.array_equal(back.robots[1].object_classes, stripped.robots[1].object_classes)


def test_import_reference_can_give_per_robot_ids(team, tmp_path):
    export_reference(team, tmp_path / "published")
    global_ids = import_reference(tmp_path / "published")
    assert global_ids.object_id_scope == "global"
    per_robot = import_reference(tmp_path / "published", object_ids="per-robot", seed=3)
    assert per_robot.object_id_scope == "per-robot"
    assert np.array_equal(
        per_robot.object_identity, strip_object_ids(global_ids, seed=3).object_identity
    )
    with pytest.raises(DatasetError, match="object_ids must be one of"):
        import_reference(tmp_path / "published", object_ids="mine")
