"""Helpers for checking models: central finite-difference Jacobians on vectors and manifolds.

Every analytic Jacobian in teamslam is checked against :func:`numerical_jacobian` in the test
suite. For a function between manifolds, pass the ``plus``/``minus`` of each side; for poses
under teamslam's right-perturbation convention these are ``T ⊕ δ = T · exp(δ)`` and
``T₁ ⊖ T₂ = log(T₂⁻¹ T₁)`` (:func:`se3_plus`, :func:`se3_minus`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from teamslam.geometry import se3

__all__ = ["numerical_jacobian", "se3_minus", "se3_plus", "vector_minus", "vector_plus"]


def vector_plus(x: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """``x + δ``."""
    return np.asarray(x, dtype=float) + delta


def vector_minus(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a - b``."""
    return np.asarray(a, dtype=float) - np.asarray(b, dtype=float)


def se3_plus(pose: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """``T · exp(δ^)`` (right perturbation)."""
    return pose @ se3.exp(delta)


def se3_minus(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``log(b⁻¹ a)``, the right-perturbation difference."""
    return se3.log(se3.inverse(b) @ a)


def numerical_jacobian(
    f: Callable[[Any], Any],
    x: Any,
    dim: int,
    plus: Callable[[Any, np.ndarray], Any] = vector_plus,
    minus: Callable[[Any, Any], np.ndarray] = vector_minus,
    eps: float = 1e-6,
) -> np.ndarray:
    """Central-difference Jacobian ``∂ (f(x ⊕ δ) ⊖ f(x)) / ∂ δ`` at ``δ = 0``.

    Parameters
    ----------
    f
        The function.
    x
        The point (vector or group element).
    dim
        Dimension of the tangent space at ``x``.
    plus, minus
        ``⊕`` on the input side and ``⊖`` on the output side.
    eps
        Step size.

    Returns
    -------
    numpy.ndarray
        ``(m, dim)`` Jacobian.
    """
    fx = f(x)
    columns = []
    for k in range(dim):
        step = np.zeros(dim)
        step[k] = eps
        forward = minus(f(plus(x, step)), fx)
        backward = minus(f(plus(x, -step)), fx)
        columns.append((np.ravel(forward) - np.ravel(backward)) / (2.0 * eps))
    return np.stack(columns, axis=-1)
