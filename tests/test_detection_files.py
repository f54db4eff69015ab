"""Detector files read into per-image boxes: YOLO folders, COCO JSON, vision_msgs bags.

Round trips against generated boxes, the pixel convention, clipping counts, and a one-line
error naming file and line (or entry, or stamp) for every malformed input.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from teamslam.errors import InputError
from teamslam.frontend.detections import (
    ImageDetections,
    clip_boxes,
    read_detections,
)

W, H = 640, 480
NAMES = [f"{k:06d}.png" for k in range(6)]


def _generate(seed: int, n_images: int = 6, dimension: int | None = None) -> list[ImageDetections]:
    """Random boxes inside a ``W × H`` image (pixel-centre convention); some images empty."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n_images):
        m = 0 if i % 3 == 1 else int(rng.integers(1, 6))
        size = rng.uniform(2.0, 200.0, (m, 2))
        lo = rng.uniform(-0.5, np.array([W, H]) - 0.5 - size)
        boxes = np.hstack([lo, lo + size])
        classes = rng.integers(0, 80, m)
        scores = rng.uniform(0.0, 1.0, m)
        emb = None if dimension is None else rng.normal(size=(m, dimension)).astype(np.float32)
        out.append(ImageDetections(boxes, classes, scores, emb))
    return out


def _write_yolo(folder: Path, names, detections, *, fmt=repr, score=True) -> Path:
    """One ``<stem>.txt`` per image with boxes, normalised as ultralytics writes them."""
    folder.mkdir(parents=True, exist_ok=True)
    for name, det in zip(names, detections, strict=True):
        if not len(det):
            continue
        lines = []
        for k, (x0, y0, x1, y1) in enumerate(det.boxes.tolist()):
            cx, cy = (x0 + x1 + 1) / 2 / W, (y0 + y1 + 1) / 2 / H
            w, h = (x1 - x0) / W, (y1 - y0) / H
            cols = [str(int(det.classes[k])), *(fmt(v) for v in (cx, cy, w, h))]
            if score:
                cols.append(fmt(float(det.scores[k])))
            if det.embeddings is not None:
                cols += [repr(float(e)) for e in det.embeddings[k]]
            lines.append(" ".join(cols))
        (folder / f"{Path(name).stem}.txt").write_text("\n".join(lines) + "\n")
    return folder


def _coco_entries(ids, detections) -> list[dict]:
    out = []
    for image_id, det in zip(ids, detections, strict=True):
        for k, (x0, y0, x1, y1) in enumerate(det.boxes.tolist()):
            entry = {
                "image_id": image_id,
                "category_id": int(det.classes[k]),
                "bbox": [x0 + 0.5, y0 + 0.5, x1 - x0, y1 - y0],
                "score": float(det.scores[k]),
            }
            if det.embeddings is not None:
                entry["embedding"] = [float(e) for e in det.embeddings[k]]
            out.append(entry)
    return out


def _same(read, expected, atol=1e-9) -> None:
    assert len(read) == len(expected)
    for got, want in zip(read, expected, strict=True):
        np.testing.assert_allclose(got.boxes, want.boxes, rtol=0, atol=atol)
        np.testing.assert_array_equal(got.classes, want.classes)
        assert got.classes.dtype == np.int64 and got.boxes.dtype == np.float64
        np.testing.assert_array_equal(got.scores, want.scores)
        if want.embeddings is None:
            assert got.embeddings is None
        else:
            assert got.embeddings.dtype == np.float32
            np.testing.assert_array_equal(got.embeddings, want.embeddings)


def _error(call) -> str:
    with pytest.raises(InputError) as info:
        call()
    text = str(info.value)
    assert "\n" not in text
    return text


# ----------------------------------------------------------------------------- YOLO
def test_yolo_round_trip(tmp_path):
    dets = _generate(1)
    folder = _write_yolo(tmp_path / "labels", NAMES, dets)
    read = read_detections(folder, NAMES, (W, H))
    _same(read.images, dets)
    assert read.boxes_read == sum(map(len, dets)) == read.boxes_kept
    assert read.boxes_clipped == read.boxes_dropped == 0
    assert read.images_without_file == sum(1 for d in dets if not len(d)) > 0
    assert read.dimension is None


def test_yolo_as_ultralytics_formats_it(tmp_path):
    """``%g`` (six significant digits) without a score column: boxes to the text's precision,
    scores 1."""
    dets = _generate(2)
    folder = _write_yolo(tmp_path / "labels", NAMES, dets, fmt=lambda v: f"{v:g}", score=False)
    read = read_detections(folder, NAMES, (W, H))
    for got, want in zip(read.images, dets, strict=True):
        np.testing.assert_allclose(got.boxes, want.boxes, rtol=0, atol=1e-6 * W)
        np.testing.assert_array_equal(got.scores, np.ones(len(want)))


def test_yolo_embeddings(tmp_path):
    dets = _generate(3, dimension=5)
    folder = _write_yolo(tmp_path / "labels", NAMES, dets)
    read = read_detections(folder, NAMES, (W, H))
    _same(read.images, dets)
    assert read.dimension == 5
    assert all(d.embeddings.shape == (len(d), 5) for d in read.images)


def test_yolo_image_order_is_the_callers(tmp_path):
    dets = _generate(4)
    folder = _write_yolo(tmp_path / "labels", NAMES, dets)
    order = [3, 0, 5, 2, 4, 1]
    read = read_detections(folder, [NAMES[i] for i in order], (W, H))
    _same(read.images, [dets[i] for i in order])


def test_pixel_convention(tmp_path):
    """Normalised 0..1 spans the image's outer edges; pixel centres are integers."""
    folder = tmp_path / "labels"
    folder.mkdir()
    (folder / "a.txt").write_text(f"0 0.5 0.5 1 1\n1 {0.5 / W!r} {0.5 / H!r} {1 / W!r} {1 / H!r}\n")
    read = read_detections(folder, ["a.png"], (W, H))
    np.testing.assert_array_equal(read.images[0].boxes[0], [-0.5, -0.5, W - 0.5, H - 0.5])
    # the box of the top-left pixel alone is centred on (0, 0)
    np.testing.assert_allclose(read.images[0].boxes[1], [-0.5, -0.5, 0.5, 0.5], atol=1e-12)
    assert read.boxes_clipped == 0

    coco = tmp_path / "r.json"
    coco.write_text(json.dumps([{"image_id": "a", "category_id": 0, "bbox": [0, 0, W, H]}]))
    read = read_detections(coco, ["a.png"], (W, H))
    np.testing.assert_array_equal(read.images[0].boxes[0], [-0.5, -0.5, W - 0.5, H - 0.5])
    assert read.images[0].scores[0] == 1.0


def test_clipping_and_dropping_counts(tmp_path):
    folder = tmp_path / "labels"
    folder.mkdir()
    lines = [
        "0 0.5 0.5 0.2 0.2",  # inside
        "1 0 0.5 0.2 0.2",  # left half outside: clipped
        "2 1 1 0.2 0.2",  # bottom-right quarter inside: clipped
        "3 -0.2 0.5 0.2 0.2",  # wholly left of the image: dropped
        "4 0.5 1.3 0.2 0.2",  # wholly below: dropped
        "5 0.5 0.5 2 2",  # covers the image and more: clipped to it
    ]
    (folder / "a.txt").write_text("\n".join(lines))
    read = read_detections(folder, ["a.png"], (W, H))
    assert (read.boxes_read, read.boxes_clipped, read.boxes_dropped) == (6, 3, 2)
    assert read.boxes_kept == 4
    d = read.images[0]
    np.testing.assert_array_equal(d.classes, [0, 1, 2, 5])
    np.testing.assert_allclose(d.boxes[1], [-0.5, 0.4 * H - 0.5, 0.1 * W - 0.5, 0.6 * H - 0.5])
    np.testing.assert_allclose(d.boxes[2], [0.9 * W - 0.5, 0.9 * H - 0.5, W - 0.5, H - 0.5])
    np.testing.assert_array_equal(d.boxes[3], [-0.5, -0.5, W - 0.5, H - 0.5])
    lo, hi = np.array([-0.5, -0.5]), np.array([W - 0.5, H - 0.5])
    assert np.all(d.boxes[:, :2] >= lo) and np.all(d.boxes[:, 2:] <= hi)


def test_clip_boxes_codes():
    boxes = np.array(
        [[0, 0, 10, 10], [-5, 0, 10, 10], [-20, 0, -0.5, 10], [W - 0.5, 0, W + 3, 10.0]]
    )
    clipped, code = clip_boxes(boxes, (W, H))
    np.testing.assert_array_equal(code, [0, 1, 2, 2])
    np.testing.assert_array_equal(clipped[1], [-0.5, 0, 10, 10])


YOLO_BAD = [
    ("0 0.5 0.5 0.2", "4 columns"),
    ("0 0.5 abc 0.2 0.2", "cy 'abc' is not a number"),
    ("0 nan 0.5 0.2 0.2", "cx is nan, not a finite number"),
    ("0 0.5 0.5 inf 0.2", "w is inf, not a finite number"),
    ("0 0.5 0.5 0.2 0.2 -inf", "score is -inf, not a finite number"),
    ("0 0.5 0.5 0 0.2", "box size 0 x 0.2 is not positive"),
    ("0 0.5 0.5 0.2 -0.1", "box size 0.2 x -0.1 is not positive"),
    ("-1 0.5 0.5 0.2 0.2", "class -1 is negative"),
    ("1.5 0.5 0.5 0.2 0.2", "class 1.5 is not an integer"),
    ("car 0.5 0.5 0.2 0.2", "class 'car' is not a number"),
    ("0 0.5 0.5 0.2 0.2 1.5", "score 1.5 is outside [0, 1]"),
    ("0 0.5 0.5 0.2 0.2 -0.01", "score -0.01 is outside [0, 1]"),
    ("0 0.5 0.5 0.2 0.2 0.9 0.1 0.2", "2 embedding values, but"),
    ("0 0.5 0.5 0.2 0.2 0.9 0.1 x 0.3", "embedding value 2 'x' is not a number"),
]


@pytest.mark.parametrize(("line", "message"), YOLO_BAD, ids=[m for _, m in YOLO_BAD])
def test_yolo_malformed_line_names_file_and_line(tmp_path, line, message):
    folder = tmp_path / "labels"
    folder.mkdir()
    path = folder / "000002.txt"
    path.write_text(f"0 0.5 0.5 0.2 0.2 0.9\n\n{line}\n")
    text = _error(lambda: read_detections(folder, NAMES, (W, H)))
    assert text.startswith(f"{path}, line 3: ")
    assert message in text


def test_yolo_embedding_length_must_agree_across_files(tmp_path):
    folder = tmp_path / "labels"
    folder.mkdir()
    (folder / "000000.txt").write_text("0 0.5 0.5 0.2 0.2 0.9 1 2 3\n")
    (folder / "000001.txt").write_text("0 0.5 0.5 0.2 0.2 0.9 1 2 3\n1 0.5 0.5 0.2 0.2 0.9 1 2\n")
    text = _error(lambda: read_detections(folder, NAMES, (W, H)))
    assert text.startswith(f"{folder / '000001.txt'}, line 2: 2 embedding values, but ")
    assert f"{folder / '000000.txt'}, line 1 has 3" in text


def test_yolo_file_for_no_image_is_named(tmp_path):
    folder = _write_yolo(tmp_path / "labels", NAMES, _generate(5))
    stray = folder / "000099.txt"
    stray.write_text("0 0.5 0.5 0.2 0.2\n")
    text = _error(lambda: read_detections(folder, NAMES, (W, H)))
    assert text.startswith(f"{stray}: detection file for no image")


def test_yolo_folder_errors(tmp_path):
    folder = tmp_path / "labels"
    folder.mkdir()
    assert "share the stem 'a'" in _error(
        lambda: read_detections(folder, ["a.png", "a.jpg"], (W, H))
    )
    assert "given twice" in _error(lambda: read_detections(folder, ["a.png", "a.png"], (W, H)))
    assert "no images file" in _error(
        lambda: read_detections(folder, NAMES, (W, H), images_file=tmp_path / "x.json")
    )
    assert "image size must be positive, got 0x480" in _error(
        lambda: read_detections(folder, NAMES, (0, H))
    )
    assert "no such detection file or folder" in _error(
        lambda: read_detections(tmp_path / "nothing", NAMES, (W, H))
    )
    other = tmp_path / "boxes.csv"
    other.write_text("")
    assert "a folder of YOLO .txt files or a COCO .json file" in _error(
        lambda: read_detections(other, NAMES, (W, H))
    )


def test_yolo_empty_folder_reads_no_boxes(tmp_path):
    folder = tmp_path / "labels"
    folder.mkdir()
    read = read_detections(folder, NAMES, (W, H))
    assert read.images_without_file == len(NAMES) and read.boxes_read == 0
    assert all(len(d) == 0 and d.boxes.shape == (0, 4) for d in read.images)
    assert read_detections(folder, [], (W, H)).images == ()


# ----------------------------------------------------------------------------- COCO
def test_coco_round_trip_with_string_ids(tmp_path):
    dets = _generate(6)
    path = tmp_path / "results.json"
    ids = [n if k % 2 else Path(n).stem for k, n in enumerate(NAMES)]  # file names and stems
    path.write_text(json.dumps(_coco_entries(ids, dets)))
    read = read_detections(path, NAMES, (W, H))
    _same(read.images, dets)
    assert read.boxes_read == sum(map(len, dets))
    assert read.images_without_file == 0 and read.boxes_clipped == 0


def test_coco_integer_ids_of_numeric_stems(tmp_path):
    """ultralytics writes ``image_id = int(stem)`` for numeric stems."""
    dets = _generate(7)
    path = tmp_path / "predictions.json"
    path.write_text(json.dumps(_coco_entries(range(len(NAMES)), dets)))
    _same(read_detections(path, NAMES, (W, H)).images, dets)


def test_coco_images_list_in_the_file_or_beside_it(tmp_path):
    dets = _generate(8)
    ids = [100 + 7 * k for k in range(len(NAMES))]
    images = [
        {"id": i, "file_name": f"val/{n}", "width": W, "height": H}
        for i, n in zip(ids, NAMES, strict=True)
    ]
    entries = _coco_entries(ids, dets)
    for e in entries:  # as ground truth: annotations carry no score
        del e["score"]
    one = tmp_path / "annotations.json"
    one.write_text(json.dumps({"images": images, "annotations": entries, "categories": []}))
    read = read_detections(one, NAMES, (W, H))
    _same(read.images, [ImageDetections(d.boxes, d.classes, np.ones(len(d))) for d in dets])

    results, gt = tmp_path / "results.json", tmp_path / "instances_val.json"
    results.write_text(json.dumps(_coco_entries(ids, dets)))
    gt.write_text(json.dumps({"images": images, "annotations": []}))
    _same(read_detections(results, NAMES, (W, H), images_file=gt).images, dets)
    bare = tmp_path / "images.json"
    bare.write_text(json.dumps(images))
    _same(read_detections(results, NAMES, (W, H), images_file=bare).images, dets)

    dict_form = tmp_path / "detections.json"
    dict_form.write_text(json.dumps({"images": images, "detections": _coco_entries(ids, dets)}))
    _same(read_detections(dict_form, NAMES, (W, H)).images, dets)


def test_coco_embeddings(tmp_path):
    dets = _generate(9, dimension=4)
    path = tmp_path / "results.json"
    path.write_text(json.dumps(_coco_entries(NAMES, dets)))
    read = read_detections(path, NAMES, (W, H))
    _same(read.images, dets)
    assert read.dimension == 4


def _good(image_id="000001") -> dict:
    return {"image_id": image_id, "category_id": 3, "bbox": [10, 20, 30, 40], "score": 0.5}


COCO_BAD = [
    ({"image_id": "000001", "category_id": 3}, "no bbox"),
    ({**_good(), "bbox": [1, 2, 3]}, "is not [x, y, width, height]"),
    ({**_good(), "bbox": [1, "2", 3, 4]}, "is not [x, y, width, height]"),
    ({**_good(), "bbox": [1, 2, float("nan"), 4]}, "is not finite"),
    ({**_good(), "bbox": [1, 2, float("inf"), 4]}, "is not finite"),
    ({**_good(), "bbox": [1, 2, 0, 4]}, "box size 0 x 4 is not positive"),
    ({**_good(), "bbox": [1, 2, 5, -4]}, "box size 5 x -4 is not positive"),
    ({**_good(), "category_id": -1}, "category_id -1 is negative"),
    ({**_good(), "category_id": 1.5}, "category_id 1.5 is not an integer"),
    ({**_good(), "category_id": "car"}, 'category_id "car" is not an integer'),
    ({**_good(), "score": 1.5}, "score 1.5 is outside [0, 1]"),
    ({**_good(), "score": "high"}, 'score "high" is not a finite number'),
    ({**_good(), "score": float("nan")}, "score NaN is not a finite number"),
    ({**_good(), "embedding": [1.0, 2.0]}, "2 embedding values, but"),
    ({**_good(), "embedding": ["a"]}, "embedding is not a list of finite numbers"),
    (_good("000042"), "image '000042' is none of the images"),
    (_good(42), "image 42 is none of the images"),
    (_good(None), "image_id null is not an integer or a string"),
    ([1, 2], "an entry is a JSON object"),
]


@pytest.mark.parametrize(("entry", "message"), COCO_BAD, ids=[m for _, m in COCO_BAD])
def test_coco_malformed_entry_names_file_and_entry(tmp_path, entry, message):
    path = tmp_path / "results.json"
    path.write_text(json.dumps([_good(), entry]))
    text = _error(lambda: read_detections(path, NAMES, (W, H)))
    assert text.startswith(f"{path}, entry 1: ")
    assert message in text


def test_coco_ids_through_an_images_list_must_resolve(tmp_path):
    images = [{"id": 1, "file_name": "000001.png"}, {"id": 2, "file_name": "elsewhere.png"}]
    path = tmp_path / "a.json"
    path.write_text(json.dumps({"images": images, "annotations": [_good(1), _good(3)]}))
    assert _error(lambda: read_detections(path, NAMES, (W, H))).startswith(
        f"{path}, entry 1: image_id 3 is not in the images list"
    )
    path.write_text(json.dumps({"images": images, "annotations": [_good(1), _good(2)]}))
    assert _error(lambda: read_detections(path, NAMES, (W, H))).startswith(
        f"{path}, entry 1: image 'elsewhere.png' is none of the images"
    )
    path.write_text(json.dumps({"images": [*images, images[0]], "annotations": []}))
    assert f"{path}, images[2]: image id 1 is given twice" in _error(
        lambda: read_detections(path, NAMES, (W, H))
    )
    path.write_text(json.dumps({"images": [{"id": 1}], "annotations": []}))
    assert f"{path}, images[0]: an image is" in _error(lambda: read_detections(path, NAMES, (W, H)))
    path.write_text(json.dumps({"images": images, "annotations": []}))
    assert "give no images file too" in _error(
        lambda: read_detections(path, NAMES, (W, H), images_file=path)
    )


def test_coco_ambiguous_stem(tmp_path):
    path = tmp_path / "r.json"
    path.write_text(json.dumps([_good(7)]))
    text = _error(lambda: read_detections(path, ["7.png", "007.png"], (W, H)))
    assert text.startswith(f"{path}, entry 0: image 7 could be 7.png and 007.png")


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("[{", "not valid JSON: line 1, column 3"),
        ("42", "a COCO results JSON is a list"),
        ('"results"', "got a JSON str"),
        ('{"images": []}', "this dict has keys images"),
        ('{"annotations": {}}', "'annotations' must be a list"),
        ('{"images": {}, "annotations": []}', "'images' must be a list"),
    ],
)
def test_coco_file_of_the_wrong_shape(tmp_path, content, message):
    path = tmp_path / "r.json"
    path.write_text(content)
    text = _error(lambda: read_detections(path, NAMES, (W, H)))
    assert text.startswith(f"{path}") and message in text


def test_coco_images_file_of_the_wrong_shape(tmp_path):
    path, images = tmp_path / "r.json", tmp_path / "gt.json"
    path.write_text("[]")
    images.write_text('{"annotations": []}')
    assert _error(lambda: read_detections(path, NAMES, (W, H), images_file=images)).startswith(
        f"{images}: an images file is a COCO JSON with an 'images' list"
    )
    assert "cannot read" in _error(
        lambda: read_detections(path, NAMES, (W, H), images_file=tmp_path / "missing.json")
    )


# ----------------------------------------------------------------------------- bags
@pytest.fixture
def bag_io():
    pytest.importorskip("rosbags")
    from teamslam.ros2 import detection_bags

    return detection_bags


STAMPS = [1_000_000_000 + 50_000_000 * k for k in range(len(NAMES))]


def test_bag_round_trip(tmp_path, bag_io):
    dets = _generate(10)
    bag = tmp_path / "detections.mcap"
    counts = bag_io.write_detection_topic(bag, "/camera/detections", STAMPS, dets)
    assert counts == {"/camera/detections": len(dets)}
    read = bag_io.read_detection_topic(bag, "/camera/detections", STAMPS, (W, H))
    _same(read.images, dets)
    assert read.boxes_read == sum(map(len, dets)) and read.images_without_file == 0
    assert all(read.class_table[k] == int(k) for k in read.class_table)


def test_bag_named_classes_and_missing_stamps(tmp_path, bag_io):
    dets = _generate(11)
    names = [f"class_{k}" for k in range(80)]
    bag = tmp_path / "detections.mcap"
    bag_io.write_detection_topic(bag, "/det", STAMPS[::2], dets[::2], class_names=names)
    table = {n: k for k, n in enumerate(names)}
    read = bag_io.read_detection_topic(bag, "/det", STAMPS, (W, H), classes=table)
    expected = [d if k % 2 == 0 else ImageDetections.empty() for k, d in enumerate(dets)]
    _same(read.images, expected)
    assert read.images_without_file == len(STAMPS) // 2
    # without a table: names numbered in order of first appearance
    read = bag_io.read_detection_topic(bag, "/det", STAMPS, (W, H))
    seen = [names[c] for d in dets[::2] for c in d.classes]
    assert read.class_table == {n: k for k, n in enumerate(dict.fromkeys(seen))}
    got = np.concatenate([d.classes for d in read.images])
    np.testing.assert_array_equal(got, [read.class_table[n] for n in seen])
    text = _error(
        lambda: bag_io.read_detection_topic(bag, "/det", STAMPS, (W, H), classes={"x": 0})
    )
    assert text.startswith(f"/det, message at {STAMPS[0]} ns, detection 0: class id ")


def test_class_table_rule(bag_io):
    assert bag_io.class_table(["3", "0", "3"]) == {"3": 3, "0": 0}
    assert bag_io.class_table(["car", "3", "person", "car"]) == {"car": 0, "3": 1, "person": 2}


def test_bag_pixel_convention(tmp_path, bag_io):
    whole = ImageDetections(np.array([[-0.5, -0.5, W - 0.5, H - 0.5]]), np.array([2]), np.ones(1))
    bag = tmp_path / "d.mcap"
    bag_io.write_detection_topic(bag, "/det", STAMPS[:1], [whole])
    from rosbags.highlevel import AnyReader

    from teamslam.ros2 import messages as m

    with AnyReader([bag], default_typestore=m.typestore()) as reader:
        conn, _, raw = next(iter(reader.messages()))
        msg = reader.deserialize(raw, conn.msgtype)
    box = msg.detections[0].bbox
    assert (box.center.position.x, box.center.position.y) == (W / 2, H / 2)
    assert (box.size_x, box.size_y) == (W, H)
    read = bag_io.read_detection_topic(bag, "/det", STAMPS[:1], (W, H))
    np.testing.assert_array_equal(read.images[0].boxes, whole.boxes)


def _raw_bag(path: Path, stamps, detections_per_message, topic="/det"):
    """A bag of hand-built ``Detection2DArray`` messages (for the malformed cases)."""
    from teamslam.ros2 import messages as m

    t = m.typestore().types
    records = []
    for stamp, dets in zip(stamps, detections_per_message, strict=True):
        msg = t[m.DETECTIONS_TYPE](header=m.header(stamp, "camera"), detections=dets)
        records.append((stamp, topic, m.DETECTIONS_TYPE, m.serialize(msg)))
    m.write_mcap_records(records, path)
    return path


def _detection2d(stamp, results, cx=100.0, cy=80.0, sx=20.0, sy=10.0, theta=0.0):
    from teamslam.ros2 import messages as m

    t = m.typestore().types
    pose = t["geometry_msgs/msg/PoseWithCovariance"](
        pose=m.pose_msg(np.eye(4)), covariance=np.zeros(36)
    )
    return t["vision_msgs/msg/Detection2D"](
        header=m.header(stamp, "camera"),
        results=[
            t["vision_msgs/msg/ObjectHypothesisWithPose"](
                hypothesis=t["vision_msgs/msg/ObjectHypothesis"](class_id=c, score=s), pose=pose
            )
            for c, s in results
        ],
        bbox=t["vision_msgs/msg/BoundingBox2D"](
            center=t["vision_msgs/msg/Pose2D"](
                position=t["vision_msgs/msg/Point2D"](x=cx, y=cy), theta=theta
            ),
            size_x=sx,
            size_y=sy,
        ),
        id="track-7",
    )


def test_bag_best_hypothesis_gives_the_class(tmp_path, bag_io):
    s = STAMPS[0]
    bag = _raw_bag(
        tmp_path / "d.mcap", [s], [[_detection2d(s, [("1", 0.2), ("4", 0.7), ("2", 0.1)])]]
    )
    read = bag_io.read_detection_topic(bag, "/det", [s], (W, H))
    assert read.images[0].classes.tolist() == [4] and read.images[0].scores.tolist() == [0.7]
    np.testing.assert_array_equal(read.images[0].boxes, [[89.5, 74.5, 109.5, 84.5]])


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"results": []}, "no class hypothesis"),
        ({"results": [("1", 1.5)]}, "score 1.5 is outside [0, 1]"),
        ({"results": [("1", float("nan"))]}, "not finite"),
        ({"results": [("1", 0.5)], "theta": 0.3}, "rotated box (theta 0.3)"),
        ({"results": [("1", 0.5)], "sx": 0.0}, "box size 0 x 10 is not positive"),
        ({"results": [("1", 0.5)], "cx": float("inf")}, "not finite"),
    ],
)
def test_bag_malformed_detection_names_topic_stamp_and_index(tmp_path, bag_io, kwargs, message):
    s = STAMPS[1]
    good = _detection2d(s, [("1", 0.5)])
    bag = _raw_bag(tmp_path / "d.mcap", [s], [[good, _detection2d(s, **kwargs)]])
    text = _error(lambda: bag_io.read_detection_topic(bag, "/det", STAMPS, (W, H)))
    assert text.startswith(f"/det, message at {s} ns, detection 1: ")
    assert message in text


def test_bag_errors(tmp_path, bag_io):
    bag = tmp_path / "d.mcap"
    bag_io.write_detection_topic(bag, "/det", STAMPS, _generate(12))
    text = _error(lambda: bag_io.read_detection_topic(bag, "/det", STAMPS[1:], (W, H)))
    assert text == f"/det: a message stamped {STAMPS[0]} ns matches no image stamp"
    assert "no topic /other" in _error(
        lambda: bag_io.read_detection_topic(bag, "/other", STAMPS, (W, H))
    )
    assert "no such bag" in _error(
        lambda: bag_io.read_detection_topic(tmp_path / "none.mcap", "/det", STAMPS, (W, H))
    )
    assert "two images share a stamp" in _error(
        lambda: bag_io.read_detection_topic(bag, "/det", [STAMPS[0]] * 2, (W, H))
    )
    assert "labels must be integers" in _error(
        lambda: bag_io.read_detection_topic(bag, "/det", STAMPS, (W, H), classes={"1": -1})
    )


def test_bag_without_definitions_reads_with_the_registered_types(tmp_path, bag_io):
    """Humble records sqlite3 bags without message definitions: the typestore's vision_msgs
    types decode them."""
    import sqlite3

    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import MessageDefinitionFormat
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin

    from teamslam.ros2 import messages as m

    s = STAMPS[2]
    bag = tmp_path / "humble"
    with Writer(bag, version=8, storage_plugin=StoragePlugin.SQLITE3) as writer:
        conn = writer.add_connection("/det", m.DETECTIONS_TYPE, typestore=m.typestore())
        msg = m.typestore().types[m.DETECTIONS_TYPE](
            header=m.header(s, "camera"), detections=[_detection2d(s, [("person", 0.8)])]
        )
        writer.write(conn, s, m.serialize(msg))
    with sqlite3.connect(next(bag.glob("*.db3"))) as db:
        db.execute("DELETE FROM message_definitions")
    with AnyReader([bag], default_typestore=m.typestore()) as reader:
        assert reader.connections[0].msgdef.format == MessageDefinitionFormat.NONE
    read = bag_io.read_detection_topic(bag, "/det", [s], (W, H))
    assert read.class_table == {"person": 0} and read.images[0].scores.tolist() == [0.8]
    np.testing.assert_array_equal(read.images[0].boxes, [[89.5, 74.5, 109.5, 84.5]])
