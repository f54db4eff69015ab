"""Stereo matching of left-image points on a rectified pair, with an outlier gate.

For each left point the right image is searched along the same row over the disparity range
(from the depth range and ``fx · b``) by normalised cross-correlation (NCC, insensitive to a
gain and offset between the cameras); the integer peak is refined by a parabola. A match is
rejected when

* its NCC is below ``ncc_min``;
* it is not unique: the best NCC more than two pixels away from the peak reaches
  ``uniqueness`` times the peak;
* the left–right check fails: searching the left image for the right patch does not return to
  the left point (an occlusion, or a repeated pattern);
* Lucas–Kanade refinement along the row (after a global gain correction of the right image)
  moves the disparity, or the row, by more than the refine threshold.

The accepted match is the Lucas–Kanade refined position ``(u_r, v_r)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.frontend._cv import require_cv2
from teamslam.frontend.config import FrontendConfig, PixelSettings

__all__ = ["StereoMatches", "match_stereo"]


@dataclass(frozen=True)
class StereoMatches:
    """Result of :func:`match_stereo`.

    Attributes
    ----------
    uv_right
        ``(N, 2)`` right-image positions (NaN where rejected).
    accepted
        ``(N,)`` accepted matches.
    searched
        ``(N,)`` points for which a search was possible (inside the image with the window and
        some disparity range); ``searched & ~accepted`` were rejected by the gate.
    """

    uv_right: np.ndarray
    accepted: np.ndarray
    searched: np.ndarray


def _best(scores: np.ndarray) -> tuple[int, float, float]:
    """Peak index, sub-pixel offset (parabola) and the best score away from the peak."""
    i = int(scores.argmax())
    n = scores.size
    offset = 0.0
    if 0 < i < n - 1:
        a, b, c = float(scores[i - 1]), float(scores[i]), float(scores[i + 1])
        den = a - 2 * b + c
        if den < 0:
            offset = min(0.5, max(-0.5, 0.5 * (a - c) / den))
    second = -1.0
    if i > 2:
        second = float(scores[: i - 2].max())
    if i + 3 < n:
        second = max(second, float(scores[i + 3 :].max()))
    return i, offset, second


def match_stereo(
    left: np.ndarray,
    right: np.ndarray,
    uv_left: np.ndarray,
    disparity_range: tuple[float, float],
    config: FrontendConfig | None = None,
    pixels: PixelSettings | None = None,
    disparity_guess: np.ndarray | None = None,
) -> StereoMatches:
    """Match left-image points into the right image of a rectified 8-bit grey pair.

    Parameters
    ----------
    left, right
        Rectified grey images (same size).
    uv_left
        ``(N, 2)`` left points.
    disparity_range
        ``(least, largest)`` disparity searched, pixels (see
        :meth:`FrontendConfig.disparity_range`).
    config, pixels
        Settings (``pixels`` defaults to ``config.pixels(image size)``).
    disparity_guess
        Optional ``(N,)`` expected disparities (NaN where unknown), e.g. a track's disparity
        in the previous frame: the search then covers only ``guess ± max(3, 20 %)`` pixels.
    """
    cv2 = require_cv2()
    config = config or FrontendConfig()
    h, w = left.shape
    px = pixels or config.pixels((w, h))
    uv_left = np.asarray(uv_left, dtype=np.float64).reshape(-1, 2)
    n = len(uv_left)
    r = px.ncc_half
    size = 2 * r + 1
    d_lo = max(0, int(np.floor(disparity_range[0])))
    d_hi_all = int(np.ceil(disparity_range[1]))
    left_f = left.astype(np.float32)
    right_f = right.astype(np.float32)
    coarse = np.full(n, np.nan)
    searched = np.zeros(n, bool)
    guess = np.full(n, np.nan) if disparity_guess is None else np.asarray(disparity_guess, float)
    for k, (u, v) in enumerate(uv_left):
        if not (r + 1 <= v <= h - r - 2 and r + 1 <= u <= w - r - 2):
            continue
        d_lo_k, d_hi_k = d_lo, d_hi_all
        if np.isfinite(guess[k]):
            margin = max(3.0, 0.2 * guess[k])
            d_lo_k = max(d_lo, int(np.floor(guess[k] - margin)))
            d_hi_k = min(d_hi_all, int(np.ceil(guess[k] + margin)))
        d_hi = min(d_hi_k, int(np.floor(u - r - 1)))
        if d_hi - d_lo_k < 4:
            continue
        searched[k] = True
        patch = cv2.getRectSubPix(left_f, (size, size), (float(u), float(v)))
        span = d_hi - d_lo_k
        centre = (float(u - (d_lo_k + d_hi) / 2.0), float(v))
        strip = cv2.getRectSubPix(right_f, (size + span, size), centre)
        scores = cv2.matchTemplate(strip, patch, cv2.TM_CCOEFF_NORMED).ravel()
        i, off, second = _best(scores)
        best = scores[i]
        if best < config.ncc_min or second >= config.uniqueness * best:
            continue
        d = d_hi - (i + off)
        # left-right check: the right patch searched for in the left image
        u_r = u - d
        back_hi = min(d_hi_k, int(np.floor(w - 2 - r - u_r)))
        if back_hi - d_lo_k < 4:
            continue
        patch_r = cv2.getRectSubPix(right_f, (size, size), (float(u_r), float(v)))
        centre_l = (float(u_r + (d_lo_k + back_hi) / 2.0), float(v))
        strip_l = cv2.getRectSubPix(left_f, (size + back_hi - d_lo_k, size), centre_l)
        scores_l = cv2.matchTemplate(strip_l, patch_r, cv2.TM_CCOEFF_NORMED).ravel()
        j, off_l, _ = _best(scores_l)
        d_back = d_lo_k + j + off_l
        if abs(d_back - d) > px.left_right:
            continue
        coarse[k] = d
    accepted = np.isfinite(coarse)
    uv_right = np.full((n, 2), np.nan)
    if np.any(accepted):
        idx = np.flatnonzero(accepted)
        # global gain/offset correction so Lucas–Kanade (a sum of squared differences) is unbiased
        gain = left_f.std() / max(float(right_f.std()), 1e-6)
        right_c = np.clip((right_f - right_f.mean()) * gain + left_f.mean(), 0, 255)
        right_c = right_c.astype(np.uint8)
        start = uv_left[idx].copy()
        start[:, 0] -= coarse[idx]
        win = px.lk_window
        out, status, _ = cv2.calcOpticalFlowPyrLK(
            left,
            right_c,
            uv_left[idx].astype(np.float32).reshape(-1, 1, 2),
            start.astype(np.float32).reshape(-1, 1, 2),
            winSize=(win, win),
            maxLevel=0,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 0.001),
            flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
        )
        out = out.reshape(-1, 2).astype(np.float64)
        ok = (
            status.ravel().astype(bool)
            & (np.abs(out[:, 0] - start[:, 0]) <= px.refine)
            & (np.abs(out[:, 1] - uv_left[idx, 1]) <= px.refine)
            & (uv_left[idx, 0] - out[:, 0] > 0)
        )
        uv_right[idx[ok]] = out[ok]
        accepted[idx[~ok]] = False
    return StereoMatches(uv_right, accepted, searched)
