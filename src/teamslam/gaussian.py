"""Gaussians in moment and information form, and the two operations consensus is made of.

Distributed-MSCKF paper, §IV-C:

* :func:`replace_marginal` — Proposition 2 (eq. 14): when the marginal of ``y`` in a joint
  ``N(μ, Σ)`` over ``(x, y)`` is replaced by ``N(μ̄ʸ, Σ̄ʸ)`` while the conditional ``p(x | y)``
  is kept, the new joint is ``μ̄ = [A μ̄ʸ + b; μ̄ʸ]``, ``Σ̄ = [[A Σ̄ʸ Aᵀ + P, A Σ̄ʸ], [Σ̄ʸ Aᵀ, Σ̄ʸ]]``
  with ``A = Σˣʸ Σʸ⁻¹``, ``b = μˣ - A μʸ``, ``P = Σˣ - A Σʸˣ``;
* :func:`geometric_average` — Proposition 3 (eq. 15) / eq. 19: the weighted geometric mean
  ``∏ⱼ N(μⱼ, Σⱼ)^{wⱼ}`` (normalised), which in information form is the weighted *sum*
  ``Σ̄⁻¹ = Σⱼ wⱼ Σⱼ⁻¹``, ``Σ̄⁻¹ μ̄ = Σⱼ wⱼ Σⱼ⁻¹ μⱼ``.

Both work on *index sets*, so a caller holding a large joint can average and replace just the
block of its common landmarks. Array-level functions (``*_arrays``) are what the filters call in
their hot paths; :class:`Gaussian` and :class:`InformationGaussian` wrap them for readable code.
Every inverse is done through a Cholesky factorisation; a matrix that is not symmetric positive
definite raises :class:`NotPositiveDefiniteError` naming what was wrong.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.linalg.lapack

__all__ = [
    "Gaussian",
    "InformationGaussian",
    "NotPositiveDefiniteError",
    "geometric_average",
    "geometric_average_arrays",
    "nees",
    "replace_marginal",
    "replace_marginal_arrays",
    "spd_inverse",
    "symmetrize",
]

IndexLike = Sequence[int] | np.ndarray | slice


class NotPositiveDefiniteError(ValueError):
    """A covariance or information matrix that must be symmetric positive definite is not."""


def symmetrize(matrix: np.ndarray) -> np.ndarray:
    """``(M + Mᵀ) / 2`` over the last two axes."""
    matrix = np.asarray(matrix, dtype=float)
    return 0.5 * (matrix + np.swapaxes(matrix, -1, -2))


def _cholesky(matrix: np.ndarray, what: str) -> np.ndarray:
    try:
        return np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError as exc:
        raise NotPositiveDefiniteError(f"{what} is not positive definite") from exc


def spd_inverse(matrix: np.ndarray, what: str = "matrix") -> np.ndarray:
    """Inverse of a symmetric positive-definite matrix (batched) through its Cholesky factor."""
    matrix = symmetrize(matrix)
    if matrix.ndim == 2:
        # LAPACK potrf + potri: the inverse straight from the Cholesky factor
        factor, info = scipy.linalg.lapack.dpotrf(matrix, lower=True, clean=True)
        if info != 0:
            raise NotPositiveDefiniteError(f"{what} is not positive definite")
        inverse, info = scipy.linalg.lapack.dpotri(factor, lower=True)
        if info != 0:
            raise NotPositiveDefiniteError(f"{what} is singular")
        lower_part = np.tril(inverse)
        return lower_part + np.tril(inverse, -1).T
    lower = _cholesky(matrix, what)
    eye = np.broadcast_to(np.eye(matrix.shape[-1]), matrix.shape)
    lower_inv = np.linalg.solve(lower, eye)
    return np.swapaxes(lower_inv, -1, -2) @ lower_inv


def _as_index(index: IndexLike, dim: int, name: str) -> np.ndarray:
    idx = np.arange(dim)[index] if isinstance(index, slice) else np.asarray(index)
    if idx.dtype == bool:
        raise TypeError(f"{name}: boolean masks are not accepted, pass integer indices")
    idx = idx.astype(np.intp, copy=False).ravel()
    if idx.size and (idx.min() < 0 or idx.max() >= dim):
        raise IndexError(f"{name}: indices out of range for dimension {dim}")
    if np.unique(idx).size != idx.size:
        raise IndexError(f"{name}: repeated indices")
    return idx


def _complement(idx: np.ndarray, dim: int) -> np.ndarray:
    mask = np.ones(dim, dtype=bool)
    mask[idx] = False
    return np.flatnonzero(mask)


def _check_moment(mean: np.ndarray, cov: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    mean = np.asarray(mean, dtype=float)
    cov = np.asarray(cov, dtype=float)
    if mean.ndim != 1:
        raise ValueError(f"{what}: mean must be a vector, got shape {mean.shape}")
    if cov.shape != (mean.size, mean.size):
        raise ValueError(
            f"{what}: covariance shape {cov.shape} does not match mean of size {mean.size}"
        )
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
        raise ValueError(f"{what}: mean or covariance contains NaN or infinite values")
    return mean, cov


def replace_marginal_arrays(
    mean: np.ndarray,
    cov: np.ndarray,
    index_y: IndexLike,
    mean_y: np.ndarray,
    cov_y: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Proposition 2 (eq. 14) on arrays: replace the marginal of the ``index_y`` block.

    Parameters
    ----------
    mean, cov
        Joint mean ``(n,)`` and covariance ``(n, n)`` over all variables.
    index_y
        Indices of the block ``y`` whose marginal changes; all other indices form ``x``.
    mean_y, cov_y
        The new marginal ``N(μ̄ʸ, Σ̄ʸ)``.

    Returns
    -------
    new_mean, new_cov
        The joint whose ``y`` marginal is the new one and whose conditional ``p(x | y)`` is the
        old one, computed as the rank-``|y|`` correction ``Σ + G (Σ̄ʸ − Σʸ) Gᵀ`` with
        ``G = Σ[:, y] Σʸ⁻¹``.
    """
    mean, cov = _check_moment(mean, cov, "replace_marginal joint")
    n = mean.size
    iy = _as_index(index_y, n, "replace_marginal index_y")
    mean_y, cov_y = _check_moment(mean_y, cov_y, "replace_marginal new marginal")
    if mean_y.size != iy.size:
        raise ValueError(
            f"replace_marginal: new marginal has size {mean_y.size}, index set has {iy.size}"
        )
    sigma_y = cov[np.ix_(iy, iy)]
    factor = scipy.linalg.cho_factor(_spd(sigma_y, "replace_marginal: old marginal Σʸ"))
    # G = Σ[:, y] Σʸ⁻¹ stacks A (rows of x) over the identity (rows of y), so the whole new
    # joint is one rank-|y| correction: μ̄ = μ + G (μ̄ʸ − μʸ), Σ̄ = Σ + G (Σ̄ʸ − Σʸ) Gᵀ. That is
    # eq. 14 block by block, computed without gathering the x–x block.
    gain = scipy.linalg.cho_solve(factor, cov[iy, :]).T
    gain[iy] = np.eye(iy.size)  # exact identity rows
    new_mean = mean + gain @ (mean_y - mean[iy])
    new_mean[iy] = mean_y
    delta = symmetrize(cov_y) - sigma_y
    new_cov = cov + (gain @ delta) @ gain.T
    new_cov[np.ix_(iy, iy)] = symmetrize(cov_y)
    return new_mean, symmetrize(new_cov)


def _spd(matrix: np.ndarray, what: str) -> np.ndarray:
    matrix = symmetrize(matrix)
    _cholesky(matrix, what)
    return matrix


def geometric_average_arrays(
    means: np.ndarray, covs: np.ndarray, weights: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted geometric average of Gaussians (eq. 15 / 19), batched over the inputs.

    Parameters
    ----------
    means
        ``(k, d)`` means of the ``k`` marginals being averaged.
    covs
        ``(k, d, d)`` covariances.
    weights
        ``(k,)`` non-negative weights summing to one (a row of a doubly-stochastic matrix
        restricted to the neighbours that hold the block).

    Returns
    -------
    mean, cov
        ``Σ̄ = (Σⱼ wⱼ Σⱼ⁻¹)⁻¹`` and ``μ̄ = Σ̄ Σⱼ wⱼ Σⱼ⁻¹ μⱼ``.
    """
    means = np.asarray(means, dtype=float)
    covs = np.asarray(covs, dtype=float)
    weights = np.asarray(weights, dtype=float)
    if means.ndim != 2 or covs.shape != (*means.shape, means.shape[1]):
        raise ValueError(
            f"geometric_average: expected means (k, d) and covs (k, d, d), "
            f"got {means.shape} and {covs.shape}"
        )
    if weights.shape != (means.shape[0],):
        raise ValueError(f"geometric_average: {weights.shape[0]} weights for {len(means)} inputs")
    if np.any(weights < 0) or not np.isclose(weights.sum(), 1.0, atol=1e-9):
        raise ValueError("geometric_average: weights must be non-negative and sum to 1")
    if not (np.all(np.isfinite(means)) and np.all(np.isfinite(covs))):
        raise ValueError("geometric_average: inputs contain NaN or infinite values")
    infos = spd_inverse(covs, "geometric_average: an input covariance")
    info = np.einsum("k,kij->ij", weights, infos)
    info_vector = np.einsum("k,kij,kj->i", weights, infos, means)
    cov = spd_inverse(info, "geometric_average: averaged information")
    return cov @ info_vector, cov


@dataclass(frozen=True)
class Gaussian:
    """A Gaussian in moment form, ``N(mean, cov)``."""

    mean: np.ndarray
    cov: np.ndarray

    def __post_init__(self) -> None:
        mean, cov = _check_moment(self.mean, self.cov, "Gaussian")
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "cov", symmetrize(cov))

    @property
    def dim(self) -> int:
        """Dimension of the variable."""
        return self.mean.size

    def information(self) -> InformationGaussian:
        """The same Gaussian in information form."""
        info = spd_inverse(self.cov, "Gaussian covariance")
        return InformationGaussian(info @ self.mean, info)

    def marginal(self, index: IndexLike) -> Gaussian:
        """Marginal over ``index`` (a sub-block of mean and covariance)."""
        idx = _as_index(index, self.dim, "Gaussian.marginal")
        return Gaussian(self.mean[idx], self.cov[np.ix_(idx, idx)])

    def conditional(self, index_y: IndexLike, value_y: np.ndarray) -> Gaussian:
        """``p(x | y = value_y)`` where ``x`` is every index not in ``index_y``."""
        iy = _as_index(index_y, self.dim, "Gaussian.conditional")
        ix = _complement(iy, self.dim)
        value_y = np.asarray(value_y, dtype=float)
        if value_y.shape != (iy.size,):
            raise ValueError(f"Gaussian.conditional: value has shape {value_y.shape}")
        factor = scipy.linalg.cho_factor(_spd(self.cov[np.ix_(iy, iy)], "Gaussian.conditional: Σʸ"))
        gain = scipy.linalg.cho_solve(factor, self.cov[np.ix_(ix, iy)].T).T
        mean = self.mean[ix] + gain @ (value_y - self.mean[iy])
        cov = self.cov[np.ix_(ix, ix)] - gain @ self.cov[np.ix_(iy, ix)]
        return Gaussian(mean, cov)

    def replace_marginal(self, index_y: IndexLike, new_marginal: Gaussian) -> Gaussian:
        """Proposition 2: keep ``p(x | y)``, make the ``y`` marginal ``new_marginal``."""
        mean, cov = replace_marginal_arrays(
            self.mean, self.cov, index_y, new_marginal.mean, new_marginal.cov
        )
        return Gaussian(mean, cov)

    def sample(self, rng: np.random.Generator, size: int | None = None) -> np.ndarray:
        """Draw samples with a Cholesky factor of the covariance."""
        lower = _cholesky(self.cov, "Gaussian covariance")
        shape = (self.dim,) if size is None else (size, self.dim)
        return self.mean + rng.standard_normal(shape) @ lower.T

    def nees(self, truth: np.ndarray) -> float:
        """Normalised estimation error squared of ``truth`` under this Gaussian."""
        return nees(self.mean, self.cov, truth)


@dataclass(frozen=True)
class InformationGaussian:
    """A Gaussian in information (canonical) form: ``Λ = Σ⁻¹``, ``η = Σ⁻¹ μ``."""

    info_vector: np.ndarray
    info_matrix: np.ndarray

    def __post_init__(self) -> None:
        eta, info = _check_moment(self.info_vector, self.info_matrix, "InformationGaussian")
        object.__setattr__(self, "info_vector", eta)
        object.__setattr__(self, "info_matrix", symmetrize(info))

    @property
    def dim(self) -> int:
        """Dimension of the variable."""
        return self.info_vector.size

    def moment(self) -> Gaussian:
        """The same Gaussian in moment form."""
        factor = scipy.linalg.cho_factor(_spd(self.info_matrix, "information matrix"))
        mean = scipy.linalg.cho_solve(factor, self.info_vector)
        return Gaussian(mean, spd_inverse(self.info_matrix, "information matrix"))

    def marginal(self, index: IndexLike) -> InformationGaussian:
        """Marginal over ``index``: the Schur complement of the other block."""
        iy = _as_index(index, self.dim, "InformationGaussian.marginal")
        ix = _complement(iy, self.dim)
        lam = self.info_matrix
        if ix.size == 0:
            return InformationGaussian(self.info_vector[iy], lam[np.ix_(iy, iy)])
        factor = scipy.linalg.cho_factor(_spd(lam[np.ix_(ix, ix)], "information block Λˣˣ"))
        solved = scipy.linalg.cho_solve(
            factor, np.column_stack([lam[np.ix_(ix, iy)], self.info_vector[ix]])
        )
        info = lam[np.ix_(iy, iy)] - lam[np.ix_(iy, ix)] @ solved[:, :-1]
        eta = self.info_vector[iy] - lam[np.ix_(iy, ix)] @ solved[:, -1]
        return InformationGaussian(eta, info)

    def conditional(self, index_y: IndexLike, value_y: np.ndarray) -> InformationGaussian:
        """``p(x | y = value_y)``: ``Λˣˣ`` and ``ηˣ - Λˣʸ y``."""
        iy = _as_index(index_y, self.dim, "InformationGaussian.conditional")
        ix = _complement(iy, self.dim)
        value_y = np.asarray(value_y, dtype=float)
        lam = self.info_matrix
        return InformationGaussian(
            self.info_vector[ix] - lam[np.ix_(ix, iy)] @ value_y, lam[np.ix_(ix, ix)]
        )


def nees(mean: np.ndarray, cov: np.ndarray, truth: np.ndarray) -> float:
    """Normalised estimation error squared ``(s - μ)ᵀ Σ⁻¹ (s - μ)`` (Cholesky solve)."""
    error = np.asarray(truth, dtype=float) - np.asarray(mean, dtype=float)
    factor = scipy.linalg.cho_factor(_spd(cov, "nees: covariance"))
    return float(error @ scipy.linalg.cho_solve(factor, error))


def replace_marginal(joint: Gaussian, index_y: IndexLike, new_marginal: Gaussian) -> Gaussian:
    """Proposition 2 (eq. 14); see :func:`replace_marginal_arrays`."""
    return joint.replace_marginal(index_y, new_marginal)


def geometric_average(marginals: Sequence[Gaussian], weights: Sequence[float]) -> Gaussian:
    """Weighted geometric average (eq. 15 / 19); see :func:`geometric_average_arrays`."""
    if len(marginals) == 0:
        raise ValueError("geometric_average: no marginals given")
    mean, cov = geometric_average_arrays(
        np.stack([m.mean for m in marginals]),
        np.stack([m.cov for m in marginals]),
        np.asarray(weights, dtype=float),
    )
    return Gaussian(mean, cov)
