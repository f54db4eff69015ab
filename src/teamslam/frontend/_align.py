"""Affine + gain/offset alignment of many small patches at once (Gauss–Newton, compiled).

Per patch, solves for a centre ``uv``, a 2×2 warp ``A``, gain ``g`` and offset ``b`` minimising
``Σ_x w(x) · (g · I(uv + A x) + b − T(x))²`` with Gaussian weights ``w``: bilinear sampling of
the image and its Sobel gradients (border replicated), normal equations
``(JᵀWJ + 10⁻⁶ I) δ = −JᵀW r`` solved by Cholesky, every step of every patch in one compiled
call (numba).
"""

from __future__ import annotations

import numba
import numpy as np

from teamslam.errors import InputError
from teamslam.frontend._cv import require_cv2

__all__ = ["PatchWindow", "align_patches", "with_gradients"]

# reassociation lets the compiler vectorise the sums over a window's pixels; NaN and
# infinity keep their meaning (the finiteness checks below must not be folded away)
_SUMS = {"reassoc", "contract"}


@numba.njit(cache=True, error_model="numpy", fastmath=_SUMS)
def _bilinear_taps(
    x: float, y: float, width: int, height: int, inside: bool
) -> tuple[int, int, float, float]:
    """Top-left tap and fractions of a bilinear sample at ``(x, y)``, border replicated
    (the coordinate clamped to the image: exact for a replicated border); ``inside``: the
    point is known to lie inside the image by half a pixel, nothing to clamp."""
    if inside:
        x0, y0 = int(x), int(y)
        return np.uintp(x0), np.uintp(y0), x - x0, y - y0
    x = min(max(x, 0.0), width - 1.0)
    y = min(max(y, 0.0), height - 1.0)
    x0 = min(int(x), width - 2)
    y0 = min(int(y), height - 2)
    # unsigned: the indices are never negative, so no wrap-around test at each access
    return np.uintp(x0), np.uintp(y0), x - x0, y - y0


@numba.njit(cache=True, error_model="numpy", fastmath=_SUMS)
def _bilinear_value(image: np.ndarray, x0: int, y0: int, fx: float, fy: float) -> float:
    """The bilinear sample of ``image`` at the taps of :func:`_bilinear_taps`."""
    top = (1 - fx) * image[y0, x0] + fx * image[y0, x0 + 1]
    bottom = (1 - fx) * image[y0 + 1, x0] + fx * image[y0 + 1, x0 + 1]
    return (1 - fy) * top + fy * bottom


@numba.njit(cache=True, error_model="numpy", fastmath=_SUMS)
def _window_inside(
    u: float,
    v: float,
    a00: float,
    a01: float,
    a10: float,
    a11: float,
    half: float,
    width: int,
    height: int,
) -> bool:
    """Whether the window of offsets up to ``half`` warped by ``A`` about ``(u, v)`` lies
    inside the image by half a pixel (its extremes are at the window's corners)."""
    ex = (abs(a00) + abs(a01)) * half
    ey = (abs(a10) + abs(a11)) * half
    return u - ex >= 0.5 and u + ex <= width - 1.5 and v - ey >= 0.5 and v + ey <= height - 1.5


@numba.njit(cache=True, error_model="numpy", fastmath=_SUMS)
def _sample_patches(
    image: np.ndarray, uv: np.ndarray, A: np.ndarray, ox: np.ndarray, oy: np.ndarray
) -> np.ndarray:
    n, p = uv.shape[0], ox.size
    height, width = image.shape
    out = np.empty((n, p), np.float32)
    half = np.abs(ox).max()
    for k in range(n):
        u, v = uv[k, 0], uv[k, 1]
        a00, a01, a10, a11 = A[k, 0, 0], A[k, 0, 1], A[k, 1, 0], A[k, 1, 1]
        if not (np.isfinite(u) and np.isfinite(v) and np.isfinite(a00 + a01 + a10 + a11)):
            out[k] = np.nan
            continue
        inside = _window_inside(u, v, a00, a01, a10, a11, half, width, height)
        for q in range(p):
            x0, y0, fx, fy = _bilinear_taps(
                u + a00 * ox[q] + a01 * oy[q], v + a10 * ox[q] + a11 * oy[q], width, height, inside
            )
            out[k, q] = _bilinear_value(image, x0, y0, fx, fy)
    return out


@numba.njit(cache=True, error_model="numpy", fastmath=_SUMS)
def _gauss_newton(
    template: np.ndarray,
    image: np.ndarray,
    grad_x: np.ndarray,
    grad_y: np.ndarray,
    ox: np.ndarray,
    oy: np.ndarray,
    weights: np.ndarray,
    uv: np.ndarray,
    A: np.ndarray,
    photo: np.ndarray,
    iterations: int,
) -> np.ndarray:
    """Gauss–Newton on every patch, ``uv``, ``A`` and ``photo`` updated in place; returns
    each aligned patch's NCC with its template (−1 where a patch diverged)."""
    n, p = template.shape
    height, width = image.shape
    # rows of √w·J (t_x, t_y, A00, A01, A10, A11, gain, offset) and √w·r over the window
    J = np.empty((8, p))
    r = np.empty(p)
    root_w = np.sqrt(weights)
    half = np.abs(ox).max()
    H = np.empty((8, 8))
    step = np.empty(8)
    ncc = np.full(n, -1.0)
    for k in range(n):
        for it in range(iterations + 1):
            u, v = uv[k, 0], uv[k, 1]
            a00, a01, a10, a11 = A[k, 0, 0], A[k, 0, 1], A[k, 1, 0], A[k, 1, 1]
            gain, offset = photo[k, 0], photo[k, 1]
            if not np.isfinite(u + v + a00 + a01 + a10 + a11 + gain + offset):
                uv[k, 0] = uv[k, 1] = np.nan
                break
            inside = _window_inside(u, v, a00, a01, a10, a11, half, width, height)
            if it == iterations:  # the aligned patch's NCC with its template
                s_t = s_c = s_tt = s_cc = s_tc = 0.0
                for q in range(p):
                    x0, y0, fx, fy = _bilinear_taps(
                        u + a00 * ox[q] + a01 * oy[q],
                        v + a10 * ox[q] + a11 * oy[q],
                        width,
                        height,
                        inside,
                    )
                    c = _bilinear_value(image, x0, y0, fx, fy)
                    t = template[k, q]
                    s_t += t
                    s_c += c
                    s_tt += t * t
                    s_cc += c * c
                    s_tc += t * c
                var_t = max(s_tt - s_t * s_t / p, 0.0)
                var_c = max(s_cc - s_c * s_c / p, 0.0)
                ncc[k] = (s_tc - s_t * s_c / p) / np.sqrt(var_t * var_c + 1e-12)
                break
            for q in range(p):
                x0, y0, fx, fy = _bilinear_taps(
                    u + a00 * ox[q] + a01 * oy[q],
                    v + a10 * ox[q] + a11 * oy[q],
                    width,
                    height,
                    inside,
                )
                w00, w01 = (1 - fx) * (1 - fy), fx * (1 - fy)
                w10, w11 = (1 - fx) * fy, fx * fy
                i_w = (
                    w00 * image[y0, x0]
                    + w01 * image[y0, x0 + 1]
                    + w10 * image[y0 + 1, x0]
                    + w11 * image[y0 + 1, x0 + 1]
                )
                gx_w = gain * (
                    w00 * grad_x[y0, x0]
                    + w01 * grad_x[y0, x0 + 1]
                    + w10 * grad_x[y0 + 1, x0]
                    + w11 * grad_x[y0 + 1, x0 + 1]
                )
                gy_w = gain * (
                    w00 * grad_y[y0, x0]
                    + w01 * grad_y[y0, x0 + 1]
                    + w10 * grad_y[y0 + 1, x0]
                    + w11 * grad_y[y0 + 1, x0 + 1]
                )
                sw = root_w[q]
                r[q] = sw * (gain * i_w + offset - template[k, q])
                gx_w, gy_w = sw * gx_w, sw * gy_w
                J[0, q], J[1, q] = gx_w, gy_w
                J[2, q], J[3, q] = gx_w * ox[q], gx_w * oy[q]
                J[4, q], J[5, q] = gy_w * ox[q], gy_w * oy[q]
                J[6, q], J[7, q] = sw * i_w, sw
            for a in range(8):
                s = 0.0
                for q in range(p):
                    s += J[a, q] * r[q]
                step[a] = -s
                for b in range(a, 8):
                    s = 0.0
                    for q in range(p):
                        s += J[a, q] * J[b, q]
                    H[a, b] = s
                H[a, a] += 1e-6
            # Cholesky H = L Lᵀ in the lower triangle, then L Lᵀ δ = step
            ok = True
            for a in range(8):
                for b in range(a + 1):
                    s = H[b, a]
                    for c in range(b):
                        s -= H[a, c] * H[b, c]
                    if a == b:
                        if not s > 0.0:
                            ok = False
                            break
                        H[a, a] = np.sqrt(s)
                    else:
                        H[a, b] = s / H[b, b]
                if not ok:
                    break
            if not ok:
                uv[k, 0] = uv[k, 1] = np.nan
                break
            for a in range(8):
                s = step[a]
                for c in range(a):
                    s -= H[a, c] * step[c]
                step[a] = s / H[a, a]
            for a in range(7, -1, -1):
                s = step[a]
                for c in range(a + 1, 8):
                    s -= H[c, a] * step[c]
                step[a] = s / H[a, a]
            uv[k, 0] += step[0]
            uv[k, 1] += step[1]
            A[k, 0, 0] += step[2]
            A[k, 0, 1] += step[3]
            A[k, 1, 0] += step[4]
            A[k, 1, 1] += step[5]
            photo[k, 0] += step[6]
            photo[k, 1] += step[7]
    return ncc


class PatchWindow:
    """A square window of ``2·half + 1`` pixels with Gaussian weights (σ = ``half``)."""

    def __init__(self, half: int) -> None:
        g = np.arange(-half, half + 1, dtype=np.float64)
        oy, ox = np.meshgrid(g, g, indexing="ij")
        self.ox, self.oy = ox.ravel(), oy.ravel()
        self.weights = np.exp(-(self.ox**2 + self.oy**2) / (2 * max(half, 1) ** 2))

    def sample(self, image: np.ndarray, uv: np.ndarray, A: np.ndarray) -> np.ndarray:
        """A grey ``image`` sampled bilinearly (border replicated) at ``uv + A · offsets``:
        ``(N, P)`` float32."""
        _check_image(image)
        return _sample_patches(
            np.ascontiguousarray(image, np.float32),
            np.ascontiguousarray(uv, np.float64).reshape(-1, 2),
            np.ascontiguousarray(A, np.float64).reshape(-1, 2, 2),
            self.ox,
            self.oy,
        )


def _check_image(image: np.ndarray, *gradients: np.ndarray) -> None:
    """The compiled sampling reads without bounds checks: a grey image of at least 2×2 pixels,
    and gradients of its shape."""
    image = np.asarray(image)
    if image.ndim != 2 or image.shape[0] < 2 or image.shape[1] < 2:
        raise InputError(
            f"patch alignment needs a grey image of at least 2×2 pixels: {image.shape}"
        )
    for gradient in gradients:
        if np.shape(gradient) != image.shape:
            raise InputError(
                f"patch alignment: a gradient of shape {np.shape(gradient)} for an image of "
                f"{image.shape}"
            )


def with_gradients(image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A float32 grey image and its Sobel gradients (per pixel of offset)."""
    cv2 = require_cv2()
    img = np.ascontiguousarray(image, np.float32)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    return img, gx, gy


def align_patches(
    window: PatchWindow,
    template: np.ndarray,
    gradients: tuple[np.ndarray, np.ndarray, np.ndarray],
    uv: np.ndarray,
    A: np.ndarray,
    photo: np.ndarray,
    iterations: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gauss–Newton on every patch (one compiled call).

    Parameters
    ----------
    window
        The window (offsets and weights).
    template
        ``(N, P)`` templates.
    gradients
        :func:`with_gradients` of the image the templates are looked for in.
    uv, A, photo
        ``(N, 2)`` start centres, ``(N, 2, 2)`` warps, ``(N, 2)`` gains and offsets.
    iterations
        Gauss–Newton steps.

    Returns
    -------
    (uv, A, photo, ncc)
        The aligned parameters and each aligned patch's normalised cross-correlation with
        its template (NaN centres and an NCC of −1 where a patch's steps diverged).
    """
    image, grad_x, grad_y = gradients
    _check_image(image, grad_x, grad_y)
    uv = np.array(uv, np.float64).reshape(-1, 2)
    A = np.array(A, np.float64).reshape(-1, 2, 2)
    photo = np.array(photo, np.float64).reshape(-1, 2)
    template = np.ascontiguousarray(template, np.float32)
    if template.shape != (len(uv), window.ox.size) or len(A) != len(uv) or len(photo) != len(uv):
        raise InputError(
            f"patch alignment: {template.shape} templates for {len(uv)} centres, {len(A)} "
            f"warps and {len(photo)} gains; a window of {window.ox.size} pixels"
        )
    ncc = _gauss_newton(
        template,
        image,
        grad_x,
        grad_y,
        window.ox,
        window.oy,
        window.weights,
        uv,
        A,
        photo,
        int(iterations),
    )
    return uv, A, photo, ncc
