"""Appearance descriptors of a detector's boxes, from the image inside each box (OpenCV, numpy).

:func:`describe` gives per box an L2-normalised float32 vector of a fixed dimension per
descriptor kind (:func:`dimension`); the cosine of two vectors (their dot product) is their
similarity. Each kind is made to survive a detector's box noise (a box shifted or scaled by a
tenth of its size) and a camera's gain and offset:

``thumbnail``
    The grey patch block-averaged to 8 × 8 samples, blurred by one sample (Gaussian σ = 1)
    and made zero-mean (64 numbers): the cosine of two thumbnails is their normalised
    cross-correlation, free of gain and offset; the coarse grid and the blur let a box move
    by a tenth of its size without changing which sample a feature falls in by more than a
    fraction of the blur.
``hog``
    A histogram of oriented gradients of the grey patch resized to 32 × 32 (2 × 2 cells of
    16 px, 9 unsigned orientations, one block, L2-Hys normalised: 36 numbers). Gradients and
    the normalisation remove gain and offset; large cells tolerate a shifted box.
``intensity``
    A histogram of the grey levels of the patch in units of its own standard deviation
    around its mean (16 bins over ±2.5 σ; gain and offset free), square-rooted (the
    Hellinger map, so the dot product is the Bhattacharyya coefficient). No layout at all.
``hue-saturation``
    A hue × saturation histogram (18 × 4 bins, saturation below 0.1 left out as hue-less)
    of the colour patch, square-rooted; neither hue nor saturation changes with a gain. A
    grey image has no hue: its vector is zero (similar to nothing), which keeps the
    dimension fixed.
``thumbnail+hue-saturation``
    Both, each L2-normalised, joined and normalised again (136 numbers): on colour images
    each half weighs ``1/√2`` and the cosine is the mean of the two cosines; on grey images
    the colour half is zero and the grey half is the ``thumbnail`` vector itself (the cosine
    is the thumbnails'). Compare grey with grey only: a grey and a colour view of one object
    score at most ``1/√2``.
``hue-saturation-or-thumbnail``
    The same two blocks (136 numbers), one of them zero: on colour images the
    ``hue-saturation`` histogram alone, on grey images the ``thumbnail`` alone (as
    ``thumbnail+hue-saturation`` gives there, to the bit). A colour histogram keeps an
    object's identity from any side; a thumbnail's layout is the view's, and from another
    side it tells nothing. A grey and a colour view score 0.

The histograms (``intensity``, ``hue-saturation`` and the colour half of the joined kinds)
count only the pixels of a box that no other box of the image covers: where two boxes overlap,
which object a pixel shows is unknown without a segmentation, and in a cluster of objects the
neighbour's colour would otherwise enter every box (a box wholly covered by others counts all
its pixels). The layouts (``thumbnail``, ``hog``) take the whole box: a hole would move with
the neighbour.

``benchmarks/appearance_roc.py`` measures how well each separates one object from another
(ROC AUC): on a grey room of markers (planar, their layout is their identity) and on a colour
street of objects seen from several sides, pairs of one pass and pairs across an absence;
:data:`DEFAULT_DESCRIPTOR` is chosen by it.
"""

from __future__ import annotations

import numpy as np

from teamslam.errors import InputError
from teamslam.frontend._cv import require_cv2

__all__ = ["DEFAULT_DESCRIPTOR", "DESCRIPTORS", "describe", "dimension"]

DESCRIPTORS = (
    "thumbnail",
    "hog",
    "intensity",
    "hue-saturation",
    "thumbnail+hue-saturation",
    "hue-saturation-or-thumbnail",
)
#: ``benchmarks/appearance_roc.py``: ``thumbnail`` separates markers from each other and from
#: wall look-alikes best on grey renders; on colour renders of objects seen from several sides
#: ``hue-saturation`` separates them best, within a pass and across an absence, where a
#: thumbnail's layout changes with the view and adding it only dilutes the colour's evidence
DEFAULT_DESCRIPTOR = "hue-saturation-or-thumbnail"

_THUMBNAIL = 8
_THUMBNAIL_BLUR = 1.0
_HOG_SIDE = 32
_HOG_CELL = 16
_BINS = 9
_INTENSITY_BINS = 16
_INTENSITY_RANGE = 2.5
_HUE_BINS, _SATURATION_BINS = 18, 4
_MIN_SATURATION = 0.1
_DIMENSIONS = {
    "thumbnail": _THUMBNAIL * _THUMBNAIL,
    "hog": (_HOG_SIDE // _HOG_CELL) ** 2 * _BINS,
    "intensity": _INTENSITY_BINS,
    "hue-saturation": _HUE_BINS * _SATURATION_BINS,
}
_DIMENSIONS["thumbnail+hue-saturation"] = _DIMENSIONS["thumbnail"] + _DIMENSIONS["hue-saturation"]
_DIMENSIONS["hue-saturation-or-thumbnail"] = _DIMENSIONS["thumbnail+hue-saturation"]


def dimension(kind: str = DEFAULT_DESCRIPTOR) -> int:
    """The length of a ``kind`` descriptor."""
    _check(kind)
    return _DIMENSIONS[kind]


def _check(kind: str) -> None:
    if kind not in DESCRIPTORS:
        raise InputError(
            f"appearance descriptor {kind!r} unknown; use one of " + ", ".join(DESCRIPTORS)
        )


def _normalised(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` L2-normalised (a zero row stays zero)."""
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return (v / np.where(norm > 0, norm, 1.0)).astype(np.float32)


def _pixel_bounds(shape: tuple[int, ...], boxes: np.ndarray) -> np.ndarray:
    """``(M, 4)`` ``(x0, y0, x1, y1)``, inclusive: the pixels of an image of ``shape`` whose
    centres lie in each box (at least one pixel)."""
    h, w = shape[:2]
    x0 = np.clip(np.ceil(boxes[:, 0]), 0, w - 1)
    y0 = np.clip(np.ceil(boxes[:, 1]), 0, h - 1)
    x1 = np.clip(np.floor(boxes[:, 2]), x0, w - 1)
    y1 = np.clip(np.floor(boxes[:, 3]), y0, h - 1)
    return np.stack([x0, y0, x1, y1], axis=1).astype(np.int64)


def _crop(image: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    x0, y0, x1, y1 = bounds.tolist()
    return image[y0 : y1 + 1, x0 : x1 + 1]


def _uncovered(bounds: np.ndarray, k: int) -> np.ndarray | None:
    """8-bit mask over box ``k``'s crop of the pixels no other box covers; ``None`` (every
    pixel) when no other box overlaps it or the others cover all of it."""
    x0, y0, x1, y1 = bounds[k].tolist()
    lo = np.maximum(bounds[:, :2], bounds[k, :2])
    hi = np.minimum(bounds[:, 2:], bounds[k, 2:])
    overlapping = np.flatnonzero(np.all(lo <= hi, axis=1))
    overlapping = overlapping[overlapping != k]
    if not overlapping.size:
        return None
    mask = np.full((y1 - y0 + 1, x1 - x0 + 1), 255, np.uint8)
    for j in overlapping.tolist():
        mask[lo[j, 1] - y0 : hi[j, 1] - y0 + 1, lo[j, 0] - x0 : hi[j, 0] - x0 + 1] = 0
    return mask if mask.any() else None


def _thumbnail_vector(cv2, grey: np.ndarray) -> np.ndarray:
    small = cv2.resize(
        grey.astype(np.float32), (_THUMBNAIL, _THUMBNAIL), interpolation=cv2.INTER_AREA
    )
    small = cv2.GaussianBlur(small, (0, 0), _THUMBNAIL_BLUR)
    return (small - small.mean()).ravel()


def _hog_vector(cv2, grey: np.ndarray) -> np.ndarray:
    """Orientation histograms (unsigned, ``_BINS`` bins, linear vote between the two nearest
    bins, weighted by the gradient magnitude) of the cells of the patch resized to
    ``_HOG_SIDE``, normalised as one block (L2, clipped at 0.2, L2 again: Dalal–Triggs'
    L2-Hys). OpenCV ≥ 5 has no ``HOGDescriptor`` in its main modules."""
    patch = cv2.resize(grey, (_HOG_SIDE, _HOG_SIDE), interpolation=cv2.INTER_AREA)
    patch = patch.astype(np.float32)
    gx = cv2.Sobel(patch, cv2.CV_32F, 1, 0, ksize=1)
    gy = cv2.Sobel(patch, cv2.CV_32F, 0, 1, ksize=1)
    magnitude, angle = cv2.cartToPolar(gx, gy, angleInDegrees=True)
    position = (angle % 180.0) / (180.0 / _BINS) - 0.5
    low = np.floor(position)
    share = position - low
    low = low.astype(np.int64) % _BINS
    cells = _HOG_SIDE // _HOG_CELL
    rows = np.arange(_HOG_SIDE) // _HOG_CELL
    cell = (rows[:, None] * cells + rows[None, :]) * _BINS
    hist = np.bincount(
        np.concatenate([(cell + low).ravel(), (cell + (low + 1) % _BINS).ravel()]),
        np.concatenate([(magnitude * (1 - share)).ravel(), (magnitude * share).ravel()]),
        minlength=cells * cells * _BINS,
    )
    hist = _normalised(hist)
    return _normalised(np.minimum(hist, 0.2))


def _intensity_vector(grey: np.ndarray, mask: np.ndarray | None) -> np.ndarray:
    g = (grey if mask is None else grey[mask > 0]).astype(np.float32)
    std = float(g.std())
    if std < 1e-6:
        return np.zeros(_INTENSITY_BINS, np.float32)
    hist, _ = np.histogram(
        (g - g.mean()) / std, _INTENSITY_BINS, (-_INTENSITY_RANGE, _INTENSITY_RANGE)
    )
    return np.sqrt(hist.astype(np.float32))


def _hue_saturation_vector(cv2, colour: np.ndarray | None, mask: np.ndarray | None) -> np.ndarray:
    if colour is None:
        return np.zeros(_DIMENSIONS["hue-saturation"], np.float32)
    hsv = cv2.cvtColor(colour, cv2.COLOR_BGR2HSV)
    least = int(np.ceil(_MIN_SATURATION * 255))
    hist = cv2.calcHist([hsv], [0, 1], mask, [_HUE_BINS, _SATURATION_BINS], [0, 180, least, 256])
    return np.sqrt(hist.ravel())


def describe(image: np.ndarray, boxes: np.ndarray, kind: str = DEFAULT_DESCRIPTOR) -> np.ndarray:
    """Appearance descriptors of boxes in one image.

    Parameters
    ----------
    image
        ``(H, W)`` 8-bit grey or ``(H, W, 3)`` 8-bit BGR image the boxes are in.
    boxes
        ``(M, 4)`` ``(x_min, y_min, x_max, y_max)`` in pixels of ``image``: every box of
        the image (the histograms leave out what another box covers).
    kind
        One of :data:`DESCRIPTORS`.

    Returns
    -------
    np.ndarray
        ``(M, dimension(kind))`` float32, each row of unit length (or zero: a patch without
        texture for ``thumbnail`` and ``intensity``, a grey image's ``hue-saturation``, a
        colour box without a hue for ``hue-saturation-or-thumbnail``).
    """
    _check(kind)
    cv2 = require_cv2("appearance descriptors")
    image = np.asarray(image)
    if image.dtype != np.uint8 or not (
        image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)
    ):
        raise InputError(
            f"appearance: image is {image.shape} {image.dtype}, expected 8-bit grey or BGR"
        )
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    colour = image if image.ndim == 3 else None
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if colour is not None else image
    out = np.zeros((len(boxes), _DIMENSIONS[kind]), np.float32)
    bounds = _pixel_bounds(image.shape, boxes)
    histogram = kind not in ("thumbnail", "hog") and (colour is not None or kind == "intensity")
    for k in range(len(boxes)):
        g = _crop(grey, bounds[k])
        c = None if colour is None else _crop(colour, bounds[k])
        mask = _uncovered(bounds, k) if histogram else None
        if kind == "thumbnail":
            out[k] = _thumbnail_vector(cv2, g)
        elif kind == "hog":
            out[k] = _hog_vector(cv2, g)
        elif kind == "intensity":
            out[k] = _intensity_vector(g, mask)
        elif kind == "hue-saturation":
            out[k] = _hue_saturation_vector(cv2, c, mask)
        elif kind == "hue-saturation-or-thumbnail":
            if c is None:
                out[k, : _DIMENSIONS["thumbnail"]] = _normalised(_thumbnail_vector(cv2, g))
            else:
                out[k, _DIMENSIONS["thumbnail"] :] = _hue_saturation_vector(cv2, c, mask)
        else:
            grey_part = _normalised(_thumbnail_vector(cv2, g))
            hue = _normalised(_hue_saturation_vector(cv2, c, mask))
            out[k] = np.concatenate([grey_part, hue])
    return _normalised(out)
