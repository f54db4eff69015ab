"""Affine + gain/offset alignment of many small patches at once (Gauss–Newton).

Both the track alignment to a track's first appearance and the stereo alignment of a left
patch in the right image solve, per patch, for a centre ``uv``, a 2×2 warp ``A`` and a gain
and offset ``(g, b)`` minimising the Gaussian-weighted

    Σ_x w(x) · (g · I(uv + A x) + b − T(x))²

over the window's offsets ``x``. The image and its two gradients are sampled by one remap of
a 3-channel image.
"""

from __future__ import annotations

import numpy as np

from teamslam.frontend._cv import require_cv2


class PatchWindow:
    """A square window of ``2·half + 1`` pixels with Gaussian weights (σ = ``half``)."""

    def __init__(self, half: int) -> None:
        g = np.arange(-half, half + 1, dtype=np.float32)
        oy, ox = np.meshgrid(g, g, indexing="ij")
        self.ox, self.oy = ox.ravel(), oy.ravel()
        self.weights = np.exp(-(self.ox**2 + self.oy**2) / (2 * max(half, 1) ** 2)).astype(
            np.float32
        )

    def sample(self, image: np.ndarray, uv: np.ndarray, A: np.ndarray) -> np.ndarray:
        """``image`` (one or more channels) at ``uv + A · offsets``: ``(N, P[, C])``."""
        cv2 = require_cv2()
        A = A.astype(np.float32)
        mx = uv[:, :1].astype(np.float32) + A[:, 0, :1] * self.ox + A[:, 0, 1:] * self.oy
        my = uv[:, 1:].astype(np.float32) + A[:, 1, :1] * self.ox + A[:, 1, 1:] * self.oy
        return cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def with_gradients(image: np.ndarray) -> np.ndarray:
    """A float32 grey image and its Sobel gradients as one 3-channel image (one remap
    samples all three)."""
    cv2 = require_cv2()
    img = image.astype(np.float32)
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    return cv2.merge([img, gx, gy])


def align_patches(
    window: PatchWindow,
    template: np.ndarray,
    image3: np.ndarray,
    uv: np.ndarray,
    A: np.ndarray,
    photo: np.ndarray,
    iterations: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gauss–Newton on every patch at once.

    Parameters
    ----------
    window
        The window (offsets and weights).
    template
        ``(N, P)`` templates.
    image3
        :func:`with_gradients` of the image the templates are looked for in.
    uv, A, photo
        ``(N, 2)`` start centres, ``(N, 2, 2)`` warps, ``(N, 2)`` gains and offsets.
    iterations
        Gauss–Newton steps.

    Returns
    -------
    (uv, A, photo, ncc)
        The aligned parameters and each aligned patch's normalised cross-correlation with
        its template.
    """
    uv = np.asarray(uv, np.float64).copy()
    A, photo = np.asarray(A, np.float64).copy(), np.asarray(photo, np.float64).copy()
    n, p = template.shape
    ox, oy, w = window.ox, window.oy, window.weights
    J = np.empty((n, 8, p), np.float32)  # t_x, t_y, A00, A01, A10, A11, gain, offset
    J[:, 7] = 1.0
    reg = 1e-6 * np.eye(8, dtype=np.float32)
    for _ in range(iterations):
        i_w, gx_w, gy_w = np.moveaxis(window.sample(image3, uv, A), 2, 0)
        gain = photo[:, :1].astype(np.float32)
        r = gain * i_w + photo[:, 1:].astype(np.float32) - template
        np.multiply(gain, gx_w, out=J[:, 0])
        np.multiply(gain, gy_w, out=J[:, 1])
        np.multiply(J[:, 0], ox, out=J[:, 2])
        np.multiply(J[:, 0], oy, out=J[:, 3])
        np.multiply(J[:, 1], ox, out=J[:, 4])
        np.multiply(J[:, 1], oy, out=J[:, 5])
        J[:, 6] = i_w
        Jw = J * w
        H = Jw @ J.transpose(0, 2, 1) + reg
        step = -np.linalg.solve(H, Jw @ r[..., None])[..., 0].astype(np.float64)
        uv += step[:, :2]
        A += step[:, 2:6].reshape(n, 2, 2)
        photo += step[:, 6:8]
    i_w = window.sample(image3, uv, A)[..., 0]
    t = template - template.mean(axis=1, keepdims=True)
    c = i_w - i_w.mean(axis=1, keepdims=True)
    ncc = (t * c).sum(1) / np.sqrt((t * t).sum(1) * (c * c).sum(1) + 1e-12)
    return uv, A, photo, ncc
