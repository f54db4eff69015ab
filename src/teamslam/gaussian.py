"""Gaussians in moment and information form, and the two operations consensus is made of.

:func:`replace_marginal` is Proposition 2 (eq. 14): replace the marginal of ``y`` in a joint over
``(x, y)`` while keeping ``p(x | y)``; :func:`geometric_average` is Proposition 3 (eq. 15) /
eq. 19: the weighted geometric mean of Gaussians, a weighted sum in information form. Both work
on index sets; the ``*_arrays`` functions serve the filters' hot paths, :class:`Gaussian` and
:class:`InformationGaussian` wrap them. Every inverse goes through a Cholesky factorisation; a
matrix that is not symmetric positive definite raises :class:`NotPositiveDefiniteError`.
Equations: the concept page *Consensus* (``docs/concepts/consensus.md``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.linalg
import scipy.linalg.lapack

from teamslam.errors import EstimationError, InputError

__all__ = [
    "Gaussian",
    "InformationGaussian",
    "NotPositiveDefiniteError",
    "add_weighted_difference",
    "average_common_marginal",
    "chi2_band",
    "chi2_quantile",
    "completed_geometric_average",
    "geometric_average",
    "geometric_average_arrays",
    "kl_divergence",
    "log_chi2_std",
    "nees",
    "replace_marginal",
    "replace_marginal_arrays",
    "replace_marginal_shift",
    "robust_std",
    "spd_inverse",
    "symmetrize",
]

IndexLike = Sequence[int] | np.ndarray | slice


@lru_cache(maxsize=1024)
def chi2_quantile(probability: float, dof: int) -> float:
    """The ``probability`` quantile of χ²(``dof``), computed once per pair of values (gates ask
    for the same few thresholds at every call)."""
    from scipy import stats

    return float(stats.chi2.ppf(probability, dof))


@lru_cache(maxsize=64)
def log_chi2_std(dof: int) -> float:
    """The standard deviation of ``log`` of a χ²(``dof``) variable, ``√ψ′(dof / 2)`` (the
    logarithm of a Gamma variable): how far one ``d²`` lies from another of the same kind, in
    the logarithm."""
    from scipy import special

    return float(np.sqrt(special.polygamma(1, 0.5 * dof)))


def robust_std(x: np.ndarray, axis: int = 0) -> np.ndarray:
    """1.4826 × median absolute deviation (the std of a Gaussian), robust to outliers."""
    med = np.median(x, axis=axis, keepdims=True)
    return 1.4826 * np.median(np.abs(x - med), axis=axis)


def chi2_band(dof: int, samples: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided band of the *average NEES normalised by dof* over ``samples`` samples.

    ``samples · dof · NEES`` is χ²(samples · dof) for a consistent filter.
    """
    from scipy import stats

    total = samples * dof
    lo, hi = stats.chi2.ppf([(1 - probability) / 2, (1 + probability) / 2], total)
    return float(lo / total), float(hi / total)


class NotPositiveDefiniteError(EstimationError, ValueError):
    """A covariance or information matrix that must be symmetric positive definite is not.

    An :class:`~teamslam.errors.EstimationError` (a filter that lost positive definiteness has
    failed, not been misused); also a ``ValueError`` for callers that validate inputs with it.
    """


def symmetrize(matrix: np.ndarray) -> np.ndarray:
    """``(M + Mᵀ) / 2`` over the last two axes."""
    matrix = np.asarray(matrix, dtype=float)
    return 0.5 * (matrix + np.swapaxes(matrix, -1, -2))


def _cholesky(matrix: np.ndarray, what: str) -> np.ndarray:
    try:
        return np.linalg.cholesky(matrix)
    except np.linalg.LinAlgError as exc:
        raise NotPositiveDefiniteError(f"{what} is not positive definite") from exc


def spd_inverse(matrix: np.ndarray, what: str = "matrix", symmetric: bool = False) -> np.ndarray:
    """Inverse of a symmetric positive-definite matrix (batched) through its Cholesky factor.

    The matrix's symmetric part is inverted; ``symmetric`` says that ``matrix`` is exactly
    that already (e.g. a block gathered with its symmetric part), so no pass makes it.
    """
    matrix = np.asarray(matrix, dtype=float) if symmetric else symmetrize(matrix)
    if matrix.ndim == 2:
        # LAPACK potrf + potri: the inverse straight from the Cholesky factor
        factor, info = scipy.linalg.lapack.dpotrf(matrix, lower=True, clean=True)
        if info != 0:
            raise NotPositiveDefiniteError(f"{what} is not positive definite")
        inverse, info = scipy.linalg.lapack.dpotri(factor, lower=True, overwrite_c=True)
        if info != 0:
            raise NotPositiveDefiniteError(f"{what} is singular")
        # potri fills the lower triangle; the upper one is still the factor's zeros
        diagonal = inverse.diagonal().copy()
        inverse += inverse.T
        inverse.flat[:: inverse.shape[0] + 1] = diagonal
        return inverse
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
        raise InputError(f"{what}: mean must be a vector, got shape {mean.shape}")
    if cov.shape != (mean.size, mean.size):
        raise InputError(
            f"{what}: covariance shape {cov.shape} does not match mean of size {mean.size}"
        )
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
        raise InputError(f"{what}: mean or covariance contains NaN or infinite values")
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
        old one (:func:`replace_marginal_shift`).
    """
    mean, cov = _check_moment(mean, cov, "replace_marginal joint")
    n = mean.size
    iy = _as_index(index_y, n, "replace_marginal index_y")
    mean_y, cov_y = _check_moment(mean_y, cov_y, "replace_marginal new marginal")
    if mean_y.size != iy.size:
        raise InputError(
            f"replace_marginal: new marginal has size {mean_y.size}, index set has {iy.size}"
        )
    shift, new_cov = replace_marginal_shift(symmetrize(cov), iy, mean_y - mean[iy], cov_y)
    new_mean = mean + shift
    new_mean[iy] = mean_y
    return new_mean, new_cov


def replace_marginal_shift(
    cov: np.ndarray,
    index_y: np.ndarray,
    shift_y: np.ndarray,
    cov_y: np.ndarray,
    info_y: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Proposition 2 (eq. 14) as a shift of the joint mean and a new covariance.

    With ``A = Σˣʸ Σʸ⁻¹`` the new joint is ``μ̄ = μ + [A δ; δ]`` (``δ = μ̄ʸ − μʸ``) and
    ``Σ̄ʸ``, ``Σ̄ˣʸ = A Σ̄ʸ``, ``Σ̄ˣ = Σˣ + A (Σ̄ʸ − Σʸ) Aᵀ``. Two equivalent ways, the cheaper
    one is taken:

    * ``y`` at least as large as ``x``: block by block, ``Σ̄ˣ = Σˣ + (Σ̄ˣʸ − Σˣʸ) Aᵀ``,
      ``O(|x| |y| (|x| + |y|))`` — the whole ``y`` block is given;
    * ``y`` smaller: one symmetric rank-``|y|`` correction ``Σ + G (Σ̄ʸ − Σʸ) Gᵀ`` with
      ``G = [A; I]``, through the eigen-decomposition of the ``|y| × |y|`` difference so that
      the result is exactly symmetric without a transposed pass over ``n²`` entries.

    Parameters
    ----------
    cov
        Joint covariance ``(n, n)``, symmetric (not modified).
    index_y
        Integer indices of ``y`` (no repeats; not checked).
    shift_y
        ``δ = μ̄ʸ − μʸ``.
    cov_y
        ``Σ̄ʸ``.
    info_y
        ``Σʸ⁻¹`` of the current marginal if already known (else computed by Cholesky).

    Returns
    -------
    shift, new_cov
        The ``(n,)`` shift of the joint mean and the new joint covariance (symmetric).
    """
    n = cov.shape[0]
    iy = np.asarray(index_y, dtype=np.intp)
    ix = _complement(iy, n)
    cov_y = symmetrize(cov_y)
    shift = np.empty(n)
    shift[iy] = shift_y
    block_form = ix.size <= iy.size
    if block_form:
        sigma_xy = cov.take(ix, axis=0).take(iy, axis=1)
    else:  # the x rows are most of the matrix: gather only the y columns
        sigma_xy = cov.take(iy, axis=1).take(ix, axis=0)
    if info_y is None:
        sigma_y = cov.take(iy, axis=0).take(iy, axis=1)
        gain = _regression_gain(sigma_xy, sigma_y, "replace_marginal: old marginal Σʸ")
    else:
        gain = sigma_xy @ info_y
    shift[ix] = gain @ shift_y
    if not block_form:
        return shift, _low_rank_replace(cov, ix, iy, gain, cov_y)
    from teamslam._gaussian_kernels import rebuilt_joint  # numba, on first use

    new_xy = gain @ cov_y
    # Σ̄ˣ = sym(Σˣ + (Σ̄ˣʸ − Σˣʸ) Aᵀ), every block written straight to its rows and columns
    return shift, rebuilt_joint(cov, ix, iy, (new_xy - sigma_xy) @ gain.T, new_xy, cov_y)


def _low_rank_replace(
    cov: np.ndarray, ix: np.ndarray, iy: np.ndarray, gain: np.ndarray, cov_y: np.ndarray
) -> np.ndarray:
    """``Σ + G (Σ̄ʸ − Σʸ) Gᵀ`` (``G`` = ``gain`` on the rows ``ix``, identity on ``iy``).

    ``Σ̄ʸ − Σʸ = V Λ Vᵀ`` splits the correction into ``W₊W₊ᵀ − W₋W₋ᵀ`` (``W = G V |Λ|^½``),
    each product exactly symmetric.
    """
    difference = cov_y - cov.take(iy, axis=0).take(iy, axis=1)
    values, vectors = np.linalg.eigh(0.5 * (difference + difference.T))
    full_gain = np.empty((cov.shape[0], iy.size))
    full_gain[ix] = gain @ vectors
    full_gain[iy] = vectors
    up = full_gain[:, values > 0] * np.sqrt(values[values > 0])
    down = full_gain[:, values < 0] * np.sqrt(-values[values < 0])
    out = up @ up.T
    out -= down @ down.T
    out += cov
    out[np.ix_(iy, iy)] = cov_y
    return out


def _spd(matrix: np.ndarray, what: str) -> np.ndarray:
    matrix = symmetrize(matrix)
    _cholesky(matrix, what)
    return matrix


def _regression_gain(sigma_xy: np.ndarray, sigma_y: np.ndarray, what: str) -> np.ndarray:
    """``A = Σˣʸ Σʸ⁻¹`` (Cholesky solve): the gain of ``x`` on ``y`` of Prop. 2 and of the
    conditional ``p(x | y)``."""
    factor = scipy.linalg.cho_factor(_spd(sigma_y, what))
    return scipy.linalg.cho_solve(factor, sigma_xy.T).T


def _schur_complement(
    info: np.ndarray, iy: np.ndarray, ix: np.ndarray, vector: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """The marginal of ``iy`` in information form, by the Schur complement of ``ix``:
    ``Λʸʸ − Λʸˣ (Λˣˣ)⁻¹ Λˣʸ`` and, with ``vector`` (``η``), ``ηʸ − Λʸˣ (Λˣˣ)⁻¹ ηˣ``."""
    rows_x = info.take(ix, axis=0)
    factor = scipy.linalg.cho_factor(_spd(rows_x.take(ix, axis=1), "information block Λˣˣ"))
    cross = rows_x.take(iy, axis=1)
    marginal = info.take(iy, axis=0).take(iy, axis=1) - cross.T @ scipy.linalg.cho_solve(
        factor, cross
    )
    if vector is None:
        return marginal, None
    return marginal, vector[iy] - cross.T @ scipy.linalg.cho_solve(factor, vector[ix])


def add_weighted_difference(
    info: np.ndarray,
    eta: np.ndarray,
    matrix_index: tuple | np.ndarray,
    vector_index: np.ndarray,
    weight: float,
    their: tuple[np.ndarray, np.ndarray],
    own: tuple[np.ndarray, np.ndarray],
) -> None:
    """One neighbour's term of eq. 19 in information form (App. B, eq. 42), in place:

        ``Ω[C, C] += w (M_j − Ω_C)``,  ``η[C] += w (m_j − η_C)``

    with ``their = (M_j, m_j)`` the neighbour's marginal information of the block ``C`` and
    ``own = (Ω_C, η_C)`` ours. Every information-form average of the package (the joint and
    per-object consensus averages, the distributed mirror descent) is a sum of these terms.

    Parameters
    ----------
    info, eta
        The information matrix and vector being averaged (edited in place).
    matrix_index, vector_index
        Where ``C`` sits in ``info`` (e.g. ``np.ix_(c, c)``, or the first axis of a stack of
        blocks) and in ``eta``.
    weight
        ``w_j``.
    """
    info[matrix_index] += weight * (their[0] - own[0])
    eta[vector_index] += weight * (their[1] - own[1])


def _marginal_information(
    info: np.ndarray, cov: np.ndarray | None, iy: np.ndarray, ix: np.ndarray
) -> np.ndarray:
    """Information matrix of the marginal of ``iy`` (``ix`` the rest), the cheaper way round.

    Either the Schur complement of the rest in the joint information,
    ``Λʸʸ − Λʸˣ (Λˣˣ)⁻¹ Λˣʸ`` (``|x|³``), or — when ``cov`` is given and ``y`` is the smaller
    block — the inverse of ``Σʸʸ`` (``|y|³``). Both are the same matrix.
    """
    if ix.size == 0:
        return info.take(iy, axis=0).take(iy, axis=1)
    if cov is not None and ix.size >= iy.size:
        return spd_inverse(cov.take(iy, axis=0).take(iy, axis=1), "marginal covariance Σʸʸ")
    return _schur_complement(info, iy, ix)[0]


def completed_geometric_average(
    mean: np.ndarray,
    cov: np.ndarray,
    terms: Sequence[tuple],
    info: np.ndarray | None = None,
    block: int | None = None,
    extra: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 19 in information form, each neighbour's term completed by our own conditional.

    Our marginal of ``y`` is ``N(mean, cov)``. Neighbour ``j`` holds a Gaussian over a subset
    ``C_j`` of ``y`` (positions ``index_j``) with information ``M_j`` and information vector
    ``m_j``; completed with our conditional ``q(y∖C_j | C_j)`` (Prop. 2) its information differs
    from ours only on ``C_j`` (App. B, eq. 42), so with weights summing to one
    (``w_self + Σ_j w_j = 1``) the average is

        ``Ω̄ = Ω + Σ_j w_j Lⱼᵀ (M_j − Ω_{C_j}) Lⱼ``,  ``η̄ = η + Σ_j w_j Lⱼᵀ (m_j − Ω_{C_j} μ_{C_j})``

    where ``Ω_{C_j}`` is the information of our own marginal of ``C_j``. A neighbour that holds
    all of ``y`` gives plain eq. 19, ``Ω̄ = w_self Ω + Σ_j w_j M_j``.

    Parameters
    ----------
    mean, cov
        Our marginal of ``y``.
    terms
        ``(w_j, index_j, M_j, m_j)`` per neighbour, or ``(w_j, index_j, M_j, m_j, Ω_{C_j})``
        with the information of our own marginal of ``C_j`` when it is already known
        (``None`` there: computed here).
    info
        ``cov⁻¹`` if already known.
    block
        Per-block averaging, for neighbours that sent each block's own marginal (``M_j``
        block-diagonal in blocks of this size): every block ``b`` is averaged on its own, eq.
        19 over the marginals that hold it, ours completing the rest —
        ``Ω̄_b = Σ_bb⁻¹ + Σ_j w_j (M_j,b − Σ_bb⁻¹)`` (a convex combination, so positive
        definite) — and the joint keeps our own correlation structure:
        ``Σ̄ = T Σ Tᵀ`` with ``T = blockdiag(L̄_b L_b⁻¹)`` (``L`` the Cholesky factors of the
        blocks before and after), whose diagonal blocks are exactly the averaged ones.
    extra
        ``(ΔΩ, Δη)`` added to the averaged information and information vector before they are
        inverted (hybrid consensus, :mod:`teamslam.msckf.consensus`); joint averages only.

    Returns
    -------
    mean, cov
        The averaged marginal of ``y``.
    """
    if block is not None:
        if extra is not None:
            raise InputError("extra information applies to joint averages only")
        return _per_block_average(mean, cov, terms, block)
    from teamslam._gaussian_kernels import add_weighted_difference_at  # numba, on first use

    own_info = spd_inverse(cov, "own marginal covariance") if info is None else info
    info_bar = own_info.copy()
    eta_bar = own_info @ mean
    d = mean.size
    for weight, index, m_info, m_eta, *known in terms:
        sub = np.asarray(index, dtype=np.intp)
        if sub.size == d and np.array_equal(sub, np.arange(d)):
            own_sub = own_info
        elif known and known[0] is not None:
            own_sub = known[0]
        else:
            own_sub = _marginal_information(own_info, cov, sub, _complement(sub, d))
        add_weighted_difference_at(
            info_bar,
            eta_bar,
            sub,
            float(weight),
            np.ascontiguousarray(m_info, dtype=float),
            np.ascontiguousarray(m_eta, dtype=float),
            np.ascontiguousarray(own_sub, dtype=float),
            own_sub @ mean[sub],
        )
    if extra is not None:
        info_bar += extra[0]
        eta_bar += extra[1]
    new_cov = spd_inverse(info_bar, "averaged information")
    return new_cov @ eta_bar, new_cov


def _per_block_average(
    mean: np.ndarray,
    cov: np.ndarray,
    terms: Sequence[tuple[float, np.ndarray, np.ndarray, np.ndarray]],
    block: int,
) -> tuple[np.ndarray, np.ndarray]:
    """See ``block`` of :func:`completed_geometric_average`."""
    d = mean.size
    cells = np.arange(d).reshape(-1, block)
    own_blocks = cov[cells[:, :, None], cells[:, None, :]]
    own_factor = _cholesky(own_blocks, "own per-block marginal")
    own_info = spd_inverse(own_blocks, "own per-block marginal")
    means = mean.reshape(-1, block)
    info = own_info.copy()
    eta = np.einsum("kij,kj->ki", own_info, means)
    for weight, index, m_info, m_eta, *_ in terms:
        sub = np.asarray(index, dtype=np.intp).reshape(-1, block)
        which = sub[:, 0] // block
        local = np.arange(sub.size).reshape(-1, block)
        their = m_info[local[:, :, None], local[:, None, :]]
        add_weighted_difference(
            info,
            eta,
            which,
            which,
            weight,
            (their, m_eta.reshape(-1, block)),
            (own_info[which], np.einsum("kij,kj->ki", own_info[which], means[which])),
        )
    new_blocks = spd_inverse(info, "averaged per-block information")
    new_mean = np.einsum("kij,kj->ki", new_blocks, eta).ravel()
    new_factor = _cholesky(new_blocks, "averaged per-block marginal")
    # T = blockdiag(L̄ L⁻¹), applied as T Σ Tᵀ block by block: (T Σ Tᵀ)_ab = T_a Σ_ab T_bᵀ
    eye = np.broadcast_to(np.eye(block), own_factor.shape)
    transform = new_factor @ np.linalg.solve(own_factor, eye)
    k = cells.shape[0]
    left = np.einsum("aij,ajbl->aibl", transform, cov.reshape(k, block, k, block))
    both = np.einsum("aibl,bml->aibm", left, transform)
    return new_mean, symmetrize(both.reshape(d, d))


def geometric_average_arrays(
    means: np.ndarray, covs: np.ndarray, weights: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted geometric average of Gaussians (eq. 15 / 19) over the same variable.

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
        ``Σ̄ = (Σⱼ wⱼ Σⱼ⁻¹)⁻¹`` and ``μ̄ = Σ̄ Σⱼ wⱼ Σⱼ⁻¹ μⱼ`` — computed by
        :func:`completed_geometric_average` with every term over the whole variable.
    """
    means = np.asarray(means, dtype=float)
    covs = np.asarray(covs, dtype=float)
    weights = np.asarray(weights, dtype=float)
    if means.ndim != 2 or covs.shape != (*means.shape, means.shape[1]):
        raise InputError(
            f"geometric_average: expected means (k, d) and covs (k, d, d), "
            f"got {means.shape} and {covs.shape}"
        )
    if weights.shape != (means.shape[0],):
        raise InputError(f"geometric_average: {weights.shape[0]} weights for {len(means)} inputs")
    if np.any(weights < 0) or not np.isclose(weights.sum(), 1.0, atol=1e-9):
        raise InputError("geometric_average: weights must be non-negative and sum to 1")
    if not (np.all(np.isfinite(means)) and np.all(np.isfinite(covs))):
        raise InputError("geometric_average: inputs contain NaN or infinite values")
    infos = spd_inverse(covs, "geometric_average: an input covariance")
    whole = np.arange(means.shape[1])
    terms = [(weights[k], whole, infos[k], infos[k] @ means[k]) for k in range(1, len(means))]
    return completed_geometric_average(means[0], covs[0], terms, info=infos[0])


def average_common_marginal(
    mean: np.ndarray,
    cov: np.ndarray,
    common_index: IndexLike,
    self_weight: float,
    neighbours: Sequence[tuple[float, np.ndarray, np.ndarray]],
) -> tuple[np.ndarray, np.ndarray]:
    """One consensus step on a joint: eq. 19 on the common block ``y``, then Prop. 2.

    Parameters
    ----------
    mean, cov
        The joint over ``[x; y]``.
    common_index
        Indices of ``y``.
    self_weight
        ``A_ii``.
    neighbours
        ``(A_ij, mean_j, cov_j)``: each neighbour's marginal of the whole of ``y``.

    Returns
    -------
    mean, cov
        The joint with ``y``'s marginal replaced by the weighted geometric average (the
        weights normalised to sum to one); without neighbours the input comes back unchanged.
    """
    if not neighbours:
        return mean, cov
    iy = _as_index(common_index, np.asarray(mean).size, "average_common_marginal index")
    weights = np.array([self_weight] + [w for w, _, _ in neighbours], dtype=float)
    avg_mean, avg_cov = geometric_average_arrays(
        np.stack([mean[iy]] + [m for _, m, _ in neighbours]),
        np.stack([cov[np.ix_(iy, iy)]] + [c for _, _, c in neighbours]),
        weights / weights.sum(),
    )
    return replace_marginal_arrays(mean, cov, iy, avg_mean, avg_cov)


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
            raise InputError(f"Gaussian.conditional: value has shape {value_y.shape}")
        gain = _regression_gain(
            self.cov[np.ix_(ix, iy)], self.cov[np.ix_(iy, iy)], "Gaussian.conditional: Σʸ"
        )
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
        info, eta = _schur_complement(lam, iy, ix, self.info_vector)
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


def kl_divergence(
    mean0: np.ndarray, cov0: np.ndarray, mean1: np.ndarray, cov1: np.ndarray
) -> np.ndarray:
    """``KL(N(μ₀, Σ₀) ‖ N(μ₁, Σ₁))`` in nats, batched over leading axes.

    ``½ [tr(Σ₁⁻¹Σ₀) + (μ₁ − μ₀)ᵀ Σ₁⁻¹ (μ₁ − μ₀) − d + ln det Σ₁ − ln det Σ₀]``, through the
    Cholesky factors of both covariances.
    """
    mean0, mean1 = np.asarray(mean0, dtype=float), np.asarray(mean1, dtype=float)
    l0 = _cholesky(np.asarray(cov0, dtype=float), "kl_divergence: Σ₀")
    l1 = _cholesky(np.asarray(cov1, dtype=float), "kl_divergence: Σ₁")
    d = mean0.shape[-1]
    # Σ₁⁻¹Σ₀ trace = ‖L₁⁻¹L₀‖²_F; Mahalanobis term = ‖L₁⁻¹(μ₁ − μ₀)‖²
    rhs = np.concatenate([l0, (mean1 - mean0)[..., :, None]], axis=-1)
    solved = np.linalg.solve(l1, rhs)
    trace = np.sum(solved[..., :d] ** 2, axis=(-2, -1))
    maha = np.sum(solved[..., d] ** 2, axis=-1)
    logdet = 2.0 * np.sum(
        np.log(np.diagonal(l1, axis1=-2, axis2=-1)) - np.log(np.diagonal(l0, axis1=-2, axis2=-1)),
        axis=-1,
    )
    return 0.5 * (trace + maha - d + logdet)


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
        raise InputError("geometric_average: no marginals given")
    mean, cov = geometric_average_arrays(
        np.stack([m.mean for m in marginals]),
        np.stack([m.cov for m in marginals]),
        np.asarray(weights, dtype=float),
    )
    return Gaussian(mean, cov)
