"""Numerical rank and nullspace, shared by the planar and the 3D observability analyses."""

from __future__ import annotations

import numpy as np
import scipy.linalg

__all__ = ["nullspace", "rank"]


def rank(matrix: np.ndarray, rtol: float = 1e-9) -> int:
    """Numerical rank: singular values above ``rtol`` times the largest."""
    s = np.linalg.svd(matrix, compute_uv=False)
    return int(np.sum(s > rtol * s[0])) if s.size else 0


def nullspace(matrix: np.ndarray, rtol: float = 1e-9) -> np.ndarray:
    """Orthonormal basis of the right nullspace (the unobservable directions)."""
    return scipy.linalg.null_space(matrix, rcond=rtol)
