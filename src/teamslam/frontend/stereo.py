"""Stereo matching of left-image points on a rectified pair, with an outlier gate.

:func:`match_stereo` searches the right image along the same row over the disparity range by
normalised cross-correlation, refines the peak (parabola, then Lucas–Kanade along the row after
a global gain correction, then with ``stereo_affine_iterations`` an affine warp with gain and
offset, :func:`affine_align`), and rejects a match below ``ncc_min``, not unique, failing the
left–right check, or moved by more than the refine threshold. A tracked point with a known
disparity (``stereo_from_guess``) is followed by pyramidal Lucas–Kanade from it instead, and
rejected when the way back misses, or the match leaves the row or ``guess ± max(3, 20 %)``
pixels, and by the same alignment gate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.frontend._align import PatchWindow, align_patches, with_gradients
from teamslam.frontend._clock import StageClock
from teamslam.frontend._cv import require_cv2
from teamslam.frontend.config import FrontendConfig, PixelSettings

__all__ = ["StereoMatches", "affine_align", "match_stereo"]


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


def affine_align(
    template_image: np.ndarray,
    uv_template: np.ndarray,
    image: np.ndarray,
    uv_start: np.ndarray,
    half: int,
    iterations: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Align patches of ``template_image`` around ``uv_template`` to ``image`` (float32 grey):
    an affine warp plus gain and offset per patch, Gauss–Newton from ``uv_start`` on all
    patches at once (Gaussian-weighted window of ``2·half + 1`` pixels).

    Returns
    -------
    (uv, ncc)
        ``(N, 2)`` aligned centres in ``image`` and the NCC of each aligned patch with its
        template.
    """
    n = len(uv_template)
    window = PatchWindow(half)
    eye = np.tile(np.eye(2), (n, 1, 1))
    template = window.sample(template_image, np.asarray(uv_template, np.float64), eye)
    photo = np.tile([1.0, 0.0], (n, 1))
    uv, A, _, ncc = align_patches(
        window, template, with_gradients(image), uv_start, eye, photo, iterations
    )
    det = np.linalg.det(A)
    ncc = np.where((det > 0.5) & (det < 2.0) & np.all(np.isfinite(uv), axis=1), ncc, -1.0)
    return uv, ncc


def _lk_pair(cv2, a, b, pts, start, win, levels):
    """Pyramidal Lucas–Kanade of ``pts`` in ``a`` into ``b`` from ``start``: ``(out, ok)``."""
    out, status, _ = cv2.calcOpticalFlowPyrLK(
        a,
        b,
        pts.astype(np.float32).reshape(-1, 1, 2),
        start.astype(np.float32).reshape(-1, 1, 2),
        winSize=(win, win),
        maxLevel=levels,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 0.001),
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    return out.reshape(-1, 2).astype(np.float64), status.ravel().astype(bool)


def match_stereo(
    left: np.ndarray,
    right: np.ndarray,
    uv_left: np.ndarray,
    disparity_range: tuple[float, float],
    config: FrontendConfig | None = None,
    pixels: PixelSettings | None = None,
    disparity_guess: np.ndarray | None = None,
    clock: StageClock | None = None,
    left_f: np.ndarray | None = None,
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
        in the previous frame. With ``stereo_from_guess`` (the default) such a point is not
        searched: pyramidal Lucas–Kanade follows it from the guess into the right image and
        back again (the left–right check), and the match must stay within
        ``guess ± max(3, 20 %)`` pixels. Otherwise the NCC search covers only that interval.
    clock
        Where the CPU time of the search, Lucas–Kanade and the alignment is counted.
    left_f
        ``left`` as float32, when the caller has it (converted here otherwise).
    """
    cv2 = require_cv2()
    config = config or FrontendConfig()
    clock = clock or StageClock()
    h, w = left.shape
    px = pixels or config.pixels((w, h))
    uv_left = np.asarray(uv_left, dtype=np.float64).reshape(-1, 2)
    n = len(uv_left)
    r = px.ncc_half
    size = 2 * r + 1
    d_lo = max(0, int(np.floor(disparity_range[0])))
    d_hi_all = int(np.ceil(disparity_range[1]))
    left_f = left.astype(np.float32) if left_f is None else left_f
    right_f = right.astype(np.float32)
    coarse = np.full(n, np.nan)
    searched = np.zeros(n, bool)
    guess = np.full(n, np.nan) if disparity_guess is None else np.asarray(disparity_guess, float)
    u_all, v_all = uv_left[:, 0], uv_left[:, 1]
    inside = (v_all >= r + 1) & (v_all <= h - r - 2) & (u_all >= r + 1) & (u_all <= w - r - 2)
    margin_all = np.maximum(3.0, 0.2 * np.nan_to_num(guess))
    g_lo = np.maximum(d_lo, np.floor(guess - margin_all))
    g_hi = np.minimum(np.minimum(d_hi_all, np.ceil(guess + margin_all)), np.floor(u_all - r - 1))
    with np.errstate(invalid="ignore"):
        predicted = inside & np.isfinite(guess) & (g_hi - g_lo >= 4) & config.stereo_from_guess
    with clock.stage("stereo search"):
        for k in np.flatnonzero(inside & ~predicted):
            u, v = uv_left[k]
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
    searched |= predicted
    uv_right = np.full((n, 2), np.nan)
    accepted = np.zeros(n, bool)
    if not (np.any(np.isfinite(coarse)) or np.any(predicted)):
        return StereoMatches(uv_right, accepted, searched)
    with clock.stage("stereo LK"):
        # global gain/offset correction so Lucas–Kanade (a sum of squared differences) is
        # unbiased (in place: one temporary image, not four)
        gain = left_f.std() / max(float(right_f.std()), 1e-6)
        right_c = right_f - right_f.mean()
        right_c *= gain
        right_c += left_f.mean()
        right_c = np.clip(right_c, 0, 255, out=right_c).astype(np.uint8)
        win = px.lk_window
        outs, oks, idxs, refs = [], [], [], []
        idx = np.flatnonzero(np.isfinite(coarse))
        if idx.size:
            start = uv_left[idx].copy()
            start[:, 0] -= coarse[idx]
            out, ok = _lk_pair(cv2, left, right_c, uv_left[idx], start, win, 0)
            outs.append(out), oks.append(ok), idxs.append(idx), refs.append(start[:, 0])
        idx = np.flatnonzero(predicted)
        if idx.size:
            # a tracked point: followed from its guessed disparity, then back to the left image
            start = uv_left[idx].copy()
            start[:, 0] -= guess[idx]
            levels = config.lk_levels
            out, ok = _lk_pair(cv2, left, right_c, uv_left[idx], start, win, levels)
            back, ok_b = _lk_pair(cv2, right_c, left, out, uv_left[idx], win, levels)
            d = uv_left[idx, 0] - out[:, 0]
            ok &= ok_b & (np.linalg.norm(back - uv_left[idx], axis=1) <= px.left_right)
            ok &= np.abs(out[:, 1] - uv_left[idx, 1]) <= px.refine
            ok &= (d >= g_lo[idx]) & (d <= g_hi[idx])
            outs.append(out), oks.append(ok), idxs.append(idx), refs.append(out[:, 0])
    idx, out, ok = np.concatenate(idxs), np.concatenate(outs), np.concatenate(oks)
    ref = np.concatenate(refs)
    if config.stereo_affine_iterations and idx.size:
        # left and right see a slanted surface with different foreshortening and a
        # different vignetting: align each left patch with an affine warp, gain and offset
        with clock.stage("stereo alignment"):
            aligned, ncc = affine_align(
                left_f, uv_left[idx], right_f, out, win // 2, config.stereo_affine_iterations
            )
        ok &= ncc >= config.ncc_min
        out = aligned
    # the outlier gate: refinement moves the disparity (from the NCC peak, or from the tracked
    # match) and the row by at most the refine threshold
    ok &= (np.abs(out[:, 0] - ref) <= px.refine) & (
        np.abs(out[:, 1] - uv_left[idx, 1]) <= px.refine
    )
    ok &= uv_left[idx, 0] - out[:, 0] > 0
    uv_right[idx[ok]] = out[ok]
    accepted[idx[ok]] = True
    return StereoMatches(uv_right, accepted, searched)
