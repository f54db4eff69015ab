"""Stereo measurements of a detector's boxes on a rectified pair.

:class:`BoxStereo` turns one stereo frame and the left image's boxes (raw pixels, a
:class:`~teamslam.frontend.detections.ImageDetections`) into per box the observation the object
filter uses — the stereo box centre ``(u_l, v_l, u_r, v_r)`` in the rectified camera — and the
box size ``(w, h)`` in rectified pixels. The right centre is, in this order:

- the centre of a right-image box, when the detector gave boxes in the right image too: paired
  one to one by class, row overlap (``box_row_overlap``) and a disparity inside the depth
  range, by the largest row overlap, and kept when the two widths agree
  (``box_width_probability`` of the width ratio learned from the pairs seen so far: a box cut
  in one image by an occluder or the border has a centre that is not its object's);
- otherwise the box's patch searched along the rectified row over the depth range's
  disparities by zero-mean normalised cross-correlation, at the level of an image pyramid
  (each level the 2 × 2 means of the one below) where the patch has at most
  ``box_patch_samples`` samples, and the match kept only when it passes ``box_ncc_min``, the
  uniqueness check (``box_uniqueness``, the feature matcher's second-peak test) and the
  left–right check (the right patch searched back in the left image must land within
  ``left_right_share`` of the diagonal, or one sample of the averaged patch, of where it came
  from); the peak is then refined coarse to fine (samples four times smaller at each level of
  an image pyramid, a parabola at each) down to full resolution, or for a large box to a patch
  of 16 times the coarse samples, so that a box's cost does not grow with its size.

A box whose right centre is found neither way stays a monocular measurement (right coordinates
NaN); :attr:`BoxMeasurements.reasons` says why and :meth:`BoxMeasurements.counts` counts them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from teamslam.frontend._cv import require_cv2
from teamslam.frontend.camera import StereoRig
from teamslam.frontend.config import FrontendConfig
from teamslam.frontend.detections import ImageDetections
from teamslam.frontend.stereo import _best
from teamslam.gaussian import chi2_quantile, robust_std

__all__ = ["MONOCULAR_REASONS", "BoxMeasurements", "BoxStereo"]

#: why a box stays monocular: its disparity range leaves the right image, its patch has no
#: texture, the best correlation is below ``box_ncc_min``, a second peak reaches
#: ``box_uniqueness`` of the best, or the left–right check fails
MONOCULAR_REASONS = ("off image", "flat", "weak", "not unique", "left-right")

# a patch whose grey levels vary less than this (standard deviation) has nothing to correlate
_FLAT_STD = 0.5
# the width ratios of this many pairs (the latest) give the ratio's distribution
_WIDTH_SAMPLES = 1000
# a box edge is known to half a pixel at best
_HALF_PIXEL = 0.5
# the finest refinement level correlates a patch of at most this many times the coarse samples
# (full resolution for boxes up to 80 × 80 pixels at the default 400 samples)
_REFINE_SAMPLES = 16


@dataclass(frozen=True)
class BoxMeasurements:
    """The stereo measurements of one frame's boxes (in the order of the boxes given).

    Attributes
    ----------
    z
        ``(M, 4)`` stereo box centres ``(u_l, v_l, u_r, v_r)``, rectified pixels; ``u_r`` and
        ``v_r`` NaN for a monocular box.
    sizes
        ``(M, 2)`` box width and height in rectified pixels.
    classes, scores
        The detector's ``(M,)`` classes and scores.
    source
        ``(M,)`` where the right centre came from: ``"right box"``, ``"patch"`` or
        ``"monocular"``.
    reasons
        ``(M,)`` why a monocular box has no right centre (one of :data:`MONOCULAR_REASONS`),
        ``""`` for the others.
    """

    z: np.ndarray
    sizes: np.ndarray
    classes: np.ndarray
    scores: np.ndarray
    source: np.ndarray
    reasons: np.ndarray

    def __len__(self) -> int:
        return len(self.z)

    def counts(self) -> dict[str, int]:
        """Boxes per source and per monocular reason: ``{"right box": n, "patch": n,
        "monocular": n, "off image": n, …}``."""
        out = {name: int(np.sum(self.source == name)) for name in ("right box", "patch")}
        out["monocular"] = int(np.sum(self.source == "monocular"))
        out.update({name: int(np.sum(self.reasons == name)) for name in MONOCULAR_REASONS})
        return out


def _row_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(A, B)`` overlap of the row spans ``[y_min, y_max]`` of boxes ``a`` and ``b`` over
    their union."""
    lo = np.maximum(a[:, None, 1], b[None, :, 1])
    hi = np.minimum(a[:, None, 3], b[None, :, 3])
    union = np.maximum(a[:, None, 3], b[None, :, 3]) - np.minimum(a[:, None, 1], b[None, :, 1])
    return np.clip(hi - lo, 0.0, None) / np.maximum(union, 1e-9)


class BoxStereo:
    """Stereo box measurements for one calibrated rig (see the module docstring).

    Parameters
    ----------
    rig
        The stereo pair; boxes are given in its raw images, images in its rectified ones.
    config
        Front-end settings (``box_*``, ``left_right_share``, the depth range).
    """

    def __init__(self, rig: StereoRig, config: FrontendConfig | None = None) -> None:
        self.rig = rig
        self.config = config or FrontendConfig()
        self.pixels = self.config.pixels(rig.image_size)
        self.disparity_range = self.config.disparity_range(rig.camera.fx_baseline)
        #: ``log(w_r / w_l)`` of the last :data:`_WIDTH_SAMPLES` pairs of left and right boxes
        #: (their distribution decides which pairs agree in width)
        self.width_ratios = np.zeros(0)

    def rectify_boxes(self, boxes: np.ndarray, side: str = "left") -> np.ndarray:
        """Raw ``(M, 4)`` boxes → the axis-aligned boxes around their corners and edge
        midpoints in the rectified image (clipped to it); the identity for a rectified pair."""
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        if self.rig.already_rectified:
            return boxes.copy()
        x0, y0, x1, y1 = boxes.T
        xm, ym = (x0 + x1) / 2, (y0 + y1) / 2
        xs = np.stack([x0, xm, x1, x1, x1, xm, x0, x0], axis=1)
        ys = np.stack([y0, y0, y0, ym, y1, y1, y1, ym], axis=1)
        pts = self.rig.rectify_points(np.stack([xs, ys], axis=-1).reshape(-1, 2), side)
        pts = pts.reshape(-1, 8, 2)
        w, h = self.rig.image_size
        lo = np.clip(pts.min(axis=1), 0.0, [w - 1, h - 1])
        hi = np.clip(pts.max(axis=1), 0.0, [w - 1, h - 1])
        return np.concatenate([lo, hi], axis=1)

    def _centres(self, boxes: np.ndarray, side: str) -> np.ndarray:
        """Rectified pixels of the raw boxes' centres."""
        centre = (boxes[:, :2] + boxes[:, 2:]) / 2
        return self.rig.rectify_points(centre, side)

    def measure(
        self,
        left: np.ndarray,
        right: np.ndarray,
        detections: ImageDetections,
        right_detections: ImageDetections | None = None,
    ) -> BoxMeasurements:
        """Measure one frame's boxes.

        Parameters
        ----------
        left, right
            The rectified 8-bit grey images (:meth:`StereoRig.rectify`).
        detections
            The left image's boxes, raw pixels.
        right_detections
            The right image's boxes (raw right-image pixels), when the detector ran on it.
        """
        self.rig.check_images(left, right, "box stereo")
        n = len(detections)
        boxes = self.rectify_boxes(detections.boxes)
        z = np.full((n, 4), np.nan)
        z[:, :2] = self._centres(np.asarray(detections.boxes, float).reshape(-1, 4), "left")
        source = np.full(n, "monocular", dtype=object)
        reasons = np.full(n, "", dtype=object)
        # per left box the width its right box shows, where the pair was refused as cut
        visible = np.full(n, np.nan)
        if right_detections is not None and len(right_detections) and n:
            li, ri, cut_li, cut_w = self._pair(detections, boxes, right_detections)
            raw_right = np.asarray(right_detections.boxes, float).reshape(-1, 4)
            z[li, 2:] = self._centres(raw_right[ri], "right")
            source[li] = "right box"
            visible[cut_li] = cut_w
        if n:
            cv2 = require_cv2()
            pyramids = _Pyramid(cv2, left), _Pyramid(cv2, right)
            for k in np.flatnonzero(source == "monocular"):
                d, reason = self._search_visible(cv2, pyramids, boxes[k], visible[k])
                if reason:
                    reasons[k] = reason
                    continue
                z[k, 2:] = z[k, 0] - d, z[k, 1]
                source[k] = "patch"
        return BoxMeasurements(
            z=z,
            sizes=boxes[:, 2:] - boxes[:, :2],
            classes=np.asarray(detections.classes, np.int64),
            scores=np.asarray(detections.scores, np.float64),
            source=source.astype(str),
            reasons=reasons.astype(str),
        )

    def _search_visible(self, cv2, pyramids, box: np.ndarray, visible: float) -> tuple[float, str]:
        """Disparity of a box's patch (:meth:`_search`); for a box whose right box was cut to
        ``visible`` pixels wide (an occluder or the border hides a side of it there), first of
        the two parts of the box that wide at its sides, one of which is what the right image
        shows: the one part matched (both passing every check and agreeing within the
        left–right tolerance: their mean), else the whole patch."""
        if np.isfinite(visible) and visible < box[2] - box[0]:
            found = []
            for side in (box[0], box[2] - visible):
                part = np.array([side, box[1], side + visible, box[3]])
                d, reason = self._search(cv2, *pyramids, part)
                if not reason:
                    found.append(d)
            agree = len(found) == 2 and abs(found[0] - found[1]) <= self.pixels.left_right
            if len(found) == 1 or agree:
                return float(np.mean(found)), ""
        return self._search(cv2, *pyramids, box)

    def _pair(
        self, detections: ImageDetections, boxes: np.ndarray, right: ImageDetections
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Left and right indices of the paired boxes (one to one, largest row overlap, widths
        agreeing), then the left indices of the pairs refused as cut in one image and the
        width of their right boxes."""
        from scipy.optimize import linear_sum_assignment

        rboxes = self.rectify_boxes(right.boxes, "right")
        overlap = _row_iou(boxes, rboxes)
        disparity = (
            boxes[:, None, 0] + boxes[:, None, 2] - rboxes[None, :, 0] - rboxes[None, :, 2]
        ) / 2
        d_lo, d_hi = self.disparity_range
        ok = (
            (np.asarray(detections.classes)[:, None] == np.asarray(right.classes)[None, :])
            & (overlap >= self.config.box_row_overlap)
            & (disparity >= d_lo)
            & (disparity <= d_hi)
            & (disparity > 0)
        )
        li, ri = linear_sum_assignment(np.where(ok, -overlap, 1.0))
        keep = ok[li, ri]
        li, ri = li[keep], ri[keep]
        w_l = np.maximum(boxes[li, 2] - boxes[li, 0], _HALF_PIXEL)
        w_r = np.maximum(rboxes[ri, 2] - rboxes[ri, 0], _HALF_PIXEL)
        ratio = np.log(w_r / w_l)
        self.width_ratios = np.concatenate([self.width_ratios, ratio])[-_WIDTH_SAMPLES:]
        if self.width_ratios.size < 3:
            return li, ri, li[:0], w_r[:0]
        centre = np.median(self.width_ratios)
        spread = robust_std(self.width_ratios)
        # each edge known to half a pixel at best: the ratio's own quantisation
        variance = spread**2 + (_HALF_PIXEL / w_l) ** 2 + (_HALF_PIXEL / w_r) ** 2
        agree = (ratio - centre) ** 2 <= chi2_quantile(self.config.box_width_probability, 1) * (
            variance
        )
        return li[agree], ri[agree], li[~agree], w_r[~agree]

    def _search(self, cv2, left: _Pyramid, right: _Pyramid, box: np.ndarray) -> tuple[float, str]:
        """Disparity of one rectified box's patch along its row, or NaN and why not."""
        w = left.image_width
        size = (max(3, int(box[2] - box[0])), max(3, int(box[3] - box[1])))
        area = size[0] * size[1]
        samples = self.config.box_patch_samples
        # the coarse level: at most box_patch_samples samples; the finest: full resolution, or
        # at most _REFINE_SAMPLES times as many samples
        level = _level(area / samples)
        finest = _level(area / (_REFINE_SAMPLES * samples))
        centre = ((box[0] + box[2]) / 2, (box[1] + box[3]) / 2)
        d_lo = max(0, int(np.floor(self.disparity_range[0])))
        # the right patch must stay inside the right image
        d_hi = min(int(np.ceil(self.disparity_range[1])), int(np.floor(centre[0] - size[0] / 2)))
        coarse = _row_search(cv2, left, right, centre, size, level, (d_lo, d_hi), 1)
        if coarse is None:
            return np.nan, "off image"
        d, best, second, texture = coarse
        if texture < _FLAT_STD:
            return np.nan, "flat"
        if best < self.config.box_ncc_min:
            return np.nan, "weak"
        if second >= self.config.box_uniqueness * best:
            return np.nan, "not unique"
        # left–right check: the right patch searched for in the left image (coarse level)
        u_r = centre[0] - d
        back_hi = min(d_hi, int(np.floor(w - 1 - u_r - size[0] / 2)))
        back = _row_search(cv2, right, left, (u_r, centre[1]), size, level, (d_lo, back_hi), -1)
        if back is None or abs(back[0] - d) > max(self.pixels.left_right, 2**level):
            return np.nan, "left-right"
        # coarse to fine: each level searches ± one sample of the last in samples four times
        # smaller (two pyramid levels down)
        while level > finest:
            step = max(finest, level - 2)
            reach = 2**level
            span = (max(d_lo, int(np.floor(d - reach))), min(d_hi, int(np.ceil(d + reach))))
            fine = _row_search(cv2, left, right, centre, size, step, span, 1)
            if fine is None:
                break
            d, level = fine[0], step
        return float(d), ""


def _level(ratio: float) -> int:
    """The pyramid level whose ``2^level``-pixel samples cut an area by at least ``ratio``."""
    return max(0, math.ceil(0.5 * math.log2(max(ratio, 1.0))))


class _Pyramid:
    """An image as float32 and its halvings (each sample the mean of 2 × 2 of the level
    below), built on demand; a level-``k`` sample ``i`` covers pixels ``[i·2^k, (i+1)·2^k)``."""

    def __init__(self, cv2, image: np.ndarray) -> None:
        self._cv2 = cv2
        self.levels = [image.astype(np.float32)]
        self.image_width = image.shape[1]

    def level(self, k: int) -> tuple[np.ndarray, int]:
        """Level ``k`` (or the smallest one of at least 8 × 8 samples) and its index."""
        while len(self.levels) <= k:
            a = self.levels[-1]
            h, w = a.shape[0] // 2, a.shape[1] // 2
            if min(h, w) < 8:
                break
            a = a[: 2 * h, : 2 * w]
            self.levels.append(self._cv2.resize(a, (w, h), interpolation=self._cv2.INTER_AREA))
        k = min(k, len(self.levels) - 1)
        return self.levels[k], k


def _row_search(
    cv2,
    source: _Pyramid,
    target: _Pyramid,
    centre: tuple[float, float],
    size: tuple[int, int],
    level: int,
    disparities: tuple[int, int],
    direction: int,
) -> tuple[float, float, float, float] | None:
    """Normalised cross-correlation of the ``size`` patch of ``source`` at ``centre`` along
    the same row of ``target``, at pyramid ``level``, over the disparities ``[d_lo, d_hi]``
    (pixels of the full image; the target patch at ``u − direction · d``).

    Returns
    -------
    (d, best, second, texture) or None
        The peak's disparity in pixels (parabola between samples), its correlation, the best
        correlation three samples or more from it (:func:`teamslam.frontend.stereo._best`) and
        the standard deviation of the patch; ``None`` when the range holds fewer than three
        samples.
    """
    image, level = source.level(level)
    other, _ = target.level(level)
    scale = 2**level
    d_lo, d_hi = disparities
    n = int((d_hi - d_lo) // scale)
    if n < 2:
        return None
    d_hi = d_lo + n * scale
    width, height = max(3, round(size[0] / scale)), max(3, round(size[1] / scale))
    # pixel x of the full image is (x − (scale − 1) / 2) / scale at this level
    u = (centre[0] - (scale - 1) / 2) / scale
    v = (centre[1] - (scale - 1) / 2) / scale
    patch = cv2.getRectSubPix(image, (width, height), (u, v))
    middle = (u - direction * (d_lo + d_hi) / (2 * scale), v)
    strip = cv2.getRectSubPix(other, (width + n, height), middle)
    scores = cv2.matchTemplate(strip, patch, cv2.TM_CCOEFF_NORMED).ravel()
    i, offset, second = _best(scores)
    # sample i: the target patch's centre at ``middle − n / 2 + i`` (this level's pixels)
    shift = (i + offset) * scale
    d = d_hi - shift if direction > 0 else d_lo + shift
    return float(d), float(scores[i]), second, float(patch.std())
