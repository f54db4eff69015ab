"""Closed-form alignment of corresponding point sets: rigid or similarity, weighted, batched.

:func:`align` finds the rotation ``R``, translation ``t`` and (optionally) scale ``s``
minimising ``Σ_i w_i ‖y_i − (s R x_i + t)‖²`` (Horn, JOSA A 4(4), 1987; Umeyama, IEEE TPAMI
13(4), 1991): the SVD of the weighted cross-covariance, its last axis turned when needed so that
``R`` is a rotation, never a reflection. Points are ``(..., n, 3)``, weights ``(..., n)`` (equal
when omitted). Degenerate sets (collinear or coincident points) are not refused here: the
singular values are returned so that a caller can refuse them in its own terms.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from teamslam.errors import InputError

__all__ = ["Alignment", "align"]


class Alignment(NamedTuple):
    """``x ↦ s R x + t`` for each set of a batch.

    Attributes
    ----------
    rotation
        ``(..., 3, 3)`` rotations ``R``.
    translation
        ``(..., 3)`` translations ``t``.
    scale
        ``(...)`` scales ``s`` (exactly 1 for a rigid alignment).
    singular_values
        ``(..., 3)`` singular values of the weighted cross-covariance, descending: a second
        one near zero means collinear points (the rotation about their line is free).
    """

    rotation: np.ndarray
    translation: np.ndarray
    scale: np.ndarray
    singular_values: np.ndarray


def align(
    source: np.ndarray,
    target: np.ndarray,
    weights: np.ndarray | None = None,
    with_scale: bool = False,
) -> Alignment:
    """The rigid (or similarity) transform taking ``source`` points onto ``target`` points.

    With ``w`` the weights normalised to sum to one, ``μ`` the weighted centroids and
    ``H = Σ_i w_i (x_i − μ_x)(y_i − μ_y)ᵀ = U D Vᵀ``: ``R = V diag(1, 1, det(V Uᵀ)) Uᵀ``,
    ``s = tr(D S) / Σ_i w_i ‖x_i − μ_x‖²`` (1 without scale) and ``t = μ_y − s R μ_x``.

    Parameters
    ----------
    source, target
        ``(..., n, 3)`` corresponding points ``x_i`` and ``y_i``.
    weights
        ``(..., n)`` positive weights ``w_i`` (any scale); equal weights when ``None``.
    with_scale
        Estimate the scale ``s`` (Sim(3)); otherwise ``s = 1`` (SE(3)).

    Returns
    -------
    Alignment
        ``R``, ``t``, ``s`` and the singular values of ``H``.
    """
    x = np.asarray(source, dtype=float)
    y = np.asarray(target, dtype=float)
    if x.shape != y.shape or x.ndim < 2 or x.shape[-1] != 3:
        raise InputError(f"alignment needs two (..., n, 3) point sets, got {x.shape} and {y.shape}")
    w = np.ones(x.shape[:-1]) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != x.shape[:-1]:
        raise InputError(f"alignment weights must be {x.shape[:-1]}, got {w.shape}")
    w = (w / w.sum(axis=-1, keepdims=True))[..., None, :]  # (..., 1, n)
    mu_x = (w @ x)[..., 0, :]
    mu_y = (w @ y)[..., 0, :]
    dx = x - mu_x[..., None, :]
    h = np.swapaxes(dx, -1, -2) @ ((y - mu_y[..., None, :]) * np.swapaxes(w, -1, -2))
    u, singular, vt = np.linalg.svd(h)
    v = np.swapaxes(vt, -1, -2)
    d = np.sign(np.linalg.det(v @ np.swapaxes(u, -1, -2)))
    d = np.where(d == 0, 1.0, d)
    fix = np.broadcast_to(np.eye(3), h.shape).copy()
    fix[..., 2, 2] = d
    rotation = v @ fix @ np.swapaxes(u, -1, -2)
    scale = np.ones(h.shape[:-2])
    if with_scale:
        spread = np.sum(w[..., 0, :] * np.sum(dx**2, axis=-1), axis=-1)
        turned = singular[..., 0] + singular[..., 1] + d * singular[..., 2]
        scale = turned / np.maximum(spread, np.finfo(float).tiny)
    translation = mu_y - scale[..., None] * (rotation @ mu_x[..., None])[..., 0]
    return Alignment(rotation, translation, scale, singular)
