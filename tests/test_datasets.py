"""Team datasets: own format, safe importer of the published data, trajectory files."""

from __future__ import annotations

import ast
import json
import pickle
import shutil
import threading

import numpy as np
import pytest

from teamslam.datasets import (
    DatasetError,
    FrameObservations,
    UnsafePickleError,
    dataset_info,
    import_reference,
    load_dataset,
    read_kitti,
    read_tum,
    safe_unpickle,
    save_dataset,
    write_kitti,
    write_tum,
)
from teamslam.geometry import se3
from teamslam.sim import lissajous_team


@pytest.fixture(scope="module")
def small_team():
    return lissajous_team(robots=3, steps=40, objects=30, seed=4, landmarks=300)


def test_threads_loading_datasets_at_once_parse_no_two_array_headers_together(
    small_team, tmp_path, monkeypatch
):
    """numpy parses each array's header with ``ast``, whose depth counter threads share.

    The first header parse waits (bounded) for a second thread to parse too: it cannot while
    the first holds the archive, so no two parses overlap and both threads load the dataset.
    """
    save_dataset(small_team, tmp_path / "d")
    parse, guard, first = ast.parse, threading.Lock(), threading.Lock()
    waiting, second, active, overlaps = threading.Event(), threading.Event(), [0], []

    def watched(*args, **kwargs):
        with guard:
            active[0] += 1
            overlaps.append(active[0] > 1)
        try:
            if first.acquire(blocking=False):
                waiting.set()
                second.wait(timeout=1.0)
            else:
                second.set()
            return parse(*args, **kwargs)
        finally:
            with guard:
                active[0] -= 1

    monkeypatch.setattr(ast, "parse", watched)
    loaded = []
    threads = [threading.Thread(target=lambda: loaded.append(load_dataset(tmp_path / "d")))]
    threads[0].start()
    assert waiting.wait(timeout=60)
    threads.append(threading.Thread(target=lambda: loaded.append(load_dataset(tmp_path / "d"))))
    threads[1].start()
    for t in threads:
        t.join(timeout=60)
    assert len(loaded) == 2 and second.is_set()
    assert len(overlaps) > 2 and not any(overlaps)
    _assert_same(*loaded)


def _assert_same(a, b):
    assert a.name == b.name
    np.testing.assert_array_equal(a.calibration.camera.intrinsics, b.calibration.camera.intrinsics)
    np.testing.assert_array_equal(
        a.calibration.camera.T_left_right, b.calibration.camera.T_left_right
    )
    np.testing.assert_array_equal(a.calibration.T_cam_body, b.calibration.T_cam_body)
    assert a.calibration.image_size == b.calibration.image_size
    for ra, rb in zip(a.robots, b.robots, strict=True):
        for field in ("T_world_body", "odometry", "timestamps"):
            np.testing.assert_array_equal(getattr(ra, field), getattr(rb, field))
        for obs in ("features", "objects"):
            for arr in ("offsets", "ids", "measurements"):
                x, y = getattr(getattr(ra, obs), arr), getattr(getattr(rb, obs), arr)
                assert x.dtype == y.dtype
                np.testing.assert_array_equal(x, y)
    for field in (
        "object_ids",
        "object_positions",
        "landmark_ids",
        "landmark_positions",
        "track_landmarks",
    ):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert a.metadata == b.metadata


def test_round_trip_is_bit_exact(tmp_path, small_team):
    save_dataset(small_team, tmp_path / "team")
    loaded = load_dataset(tmp_path / "team")
    _assert_same(small_team, loaded)
    # saving again over it replaces it atomically
    save_dataset(loaded, tmp_path / "team")
    _assert_same(small_team, load_dataset(tmp_path / "team"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["team"]


def test_frame_observations_round_trip_dicts():
    frames = [{3: [1, 2, 3, 4]}, {}, {7: [5, 6, 7, 8], 3: [0, 0, 0, 0]}]
    obs = FrameObservations.from_frames(frames)
    assert obs.frames == 3
    np.testing.assert_array_equal(obs.counts(), [1, 0, 2])
    back = obs.to_dicts()
    assert set(back[2]) == {7, 3}
    np.testing.assert_array_equal(back[2][7], [5, 6, 7, 8])
    with pytest.raises(DatasetError, match="twice"):
        FrameObservations.from_frames([{1: [0, 0, 0, 0]}, ([2, 2], np.zeros((2, 4)))])
    with pytest.raises(DatasetError, match="monotone"):
        FrameObservations(np.array([0, 2, 1, 2]), np.arange(2), np.zeros((2, 4)))
    with pytest.raises(DatasetError, match="non-finite measurement in frame 1"):
        FrameObservations.from_frames([{1: [0, 0, 0, 0]}, {2: [0, np.nan, 0, 0]}])


def _saved(tmp_path, team):
    path = tmp_path / "ds"
    save_dataset(team, path)
    return path


def test_truncated_npz_is_named(tmp_path, small_team):
    path = _saved(tmp_path, small_team)
    f = path / "robot_001.npz"
    f.write_bytes(f.read_bytes()[:200])
    with pytest.raises(DatasetError, match=r"robot_001\.npz.*cannot read"):
        load_dataset(path)


def test_nan_pose_is_named(tmp_path, small_team):
    path = _saved(tmp_path, small_team)
    with np.load(path / "robot_000.npz") as npz:
        arrays = dict(npz)
    arrays["T_world_body"][5, 0, 3] = np.nan
    np.savez_compressed(path / "robot_000.npz", **arrays)
    with pytest.raises(DatasetError, match=r"robot_000\.npz.*T_world_body.*frame 5"):
        load_dataset(path)


def test_unknown_version_and_bad_fields(tmp_path, small_team):
    path = _saved(tmp_path, small_team)
    manifest = json.loads((path / "manifest.json").read_text())
    manifest["version"] = 99
    (path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetError, match="unsupported format version 99"):
        load_dataset(path)
    manifest["version"] = 1
    manifest["robots"][0]["frames"] = 5
    (path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetError, match="manifest says 5 frames"):
        load_dataset(path)
    manifest["robots"][0]["frames"] = small_team.robots[0].frames
    manifest["robots"][0]["file"] = "../outside.npz"
    (path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetError, match="not a plain file name"):
        load_dataset(path)


def test_wrong_dtype_and_mismatched_frames(tmp_path, small_team):
    path = _saved(tmp_path, small_team)
    with np.load(path / "robot_002.npz") as npz:
        arrays = dict(npz)
    good = dict(arrays)
    arrays["object_ids"] = arrays["object_ids"].astype(float)
    np.savez_compressed(path / "robot_002.npz", **arrays)
    with pytest.raises(DatasetError, match=r"object_ids.*dtype"):
        load_dataset(path)
    # one frame of feature observations short of the number of poses
    end = good["feature_offsets"][-2]
    good["feature_offsets"] = good["feature_offsets"][:-1]
    good["feature_ids"] = good["feature_ids"][:end]
    good["feature_measurements"] = good["feature_measurements"][:end]
    np.savez_compressed(path / "robot_002.npz", **good)
    with pytest.raises(DatasetError, match=r"robot_002\.npz.*features: 40 frames .* 41 poses"):
        load_dataset(path)


def test_trajectory_files_round_trip(tmp_path):
    poses = se3.exp(np.random.default_rng(0).normal(size=(25, 6)))
    stamps = np.linspace(0.0, 2.4, 25)
    write_tum(tmp_path / "t.txt", poses, stamps)
    ts, back = read_tum(tmp_path / "t.txt")
    np.testing.assert_array_equal(ts, stamps)
    np.testing.assert_allclose(back, poses, atol=1e-15)
    write_kitti(tmp_path / "k.txt", poses)
    np.testing.assert_array_equal(read_kitti(tmp_path / "k.txt"), poses)
    first = (tmp_path / "t.txt").read_text().splitlines()[0].split()
    assert len(first) == 8
    (tmp_path / "bad.txt").write_text("1 2 3\n")
    with pytest.raises(DatasetError, match="12 numbers"):
        read_kitti(tmp_path / "bad.txt")


# ------------------------------------------------------------- published data
# a hand-crafted pickle that calls os.system("echo pwned") when loaded by a plain unpickler
EVIL_PICKLE = b"cos\nsystem\n(S'echo pwned'\ntR."


def test_pickle_calling_a_function_is_refused(tmp_path, monkeypatch):
    called = []
    import os

    monkeypatch.setattr(os, "system", lambda *a: called.append(a) or 0)
    path = tmp_path / "evil"
    path.write_bytes(EVIL_PICKLE)
    with pytest.raises(UnsafePickleError, match=r"os\.system"):
        safe_unpickle(path)
    assert called == []
    # the same bytes do call the function through a plain unpickler: the test can fail
    pickle.loads(EVIL_PICKLE)
    assert called == [("echo pwned",)]
    path.write_bytes(pickle.dumps([np.arange(3), {np.uint32(4): np.zeros(4)}]))
    ok = safe_unpickle(path)
    np.testing.assert_array_equal(ok[0], np.arange(3))
    path.write_bytes(b"\x80\x04garbage")
    with pytest.raises(DatasetError, match="not a readable pickle"):
        safe_unpickle(path)


def test_evil_calib_in_a_reference_directory_is_refused(tmp_path, kitti00_dir, monkeypatch):
    called = []
    import os

    monkeypatch.setattr(os, "system", lambda *a: called.append(a) or 0)
    src = tmp_path / "src"
    shutil.copytree(kitti00_dir, src)
    (src / "calib").chmod(0o644)
    (src / "calib").write_bytes(EVIL_PICKLE)
    with pytest.raises(UnsafePickleError):
        import_reference(src)
    assert called == []


def test_import_kitti00(kitti00_dir, tmp_path):
    ds = import_reference(kitti00_dir)
    info = dataset_info(ds)
    assert info["robots"] == 3
    assert info["frames_per_robot"] == [2001, 2001, 2041]
    assert info["objects_observed"] == 405
    assert info["objects_shared"] == 261
    assert info["object_observations_per_frame"]["total"] == 18396
    assert ds.calibration.camera.intrinsics[0, 0] == pytest.approx(718.856)
    assert ds.calibration.camera.fx_baseline == pytest.approx(382.67, abs=0.01)
    assert info["geometric_tracks"] == 0  # no geometric-feature file for this sequence
    np.testing.assert_allclose(ds.robots[0].T_world_body[0], np.eye(4), atol=1e-7)
    for robot in ds.robots:
        true_rel = se3.inverse(robot.T_world_body[:-1]) @ robot.T_world_body[1:]
        err = np.linalg.norm(true_rel[:, :3, 3] - robot.odometry[:, :3, 3], axis=1)
        assert err.mean() < 0.03  # a few centimetres per step on average
        rot = np.linalg.norm(se3.log(se3.inverse(true_rel) @ robot.odometry)[:, 3:], axis=1)
        assert rot.mean() < 0.01
    # writes our format and reads back the same
    save_dataset(ds, tmp_path / "k")
    _assert_same(ds, load_dataset(tmp_path / "k"))
    # the inverted-odometry option inverts each step
    inv = import_reference(kitti00_dir, inverted_odometry=True)
    np.testing.assert_allclose(inv.robots[1].odometry[7], se3.inverse(ds.robots[1].odometry[7]))
