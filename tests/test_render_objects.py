"""Rendered objects and the simulated detector: exact casting onto boxes, cylinders and cones,
occlusion in the id buffer, unchanged grey renders without objects, the street layout, the
detector's boxes against the visible truth and its error rates against its settings, and the
files a team with a detector is written as."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2", reason="the images extra (OpenCV) is not installed")

from scipy import stats  # noqa: E402

from teamslam.datasets.images import read_image  # noqa: E402
from teamslam.errors import InputError  # noqa: E402
from teamslam.frontend.detections import ImageDetections  # noqa: E402
from teamslam.geometry import se3  # noqa: E402
from teamslam.sim.detector import DetectorConfig, detect, write_yolo  # noqa: E402
from teamslam.sim.render import (  # noqa: E402
    RenderConfig,
    TexturedRoom,
    render_stereo,
    render_team,
    robot_paths,
    street_loop,
)
from teamslam.sim.shapes import BOX, CONE, CYLINDER, SHAPE_CLASSES, Shapes  # noqa: E402

SMALL = {"image_size": (160, 120), "focal": 105.0}
STREET = {**SMALL, "layout": "street", "objects": "shapes", "robots": 3, "steps": 60}
P_FAIL = 1e-4  # each statistical check fails a correct detector this rarely


@pytest.fixture(scope="module")
def street():
    return render_team(RenderConfig(**STREET))


def _frames(team, every=6):
    K = team.config.camera().intrinsics
    for r in range(team.config.robots):
        for k in range(0, team.config.steps + 1, every):
            T = team.T_world_cam(r, k)
            yield r, k, T, team.room.render_ids(T, K, team.config.image_size)


def _on_surface(shapes: Shapes, j: int, p: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Whether points ``p`` lie on object ``j``'s surface (written from the definitions)."""
    size = shapes.sizes[j]
    base = shapes.centres[j] - [0.0, 0.0, size[2] / 2]
    c, s = np.cos(shapes.yaws[j]), np.sin(shapes.yaws[j])
    q = p - base
    x, y, z = c * q[:, 0] + s * q[:, 1], -s * q[:, 0] + c * q[:, 1], q[:, 2]
    inside_z = (z > -tol) & (z < size[2] + tol)
    if shapes.kinds[j] == BOX:
        lim = np.array([size[0], size[1], size[2] / 2])
        u = np.abs(np.column_stack([x, y, z - size[2] / 2])) - lim
        return np.all(u < tol, axis=1) & np.any(np.abs(u) < tol, axis=1)
    rho = np.hypot(x, y)
    r = size[0] * (1 - z / size[2]) if shapes.kinds[j] == CONE else size[0]
    side = (np.abs(rho - r) < tol) & inside_z
    caps = (np.abs(z) < tol) & (rho < size[0] + tol)
    if shapes.kinds[j] == CYLINDER:
        caps |= (np.abs(z - size[2]) < tol) & (rho < size[0] + tol)
    return side | caps


def test_cast_points_behind_object_pixels_lie_on_the_object(street):
    shapes = street.room.shapes
    kinds_seen = set()
    walls_seen = False
    room_size = np.array(street.config.extent)
    for r, k, _, (image, ids, _) in _frames(street, every=12):
        assert image.shape == (120, 160, 3)
        rows, cols = np.nonzero(ids >= 0)
        uv = np.column_stack([cols, rows]).astype(float)
        p = street.points_behind(r, k, uv)
        for j in np.unique(ids[rows, cols]):
            on = ids[rows, cols] == j
            assert _on_surface(shapes, j, p[on]).all(), (r, k, j)
            kinds_seen.add(int(shapes.kinds[j]))
        np.testing.assert_allclose(street.project(r, k, p)[:, :2], uv, atol=1e-8)
        # pixels that show no object show the street's planes or a cross wall off its doorway
        rows, cols = np.nonzero(ids < 0)
        q = street.points_behind(r, k, np.column_stack([cols, rows]).astype(float))
        on_plane = np.isclose(q, 0.0, atol=1e-9) | np.isclose(q, room_size, atol=1e-9)
        cross = np.isclose(q[:, :1], street.config.partitions[None, :], atol=1e-9).any(axis=1)
        door_w, door_h = street.config.doorway
        in_door = (np.abs(q[:, 1] - room_size[1] / 2) < door_w / 2) & (q[:, 2] < door_h)
        assert (on_plane.any(axis=1) | (cross & ~in_door)).all()
        walls_seen |= cross.any()
    assert kinds_seen == {BOX, CYLINDER, CONE}
    assert walls_seen


def _two_objects(kind_near: int) -> Shapes:
    """A near object at x = 4 (radius/half width 0.3) in front of a wider one at x = 6."""
    sizes = np.array([[0.3, 0.3, 1.4], [0.6, 0.6, 1.8]])
    return Shapes(
        ids=np.array([100, 101]),
        classes=np.array([0, 2]),
        kinds=np.array([kind_near, CYLINDER]),
        centres=np.array([[4.0, 6.0, 0.7], [6.0, 6.0, 0.9]]),
        sizes=sizes,
        yaws=np.zeros(2),
        colours=np.array([[0.2, 0.4, 0.9], [0.9, 0.3, 0.1]]),
        textures=np.zeros(2, np.int64),
        lookalike_of=np.array([-1, -1]),
    )


def _looking(eye, direction):
    z = np.asarray(direction, float) / np.linalg.norm(direction)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = eye
    return T


@pytest.mark.parametrize("kind", [BOX, CYLINDER, CONE])
def test_a_nearer_object_hides_a_farther_one(kind):
    config = RenderConfig(**SMALL, steps=1, robots=1)
    room = TexturedRoom(config, shapes=_two_objects(kind))
    K = config.camera().intrinsics
    centre = np.array([[79.5, 59.5]])  # between the four central pixels: on the axis
    for eye, near in (((1.0, 6.0, 0.6), 0), ((9.0, 6.0, 0.6), 1)):
        T = _looking(eye, (1.0 if near == 0 else -1.0, 0.0, 0.0))
        image, ids, silhouette = room.render_ids(T, K, config.image_size)
        assert ids[59, 79] == near and ids[60, 80] == near
        far = 1 - near
        visible = np.count_nonzero(ids == far)
        assert 0 < visible < silhouette[far] if near == 0 else visible == 0
        # the cast point is on the near object's face towards the camera
        p = room.cast(T, K, centre)
        assert _on_surface(room.shapes, near, p).all()
        assert np.linalg.norm(p - eye) < np.linalg.norm(room.shapes.centres[near] - eye)
        assert image.shape == (120, 160, 3)
        # the room is grey, objects are coloured
        grey = image[ids < 0]
        np.testing.assert_array_equal(grey[:, 0], grey[:, 1])
        coloured = image[ids == near]
        assert np.abs(coloured[:, 0] - coloured[:, 2]).mean() > 0.05


# sha256 of the stereo images below, rendered by the renderer before objects existed; a render
# without objects must not change a single byte (JPEG off: its encoder is OpenCV's build's)
_GREY_DIGEST = "7c6deeaa38c53ab356f8d0caf57ba05d13f2e6bd0233a48da915e9de267ec885"


def test_renders_without_objects_are_unchanged():
    team = render_team(RenderConfig(**SMALL, steps=3, robots=2, jpeg_quality=None))
    digest = hashlib.sha256()
    for r in range(2):
        for k in range(4):
            images = render_stereo(team.room, team.T_world_cam(r, k), np.random.default_rng([r, k]))
            for img in images:
                assert img.shape == (120, 160) and img.dtype == np.uint8
                digest.update(img.tobytes())
    assert digest.hexdigest() == _GREY_DIGEST


def test_colour_images_read_as_grey(street, tmp_path):
    left, right = render_stereo(street.room, street.T_world_cam(0, 0), np.random.default_rng(0))
    assert left.shape == (120, 160, 3) and right.dtype == np.uint8
    cv2.imwrite(str(tmp_path / "a.png"), left)
    grey = read_image(tmp_path / "a.png", (160, 120))
    np.testing.assert_array_equal(grey, cv2.cvtColor(left, cv2.COLOR_BGR2GRAY))


def test_street_paths_loop_clear_of_objects_and_walls(street):
    config = street.config
    length, width = config.street
    shapes = street.room.shapes
    assert len(shapes) >= 0.8 * config.shape_count
    for path in street.paths:
        xy = path[:, :2, 3]
        assert np.all(xy[:, 0] >= config.wall_margin - 1e-9)
        assert np.all(xy[:, 0] <= length - config.wall_margin + 1e-9)
        assert np.all((xy[:, 1] > 0.3 * width) & (xy[:, 1] < 0.7 * width))
        step = np.linalg.norm(np.diff(path[:, :3, 3], axis=0), axis=1)
        np.testing.assert_allclose(step, config.step_length, rtol=0.05)
        gap = np.linalg.norm(xy[:, None, :] - shapes.centres[None, :, :2], axis=2)
        assert np.all(gap - shapes.footprint_radius() >= config.object_clearance - 1e-9)
        # robots pass the cross walls through their doorways
        for x in config.partitions:
            crossing = np.flatnonzero(np.diff(np.sign(xy[:, 0] - x)) != 0)
            y = xy[crossing, 1]
            assert np.all(np.abs(y - width / 2) < config.doorway[0] / 2 - 0.5)
    # objects stand inside the street, clear of the cross walls, and do not overlap
    r = shapes.footprint_radius()
    assert np.all(np.abs(shapes.centres[:, :1] - config.partitions[None, :]) > r[:, None])
    assert np.all(shapes.centres[:, 0] - r > 0) and np.all(shapes.centres[:, 0] + r < length)
    assert np.all(shapes.centres[:, 1] - r > 0) and np.all(shapes.centres[:, 1] + r < width)
    d = np.linalg.norm(shapes.centres[:, None, :2] - shapes.centres[None, :, :2], axis=2)
    np.fill_diagonal(d, np.inf)
    assert np.all(d > r[:, None] + r[None, :])
    # robots start spread evenly round the loop, heading along it
    pos, heading = street_loop(config, np.array([0.0]))
    np.testing.assert_allclose(street.paths[0][0, :2, 3], pos[0])
    assert np.cos(heading[0]) == pytest.approx(1.0)


def test_the_room_layout_keeps_its_paths():
    config = RenderConfig(robots=2, steps=30)
    a = robot_paths(config)
    b = robot_paths(RenderConfig(robots=2, steps=30, objects="shapes", markers_per_wall=0))
    for pa, pb in zip(a, b, strict=True):
        np.testing.assert_array_equal(pa, pb)


def test_in_the_street_robots_reach_what_others_saw_long_before():
    config = RenderConfig(**STREET | {"steps": 200})
    team = render_team(config)
    K = config.camera().intrinsics
    n = len(team.room.shapes)
    unseen = config.steps + 1
    first = np.full((config.robots, n), unseen)
    for r in range(config.robots):
        for k in range(0, config.steps + 1, 4):
            _, ids, _ = team.room.render_ids(team.T_world_cam(r, k), K, config.image_size)
            seen = np.bincount(ids[ids >= 0], minlength=n) >= 6
            first[r, seen] = np.minimum(first[r, seen], k)
    # an object a robot first sees at least 100 frames after another robot did
    both = (first[:, None, :] < unseen) & (first[None, :, :] < unseen)
    assert np.any(both & (first[:, None, :] - first[None, :, :] >= 100))
    # every robot sees objects no other robot saw before it, and none sees every object
    for r in range(config.robots):
        others = np.delete(first, r, axis=0).min(axis=0)
        assert np.any(first[r] < others)
        assert np.any(first[r] == unseen)


def _visible_extent(ids, j):
    """The box of object ``j``'s pixels: their outer edges (pixel centres ± 0.5)."""
    rows, cols = np.nonzero(ids == j)
    return np.array([cols.min() - 0.5, rows.min() - 0.5, cols.max() + 0.5, rows.max() + 0.5])


def test_noise_free_boxes_are_the_visible_extent_of_each_object(street):
    config = DetectorConfig(box_noise=0.0, miss=0.0, clutter=0.0, confusion=0.0)
    shapes = street.room.shapes
    boxes = 0
    for r, k, _, (_, ids, silhouette) in _frames(street):
        out = detect(config, ids, silhouette, shapes.classes, 5, np.random.default_rng(k))
        det = out.detections
        np.testing.assert_array_equal(np.sort(out.truth), np.sort(out.eligible))
        np.testing.assert_array_equal(det.classes, shapes.classes[out.truth])
        counts = np.bincount(ids[ids >= 0], minlength=len(shapes))
        for j in range(len(shapes)):
            big = counts[j] >= config.min_area * ids.size
            share = counts[j] >= config.min_visible * max(silhouette[j], 1)
            assert (j in out.eligible) == (counts[j] > 0 and big and share)
        for box, j in zip(det.boxes, out.truth, strict=True):
            np.testing.assert_array_equal(box, _visible_extent(ids, j))
            # the visible surface points project inside the box, and the box inside the
            # projection of the object's bounding box
            rows, cols = np.nonzero(ids == j)
            p = street.points_behind(r, k, np.column_stack([cols, rows]).astype(float))
            z = street.project(r, k, p)[:, :2]
            assert np.all((z >= box[:2] + 0.5 - 1e-6) & (z <= box[2:] - 0.5 + 1e-6))
            corners = shapes.bounding_corners()[j]
            T_cam_world = se3.inverse(street.T_world_cam(r, k))
            c = street.project(r, k, corners)[:, :2]
            if np.all(corners @ T_cam_world[2, :3] + T_cam_world[2, 3] > 0):
                assert np.all(box[:2] >= np.maximum(c.min(axis=0), -0.5) - 1.0)
                assert np.all(box[2:] <= c.max(axis=0) + 1.0)
            boxes += 1
    assert boxes > 20


def test_box_noise_is_gaussian_with_the_set_share_of_the_box_size(street):
    config = DetectorConfig(box_noise=0.05, miss=0.0, clutter=0.0, confusion=0.0)
    shapes = street.room.shapes
    rng = np.random.default_rng(3)
    z = []
    for _, _, _, (_, ids, silhouette) in _frames(street):
        h, w = ids.shape
        for _ in range(20):
            out = detect(config, ids, silhouette, shapes.classes, 5, rng)
            for box, j in zip(out.detections.boxes, out.truth, strict=True):
                truth = _visible_extent(ids, j)
                size = np.array([truth[2] - truth[0], truth[3] - truth[1]] * 2)
                margin = 6 * config.box_noise * size
                if np.any(truth[:2] - margin[:2] < -0.5) or truth[2] + margin[2] > w - 0.5:
                    continue  # near the border: may be clipped
                if truth[3] + margin[3] > h - 0.5 or size.min() < 12:
                    continue  # near the border, or narrow enough to be widened to a pixel
                z.append((box - truth) / (config.box_noise * size))
    z = np.concatenate(z)
    n = z.size
    assert n > 1000
    lo, hi = stats.chi2.ppf([P_FAIL / 2, 1 - P_FAIL / 2], n)
    assert lo < np.sum(z**2) < hi
    assert abs(z.mean()) < stats.norm.ppf(1 - P_FAIL / 2) / np.sqrt(n)
    assert np.abs(z).max() < stats.norm.ppf(1 - P_FAIL / (2 * n))


def test_miss_clutter_and_confusion_rates_match_their_settings(street):
    config = DetectorConfig(miss=0.2, clutter=1.5, confusion=0.1)
    shapes = street.room.shapes
    rng = np.random.default_rng(11)
    images = eligible = true_boxes = false_boxes = confused = 0
    true_scores, false_scores = [], []
    w, h = street.config.image_size
    for _, _, _, (_, ids, silhouette) in _frames(street):
        for _ in range(40):
            out = detect(config, ids, silhouette, shapes.classes, 5, rng)
            images += 1
            eligible += len(out.eligible)
            real = out.truth >= 0
            true_boxes += real.sum()
            false_boxes += (~real).sum()
            confused += np.sum(out.detections.classes[real] != shapes.classes[out.truth[real]])
            true_scores.append(out.detections.scores[real])
            false_scores.append(out.detections.scores[~real])
            b = out.detections.boxes
            assert np.all(b[:, 2] - b[:, 0] >= 1.0 - 1e-9) and np.all(b[:, 3] - b[:, 1] >= 1 - 1e-9)
            assert np.all(b[:, :2] >= -0.5) and np.all(b[:, 2] <= w - 0.5)
            assert np.all(b[:, 3] <= h - 0.5)
            assert np.all(np.diff(out.detections.scores) <= 0)
    misses = eligible - true_boxes
    assert eligible > 1000
    lo, hi = stats.binom.ppf([P_FAIL / 2, 1 - P_FAIL / 2], eligible, config.miss)
    assert lo <= misses <= hi
    lo, hi = stats.poisson.ppf([P_FAIL / 2, 1 - P_FAIL / 2], images * config.clutter)
    assert lo <= false_boxes <= hi
    lo, hi = stats.binom.ppf([P_FAIL / 2, 1 - P_FAIL / 2], true_boxes, config.confusion)
    assert lo <= confused <= hi
    # scores: true boxes higher on average, with the means set; the two overlap
    t, f = np.concatenate(true_scores), np.concatenate(false_scores)
    for s, mean in ((t, config.score_true), (f, config.score_false)):
        var = mean * (1 - mean) / (config.score_concentration + 1)
        assert abs(s.mean() - mean) < stats.norm.ppf(1 - P_FAIL / 2) * np.sqrt(var / s.size)
    assert np.mean(f > np.quantile(t, 0.25)) > 0.01


def _read_yolo(path, image_size):
    """A minimal reader: pixel boxes (pixel-centre convention), classes and scores."""
    w, h = image_size
    rows = np.loadtxt(path, ndmin=2)
    assert rows.shape[1] == 6
    cx, cy, bw, bh = rows[:, 1] * w, rows[:, 2] * h, rows[:, 3] * w, rows[:, 4] * h
    boxes = np.column_stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2]) - 0.5
    return boxes, rows[:, 0], rows[:, 5]


def test_yolo_lines_round_trip_with_the_pixel_centre_convention(tmp_path):
    boxes = np.array([[-0.5, -0.5, 159.5, 119.5], [10.25, 20.0, 30.75, 90.5]])
    det = ImageDetections(boxes, np.array([3, 0]), np.array([0.9, 0.25]))
    write_yolo(tmp_path / "a.txt", det, (160, 120))
    assert (tmp_path / "a.txt").read_text().splitlines()[0] == "3 0.5 0.5 1 1 0.9"
    got, classes, scores = _read_yolo(tmp_path / "a.txt", (160, 120))
    np.testing.assert_allclose(got, boxes, atol=1e-3)
    np.testing.assert_array_equal(classes, [3, 0])
    np.testing.assert_array_equal(scores, [0.9, 0.25])
    write_yolo(tmp_path / "b.txt", ImageDetections.empty(), (160, 120))
    assert not (tmp_path / "b.txt").exists()


def test_a_rendered_team_with_a_detector_writes_yolo_folders_and_truth(tmp_path):
    config = RenderConfig(**STREET | {"steps": 4, "robots": 2, "markers_per_wall": 0})
    team = render_team(config, tmp_path / "t", detector=DetectorConfig(clutter=1.0))
    out = tmp_path / "t"
    objects = np.loadtxt(out / "objects.txt", ndmin=2)
    np.testing.assert_array_equal(objects[:, 0], team.room.shapes.ids)
    np.testing.assert_array_equal(objects[:, 1], team.room.shapes.classes)
    np.testing.assert_allclose(objects[:, 2:], team.room.shapes.centres, atol=1e-8)
    assert team.room.shapes.ids.min() == 0  # no markers: objects are numbered from 0
    names = (out / "classes.txt").read_text().split("\n")[1:6]
    assert [n.split()[1] for n in names] == [c.name for c in SHAPE_CLASSES]
    true_boxes = 0
    for r in range(2):
        d = out / f"robot_{r}"
        stems = {p.stem for p in (d / "left").iterdir()}
        for side in ("", "_right"):
            files = sorted((d / f"detections{side}").iterdir())
            assert files and {p.stem for p in files} <= stems
            truth_files = sorted((d / f"detections{side}_truth").iterdir())
            assert [p.name for p in truth_files] == [p.name for p in files]
            for f, g in zip(files, truth_files, strict=True):
                boxes, classes, scores = _read_yolo(f, config.image_size)
                truth = np.loadtxt(g, ndmin=1).astype(int)
                assert len(truth) == len(boxes)
                assert set(truth) <= set(team.room.shapes.ids) | {-1}
                assert np.all((classes >= 0) & (classes < len(SHAPE_CLASSES)))
                assert np.all((scores >= 0) & (scores <= 1))
                assert np.all(boxes[:, :2] >= -0.5 - 1e-3)
                assert np.all(boxes[:, 2:] <= np.array(config.image_size) - 0.5 + 1e-3)
                # a true box overlaps the projection of its object's bounding box
                k = int(f.stem)
                T_cam_world = se3.inverse(team.T_world_cam(r, k))
                if side:
                    T_cam_world = se3.inverse(config.camera().T_left_right) @ T_cam_world
                for box, i in zip(boxes, truth, strict=True):
                    if i < 0:
                        continue
                    true_boxes += 1
                    j = int(np.flatnonzero(team.room.shapes.ids == i)[0])
                    c = team.room.shapes.bounding_corners()[j]
                    p = c @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
                    uv = p[:, :2] / p[:, 2:] * config.focal + (np.array(config.image_size) - 1) / 2
                    if np.any(p[:, 2] <= 0):
                        continue  # partly behind the camera
                    assert np.all(box[:2] < uv.max(axis=0)) and np.all(box[2:] > uv.min(axis=0))
    assert true_boxes > 10
    img = cv2.imread(str(out / "robot_0" / "left" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert img.shape == (120, 160, 3)


def test_bad_object_and_detector_settings():
    with pytest.raises(InputError, match="layout"):
        RenderConfig(layout="maze")
    with pytest.raises(InputError, match="objects"):
        RenderConfig(objects="teapots")
    with pytest.raises(InputError, match="street"):
        RenderConfig(layout="street", street=(5.0, 6.0))
    with pytest.raises(InputError, match="miss"):
        DetectorConfig(miss=1.5)
    with pytest.raises(InputError, match="clutter"):
        DetectorConfig(clutter=-1.0)
    with pytest.raises(InputError, match="needs objects"):
        render_team(RenderConfig(**SMALL, steps=1, robots=1), detector=DetectorConfig())


def test_simulate_images_with_shapes_from_the_command_line(tmp_path, capsys):
    from teamslam.cli import main

    out = tmp_path / "s"
    argv = ["simulate", "--images", "--objects", "shapes", "--layout", "street", "--no-markers"]
    argv += ["--robots", "1", "--steps", "2", "--image-width", "160", "--no-bag", "--quiet"]
    argv += ["--detector-clutter", "3", "--detector-miss", "0", "--out", str(out)]
    assert main(argv) == 0
    render = (out / "render.json").read_text()
    assert '"layout": "street"' in render and '"markers_per_wall": 0' in render
    assert (out / "markers.txt").read_text().strip() == "# id x y z"
    assert len(np.loadtxt(out / "objects.txt", ndmin=2)) > 10
    truth = [np.loadtxt(p, ndmin=1) for p in (out / "robot_0" / "detections_truth").iterdir()]
    assert sum(np.sum(t == -1) for t in truth) > 0  # clutter 3 per image: false boxes
    capsys.readouterr()
    for bad, message in (
        (["--objects", "7"], "--images takes --objects shapes"),
        (["--detector-miss", "0.2"], "--detector-* options need --objects shapes"),
        (["--objects", "shapes", "--detector-confusion", "1.5"], "expected a number in [0, 1]"),
        (["--objects", "shapes", "--layout", "maze"], "invalid choice"),
        (["--no-markers"], "--no-markers leaves nothing to see"),
    ):
        try:
            code = main(["simulate", "--images", *bad, "--out", str(tmp_path / "x")])
        except SystemExit as exit:  # the argument parser's own errors
            code = exit.code
        assert code == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err
    assert main(["simulate", "--objects", "shapes", "--out", str(tmp_path / "y")]) == 2
    assert "needs --images" in capsys.readouterr().err


def test_markers_hidden_by_an_object_are_not_visible():
    from teamslam.sim.render import T_CAM_BODY, RenderedTeam

    config = RenderConfig(**SMALL, steps=1, robots=1)
    plain = TexturedRoom(config)
    centre = plain.marker_centres[0]  # on the wall x = 0, facing +x
    T_world_cam = _looking(centre + np.array([2.5, 0.0, 0.0]), (-1.0, 0.0, 0.0))
    paths = [np.stack([T_world_cam @ T_CAM_BODY] * 2)]
    cabinet = Shapes(
        ids=np.array([100]),
        classes=np.array([1]),
        kinds=np.array([BOX]),
        centres=np.array([[centre[0] + 1.2, centre[1], 1.25]]),
        sizes=np.array([[0.3, 0.4, 2.5]]),
        yaws=np.zeros(1),
        colours=np.array([[0.5, 0.5, 0.9]]),
        textures=np.zeros(1, np.int64),
        lookalike_of=np.array([-1]),
    )
    for shapes, visible in ((None, True), (cabinet, False)):
        room = TexturedRoom(config, shapes=shapes)
        team = RenderedTeam(None, room, paths, [np.eye(4)[None]], np.zeros(2))
        ids, _, _ = team.visible_markers(0, 0)
        assert (0 in ids) == visible


def test_classes_vary_within_and_lookalikes_copy_an_original():
    config = RenderConfig(**STREET | {"object_count": 40, "lookalikes": 0.5})
    shapes = TexturedRoom(config).shapes
    assert set(shapes.classes) == set(range(len(SHAPE_CLASSES)))
    copies = np.flatnonzero(shapes.lookalike_of >= 0)
    assert copies.size >= 5
    for j in copies:
        o = shapes.lookalike_of[j]
        assert shapes.lookalike_of[o] == -1 and shapes.classes[o] == shapes.classes[j]
        assert shapes.textures[o] == shapes.textures[j]
        np.testing.assert_array_equal(shapes.sizes[o], shapes.sizes[j])
        assert np.abs(shapes.colours[o] - shapes.colours[j]).max() <= 0.03
    for c, cls in enumerate(SHAPE_CLASSES):
        originals = np.flatnonzero((shapes.classes == c) & (shapes.lookalike_of < 0))
        assert np.all(shapes.kinds[originals] == cls.kind)
        if originals.size > 1:  # instances of a class differ in texture, colour and size
            assert np.unique(shapes.textures[originals]).size == originals.size
            assert np.ptp(shapes.colours[originals], axis=0).max() > 0.03
            assert np.ptp(shapes.sizes[originals, 2]) > 0
