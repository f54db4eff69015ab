"""Live inputs without a network: stamp pairing (ApproximateTimeSync) and the decoders of the
messages a live robot receives (images, camera infos, odometry)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip("rosbags", reason="the ros2 extra is not installed")

from teamslam.errors import InputError
from teamslam.ros2 import messages as m
from teamslam.ros2.live import (
    ApproximateTimeSync,
    Received,
    check_topic_name,
    image_array,
    odometry_pose,
    stereo_rig,
)

L, R, ODOM = "/r/left/image_raw", "/r/right/image_raw", "/r/odom"


def _item(topic: str, stamp: int) -> Received:
    return Received(topic, "sensor_msgs/msg/Image", stamp, None, 0)


def _stamps(sets):
    return [{t: s[t].stamp_ns for t in s} for s in sets]


def test_exact_stamps_pair_in_order():
    sync = ApproximateTimeSync([L, R], tolerance_ns=0)
    assert sync.add(_item(L, 100)) == []
    assert _stamps(sync.add(_item(R, 100))) == [{L: 100, R: 100}]
    assert sync.add(_item(R, 200)) == []
    assert _stamps(sync.add(_item(L, 200))) == [{L: 200, R: 200}]
    assert sync.dropped == {L: 0, R: 0}
    assert sync.pending() == {L: 0, R: 0}


def test_jitter_within_tolerance_pairs_and_beyond_it_does_not():
    sync = ApproximateTimeSync([L, R, ODOM], tolerance_ns=5)
    sync.add(_item(L, 1000))
    sync.add(_item(ODOM, 1003))
    (got,) = sync.add(_item(R, 1005))  # spread 5 = tolerance
    assert {t: x.stamp_ns for t, x in got.items()} == {L: 1000, R: 1005, ODOM: 1003}
    assert list(got) == [L, R, ODOM], "a set is keyed in the synchroniser's topic order"
    sync.add(_item(L, 2000))
    sync.add(_item(ODOM, 2000))
    assert sync.add(_item(R, 2006)) == []  # spread 6: the two at 2000 cannot pair any more
    assert sync.dropped == {L: 1, R: 0, ODOM: 1}
    assert sync.pending() == {L: 0, R: 1, ODOM: 0}


def test_a_missing_right_image_drops_its_left_once_a_later_right_arrives():
    sync = ApproximateTimeSync([L, R], tolerance_ns=10)
    out = []
    for k in range(5):
        out += sync.add(_item(L, 100 * k))
        if k != 2:  # right image 2 lost
            out += sync.add(_item(R, 100 * k))
    assert [s[L].stamp_ns for s in out] == [0, 100, 300, 400]
    assert all(s[L].stamp_ns == s[R].stamp_ns for s in out)
    assert sync.dropped == {L: 1, R: 0}


def test_a_topic_that_stops_leaves_a_bounded_queue():
    sync = ApproximateTimeSync([L, R], tolerance_ns=0, queue_size=3)
    for k in range(10):
        assert sync.add(_item(L, k)) == []
    assert sync.pending() == {L: 3, R: 0}
    assert sync.dropped == {L: 7, R: 0}
    # the right topic returns: the queued lefts it matches pair, the older are dropped
    assert _stamps(sync.add(_item(R, 8))) == [{L: 8, R: 8}]
    assert sync.dropped == {L: 8, R: 0}
    assert sync.pending() == {L: 1, R: 0}


def test_a_stamp_going_back_or_repeated_is_dropped():
    sync = ApproximateTimeSync([L, R], tolerance_ns=0)
    sync.add(_item(L, 500))
    assert sync.add(_item(L, 400)) == []
    assert sync.add(_item(L, 500)) == []
    assert sync.dropped == {L: 2, R: 0}
    assert _stamps(sync.add(_item(R, 500))) == [{L: 500, R: 500}]


def test_several_sets_completed_by_one_message_come_oldest_first():
    sync = ApproximateTimeSync([L, R], tolerance_ns=0, queue_size=5)
    for s in (1, 2, 3):
        sync.add(_item(L, s))
    assert sync.add(_item(R, 3)) != []
    assert sync.dropped[L] == 2  # 1 and 2 had no right partner before 3
    sync2 = ApproximateTimeSync([L, R], tolerance_ns=10, queue_size=5)
    for s in (10, 30):
        sync2.add(_item(L, s))
    sync2.add(_item(R, 12))
    assert _stamps(sync2.add(_item(R, 31))) == [{L: 30, R: 31}]


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (([L, L], 0), "distinct"),
        (([], 0), "distinct"),
        (([L, R], -1), "tolerance"),
        (([L, R], 0.5), "tolerance"),
        (([L, R], 0, 0), "queue size"),
    ],
)
def test_sync_settings_are_checked(args, match):
    with pytest.raises(InputError, match=match):
        ApproximateTimeSync(*args)
    with pytest.raises(InputError, match="not a topic"):
        ApproximateTimeSync([L, R], 0).add(_item(ODOM, 1))


def test_topic_names():
    assert check_topic_name("/robot_0/left/image_raw") == "/robot_0/left/image_raw"
    for bad in ("robot_0/left", "/a//b", "/a/*", "/0a", "/a/", "/a b", "/a/$b", "/a__b"):
        with pytest.raises(InputError, match="topic"):
            check_topic_name(bad)


# ------------------------------------------------------------------------------ decoders
def _image(encoding: str, pixels: np.ndarray, stamp: int = 7, step: int | None = None):
    t = m.typestore().types
    h, w = pixels.shape[:2]
    data = np.ascontiguousarray(pixels).view(np.uint8).reshape(h, -1)
    step = data.shape[1] if step is None else step
    rows = np.zeros((h, step), np.uint8)
    rows[:, : data.shape[1]] = data
    return t["sensor_msgs/msg/Image"](
        header=m.header(stamp, "cam"),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=step,
        data=rows.ravel(),
    )


def test_image_array_of_each_encoding():
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(4)
    grey = rng.integers(0, 256, (6, 9), dtype=np.uint8)
    np.testing.assert_array_equal(image_array(_image("mono8", grey)), grey)
    np.testing.assert_array_equal(image_array(_image("mono8", grey, step=12)), grey)
    bgr = rng.integers(0, 256, (6, 9, 3), dtype=np.uint8)
    np.testing.assert_array_equal(
        image_array(_image("bgr8", bgr)), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    )
    np.testing.assert_array_equal(
        image_array(_image("rgb8", bgr[..., ::-1])), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    )
    wide = grey.astype("<u2") * 257
    np.testing.assert_array_equal(image_array(_image("mono16", wide)), grey)
    ok, png = cv2.imencode(".png", grey)
    assert ok
    compressed = m.typestore().types["sensor_msgs/msg/CompressedImage"](
        header=m.header(9, "cam"), format="png", data=png.ravel()
    )
    np.testing.assert_array_equal(image_array(compressed, size=(9, 6)), grey)
    item = Received("/r/left", "sensor_msgs/msg/Image", 7, _image("mono8", grey), 0)
    np.testing.assert_array_equal(image_array(item), grey)


def test_image_array_errors_name_topic_and_stamp():
    pytest.importorskip("cv2")
    grey = np.zeros((6, 9), np.uint8)
    item = Received("/r/left", "sensor_msgs/msg/Image", 7, _image("yuv422", grey), 0)
    with pytest.raises(InputError, match=r"/r/left at stamp 7 ns: unsupported image encoding"):
        image_array(item)
    short = _image("mono8", grey)
    short.data = short.data[:-1]
    with pytest.raises(InputError, match=r"/cam at stamp 7 ns: 53 bytes for 6 rows"):
        image_array(short, "/cam")
    with pytest.raises(InputError, match=r"/cam at stamp 7 ns: image is 9×6, the camera says"):
        image_array(_image("mono8", grey), "/cam", size=(10, 6))
    bad = m.typestore().types["sensor_msgs/msg/CompressedImage"](
        header=m.header(3, "cam"), format="png", data=np.arange(10, dtype=np.uint8)
    )
    with pytest.raises(InputError, match=r"/cam at stamp 3 ns: cannot decode"):
        image_array(bad, "/cam")
    with pytest.raises(InputError, match="not an image"):
        image_array(m.pose_stamped(np.eye(4), 1), "/cam")


def test_stereo_rig_inverts_the_camera_infos_a_bag_carries():
    from teamslam.frontend.camera import StereoRig
    from teamslam.ros2.image_bags import _camera_info_msg

    K_l = np.array([[400.0, 0, 161.0], [0, 401.0, 119.0], [0, 0, 1]])
    K_r = np.array([[402.0, 0, 159.0], [0, 400.5, 121.0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [0.004, -0.006, 0.002]).as_matrix()
    T[:3, 3] = [0.12, 0.001, -0.002]
    rig = StereoRig((320, 240), K_l, K_r, np.array([0.01, -0.02, 0, 0, 0]), np.zeros(5), T)
    store = m.typestore()
    left = _camera_info_msg(store, 5, "cam", rig, right=False)
    right = _camera_info_msg(store, 5, "cam", rig, right=True)
    back = stereo_rig(Received("/l", "sensor_msgs/msg/CameraInfo", 5, left, 0), right)
    assert back.image_size == (320, 240)
    np.testing.assert_array_equal(back.K_left, K_l)
    np.testing.assert_array_equal(back.K_right, K_r)
    np.testing.assert_array_equal(back.distortion_left, rig.distortion_left)
    np.testing.assert_allclose(back.T_left_right, T, atol=1e-12)
    with pytest.raises(InputError, match="right camera info"):
        stereo_rig(left, m.pose_stamped(np.eye(4), 1))
    with pytest.raises(InputError, match="baseline"):
        stereo_rig(left, left)


def _odometry(T: np.ndarray, cov: np.ndarray):
    t = m.typestore().types
    zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    return t["nav_msgs/msg/Odometry"](
        header=m.header(11, "odom"),
        child_frame_id="base_link",
        pose=t["geometry_msgs/msg/PoseWithCovariance"](pose=m.pose_msg(T), covariance=cov),
        twist=t["geometry_msgs/msg/TwistWithCovariance"](
            twist=t["geometry_msgs/msg/Twist"](linear=zero, angular=zero),
            covariance=np.zeros(36),
        ),
    )


def test_odometry_pose_and_covariance():
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("zyx", [0.3, -0.2, 0.1]).as_matrix()
    T[:3, 3] = [1.5, -2.0, 0.25]
    pose, cov = odometry_pose(_odometry(T, np.zeros(36)))
    np.testing.assert_allclose(pose, T, atol=1e-12)
    assert cov is None
    unknown = np.zeros(36)
    unknown[0] = -1.0
    assert odometry_pose(_odometry(T, unknown))[1] is None
    given = np.diag([0.1, 0.2, 0.3, 0.01, 0.02, 0.03]).ravel()
    pose, cov = odometry_pose(Received("/o", "nav_msgs/msg/Odometry", 11, _odometry(T, given), 0))
    np.testing.assert_array_equal(cov, given.reshape(6, 6))
    bad = _odometry(T, np.zeros(36))
    bad.pose.pose.orientation.w = 3.0
    with pytest.raises(InputError, match="odometry at stamp 11 ns: quaternion"):
        odometry_pose(bad)
    with pytest.raises(InputError, match="not a nav_msgs/msg/Odometry"):
        odometry_pose(m.pose_stamped(np.eye(4), 1))
