"""A simulated object detector on rendered images, from the renderer's per-pixel truth.

For one image, :func:`detect` takes which object each pixel shows
(:meth:`teamslam.sim.render.TexturedRoom.render_ids`) and gives the boxes a detector would:
one per object whose visible part is large enough (the box of its visible pixels, each edge
moved by Gaussian noise scaled by the box's size), minus misses, with class confusions, plus
false boxes on the background (Poisson count, sizes and places drawn in shares of the image),
scored from two overlapping Beta distributions (true boxes higher on average). Every setting
is a probability, a rate or a share (:class:`DetectorConfig`), nothing in pixels.

A box's centre approximates the image of the visible part's centre, not of the object's 3D
reference point (the centre of its bounding box): for an unoccluded object seen from the
camera's height the two differ by perspective (the nearer top or side looks bigger; below a
few percent of the box at the renders' distances); occlusion and the image border shift it by
up to half the hidden part. :func:`write_yolo` writes boxes as ``ultralytics`` does with
``save_txt`` and ``save_conf``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from teamslam.errors import InputError
from teamslam.frontend.detections import ImageDetections

__all__ = ["DetectorConfig", "DetectorOutput", "detect", "write_truth", "write_yolo"]


@dataclass(frozen=True)
class DetectorConfig:
    """How the simulated detector sees and errs.

    Attributes
    ----------
    min_area
        Smallest visible part of an object it detects, as a share of the image's pixels.
    min_visible
        Smallest visible share of an object's unoccluded silhouette inside the image
        (occlusion by other objects hides; the image border truncates but does not hide).
    box_noise
        Std of each box edge, as a share of the box's width (left, right edges) or height.
    miss
        Probability of missing an object it would detect.
    clutter
        Mean number of false boxes per image (Poisson).
    confusion
        Probability that a true box carries another class (uniform over the others).
    clutter_size
        Range of a false box's width as a share of the image's width (log-uniform); its
        height is its width times an aspect ratio log-uniform in ``clutter_aspect``.
    clutter_aspect
        Range of a false box's height / width.
    score_true, score_false, score_concentration
        Mean score of true and of false boxes, and the concentration ``α + β`` of their Beta
        distributions.
    """

    min_area: float = 3e-4
    min_visible: float = 0.3
    box_noise: float = 0.03
    miss: float = 0.05
    clutter: float = 0.3
    confusion: float = 0.03
    clutter_size: tuple[float, float] = (0.03, 0.25)
    clutter_aspect: tuple[float, float] = (0.7, 3.0)
    score_true: float = 0.75
    score_false: float = 0.4
    score_concentration: float = 8.0

    def __post_init__(self) -> None:
        for name in ("min_area", "min_visible", "miss", "confusion", "score_true", "score_false"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise InputError(f"detector {name} must lie in [0, 1]")
        if self.box_noise < 0 or self.clutter < 0 or self.score_concentration <= 0:
            raise InputError("detector box_noise and clutter must be ≥ 0, concentration > 0")
        if not 0.0 < self.score_true < 1.0 or not 0.0 < self.score_false < 1.0:
            raise InputError("detector mean scores must lie strictly between 0 and 1")
        lo, hi = self.clutter_size
        if not 0.0 < lo <= hi <= 1.0 or not 0.0 < self.clutter_aspect[0] <= self.clutter_aspect[1]:
            raise InputError("detector clutter_size must lie in (0, 1], aspects be positive")


@dataclass
class DetectorOutput:
    """One image's boxes and their truth.

    Attributes
    ----------
    detections
        The boxes (raw-image pixels), classes and scores, sorted by falling score.
    truth
        ``(M,)`` the index of the object each box shows, ``-1`` for a false box.
    eligible
        Indices of the objects visible enough to be detected (missed ones included).
    """

    detections: ImageDetections
    truth: np.ndarray
    eligible: np.ndarray


def detect(
    config: DetectorConfig,
    ids: np.ndarray,
    silhouette: np.ndarray,
    classes: np.ndarray,
    n_classes: int,
    rng: np.random.Generator,
) -> DetectorOutput:
    """The simulated detector's boxes for one image.

    Parameters
    ----------
    config
        Detector settings.
    ids
        ``(height, width)`` object index each pixel shows (``-1``: none).
    silhouette
        ``(K,)`` pixels each object covers in the image when the others are ignored.
    classes
        ``(K,)`` true class of each object.
    n_classes
        Number of classes (confusions and false boxes draw from ``0 … n_classes - 1``).
    rng
        Random generator.
    """
    from scipy import ndimage

    h, w = ids.shape
    k = len(silhouette)
    flat = ids.ravel()
    counts = np.bincount(flat[flat >= 0], minlength=k)[:k]
    eligible = np.flatnonzero(
        (counts > 0)
        & (counts >= config.min_area * w * h)
        & (counts >= config.min_visible * np.maximum(silhouette, 1))
    )
    extents = ndimage.find_objects(ids + 1, max_label=k)
    boxes, labels, truth = [], [], []
    for j in eligible:
        if rng.random() < config.miss:
            continue
        rows, cols = extents[j]
        box = np.array([cols.start, rows.start, cols.stop, rows.stop], float) - 0.5
        bw, bh = box[2] - box[0], box[3] - box[1]
        size = np.array([bw, bh, bw, bh])
        boxes.append(box + config.box_noise * size * rng.standard_normal(4))
        label = int(classes[j])
        if n_classes > 1 and rng.random() < config.confusion:
            label = int((label + rng.integers(1, n_classes)) % n_classes)
        labels.append(label)
        truth.append(int(j))
    true_scores = _scores(rng, config.score_true, config.score_concentration, len(truth))
    n_false = int(rng.poisson(config.clutter))
    width = w * np.exp(rng.uniform(*np.log(config.clutter_size), n_false))
    height = np.minimum(width * np.exp(rng.uniform(*np.log(config.clutter_aspect), n_false)), h)
    width = np.minimum(width, w)
    x0 = rng.uniform(0, 1, n_false) * (w - width) - 0.5
    y0 = rng.uniform(0, 1, n_false) * (h - height) - 0.5
    false_boxes = np.column_stack([x0, y0, x0 + width, y0 + height])
    false_labels = rng.integers(0, max(n_classes, 1), n_false)
    false_scores = _scores(rng, config.score_false, config.score_concentration, n_false)
    all_boxes = np.concatenate([np.reshape(boxes, (-1, 4)), false_boxes])
    all_boxes[:, 0::2] = np.clip(all_boxes[:, 0::2], -0.5, w - 0.5)
    all_boxes[:, 1::2] = np.clip(all_boxes[:, 1::2], -0.5, h - 0.5)
    # a box at least one pixel wide and high after noise and clipping
    for lo, hi, limit in ((0, 2, w), (1, 3, h)):
        thin = all_boxes[:, hi] - all_boxes[:, lo] < 1.0
        mid = np.clip(0.5 * (all_boxes[thin, lo] + all_boxes[thin, hi]), 0.0, limit - 1.0)
        all_boxes[thin, lo], all_boxes[thin, hi] = mid - 0.5, mid + 0.5
    scores = np.concatenate([true_scores, false_scores])
    order = np.argsort(-scores, kind="stable")
    detections = ImageDetections(
        all_boxes[order],
        np.concatenate([labels, false_labels]).astype(np.int64)[order],
        scores[order],
    )
    all_truth = np.concatenate([np.array(truth, np.int64), np.full(n_false, -1, np.int64)])
    return DetectorOutput(detections, all_truth[order], eligible)


def _scores(rng: np.random.Generator, mean: float, concentration: float, n: int) -> np.ndarray:
    return rng.beta(mean * concentration, (1.0 - mean) * concentration, n)


def write_yolo(path: str | Path, detections: ImageDetections, image_size: tuple[int, int]) -> None:
    """Write one image's boxes as ``ultralytics`` does (``save_txt`` + ``save_conf``): lines
    ``class cx cy w h score`` normalised by the image's width and height (``0 … 1`` spans the
    image's outer edges, so a box's edge at pixel coordinate ``x`` is at ``(x + 0.5) / W``),
    ``%g`` numbers; no file for an image without boxes."""
    if not len(detections):
        return
    w, h = image_size
    b = detections.boxes
    rows = np.column_stack(
        [
            detections.classes,
            (0.5 * (b[:, 0] + b[:, 2]) + 0.5) / w,
            (0.5 * (b[:, 1] + b[:, 3]) + 0.5) / h,
            (b[:, 2] - b[:, 0]) / w,
            (b[:, 3] - b[:, 1]) / h,
            detections.scores,
        ]
    )
    lines = [f"{int(r[0])} " + " ".join(f"{x:g}" for x in r[1:]) for r in rows]
    Path(path).write_text("\n".join(lines) + "\n")


def write_truth(path: str | Path, object_ids: np.ndarray) -> None:
    """Write which object each box of an image shows, one id a line in the boxes' order
    (``-1``: a false box); no file for an image without boxes."""
    if len(object_ids):
        Path(path).write_text("".join(f"{int(i)}\n" for i in object_ids))
