"""Kalman filtering blocks: prediction, update, and the update with correlated noise (App. C).

:func:`kalman_update` is Gaussian conditioning of the predicted state on ``z`` with motion and
observation noise correlated by ``S = E[w_{t-1} v_tᵀ]`` (eqs. 65–67; ``S = 0``: the standard
update), ``S`` of shape ``(n, m)`` in the state space. See the concept page *Consensus*
(``docs/concepts/consensus.md``).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

from teamslam.errors import InputError
from teamslam.gaussian import NotPositiveDefiniteError, symmetrize

__all__ = ["kalman_predict", "kalman_update"]


def kalman_predict(
    mean: np.ndarray,
    cov: np.ndarray,
    transition: np.ndarray,
    process_cov: np.ndarray,
    control: np.ndarray | None = None,
    control_matrix: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Propagate ``s_t = F s_{t-1} + G u + w``, ``w ~ N(0, W)``.

    Returns
    -------
    mean, cov
        ``F μ + G u`` and ``F Σ Fᵀ + W``.
    """
    mean = transition @ mean
    if control is not None:
        mean = mean + (control if control_matrix is None else control_matrix @ control)
    return mean, symmetrize(transition @ cov @ transition.T + process_cov)


def kalman_update(
    mean: np.ndarray,
    cov: np.ndarray,
    observation_matrix: np.ndarray,
    observation: np.ndarray,
    observation_cov: np.ndarray,
    correlation: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update, with optional motion/observation noise correlation (eqs. 65–67).

    Parameters
    ----------
    mean, cov
        Predicted ``μ⁺`` ``(n,)`` and ``Σ⁺`` ``(n, n)``.
    observation_matrix
        ``H`` ``(m, n)``.
    observation
        ``z`` ``(m,)``.
    observation_cov
        ``V`` ``(m, m)``.
    correlation
        ``S = E[w vᵀ]`` ``(n, m)``; ``None`` means zero.

    Returns
    -------
    mean, cov
        The posterior. The innovation covariance is factored by Cholesky, never inverted.
    """
    h = np.asarray(observation_matrix, dtype=float)
    z = np.asarray(observation, dtype=float)
    if h.ndim != 2 or h.shape[1] != mean.size or z.shape != (h.shape[0],):
        raise InputError(
            f"kalman_update: H {h.shape}, z {z.shape} do not fit a state of size {mean.size}"
        )
    cross = cov @ h.T  # Cov(s, z) = Σ⁺ Hᵀ + S
    innovation_cov = h @ cross + observation_cov
    if correlation is not None:
        s = np.asarray(correlation, dtype=float)
        if s.shape != (mean.size, h.shape[0]):
            raise InputError(f"kalman_update: correlation S has shape {s.shape}")
        cross = cross + s
        hs = h @ s
        innovation_cov = innovation_cov + hs + hs.T
    try:
        factor = scipy.linalg.cho_factor(symmetrize(innovation_cov))
    except np.linalg.LinAlgError as exc:
        raise NotPositiveDefiniteError("innovation covariance is not positive definite") from exc
    gain = scipy.linalg.cho_solve(factor, cross.T).T
    new_mean = mean + gain @ (z - h @ mean)
    new_cov = cov - gain @ cross.T  # (I - K H) Σ⁺ - K Sᵀ
    return new_mean, symmetrize(new_cov)
