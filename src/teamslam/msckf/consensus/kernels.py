"""Compiled per-message passes of consensus (numba).

Each function is one compiled pass over a message's arrays — gathering the symmetric block a
sender inverts, checking a received marginal, rounding to single precision, merging exchange
records, sizing a message on the wire — and gives the same numbers as the numpy expressions it
replaces (the same floating-point operations, no reassociation). The one exception,
:func:`rounding_bound`, adds its sums of squares in another order: its estimate may differ in
the last bits and only decides against
:data:`~teamslam.msckf.consensus.marginals.FLOAT32_MAX_KL`.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = [
    "FINITE",
    "NON_FINITE",
    "NOT_SYMMETRIC",
    "all_single",
    "checked_symmetric_part",
    "encoded_ids_bytes",
    "merged_record",
    "rounding_bound",
    "single_rounding",
    "symmetric_block",
]

FINITE, NON_FINITE, NOT_SYMMETRIC = 0, 1, 2
"""What :func:`checked_symmetric_part` found."""


@numba.njit(cache=True)
def checked_symmetric_part(mean: np.ndarray, matrix: np.ndarray) -> tuple[int, np.ndarray]:
    """``(status, (M + Mᵀ) / 2)`` of a received mean and ``(d, d)`` matrix ``M``.

    ``status`` is :data:`NON_FINITE` when an entry of either is NaN or infinite,
    :data:`NOT_SYMMETRIC` when ``max |M − Mᵀ| > 10⁻⁹ max |M| + 10⁻¹²``, else :data:`FINITE`
    (the symmetric part is then the second value; otherwise it is not filled in).
    """
    d = matrix.shape[0]
    out = np.empty((d, d))
    finite = True
    for i in range(mean.size):
        finite &= np.isfinite(mean[i])
    # one pass in memory order (finiteness, largest entry, a copy), then the symmetric part
    # inside the copy, which stays in cache: reading the matrix by columns costs a cache line
    # per entry. ``value * 0`` is ±0 for a finite value and NaN otherwise, so their sum tells
    # whether every entry is finite without a test per entry.
    largest = 0.0
    probe = 0.0
    for i in range(d):
        for j in range(d):
            value = matrix[i, j]
            probe += value * 0.0
            largest = max(largest, abs(value))
            out[i, j] = value
    finite &= probe == 0.0
    if not finite:
        return NON_FINITE, out
    asymmetry = 0.0
    for i in range(d):
        out[i, i] = 0.5 * (out[i, i] + out[i, i])
        for j in range(i + 1, d):
            upper, lower = out[i, j], out[j, i]
            asymmetry = max(asymmetry, abs(upper - lower))
            value = 0.5 * (upper + lower)
            out[i, j] = value
            out[j, i] = value
    if asymmetry > 1e-9 * largest + 1e-12:
        return NOT_SYMMETRIC, out
    return FINITE, out


@numba.njit(cache=True, error_model="numpy")
def rounding_bound(
    mean: np.ndarray,
    cov: np.ndarray,
    info: np.ndarray,
    mean_rounded: np.ndarray,
    info_rounded: np.ndarray,
) -> float:
    """:func:`~teamslam.msckf.consensus.marginals.information_rounding_bound` in one pass."""
    d = mean.size
    std = np.empty(d)
    for i in range(d):
        std[i] = np.sqrt(cov[i, i])
    correlation_sums = np.zeros(d)
    info_sums = np.zeros(d)
    d_info = 0.0
    for i in range(d):
        # the column sums first (each its own chain, so the row is one vector pass), then the
        # single running sum in the same order
        for j in range(d):
            scale = std[i] * std[j]
            correlation_sums[j] += abs(cov[i, j]) / scale
            info_sums[j] += abs(info[i, j]) * scale
        for j in range(d):
            change = (info_rounded[i, j] - info[i, j]) * (std[i] * std[j])
            d_info += change**2
    d_mean = 0.0
    for i in range(d):
        change = (mean_rounded[i] - mean[i]) / std[i]
        d_mean += change**2
    correlation_norm = correlation_sums.max()
    scaled_info_norm = info_sums.max()
    return 0.25 * correlation_norm**2 * d_info + 0.5 * scaled_info_norm * d_mean


@numba.njit(cache=True, error_model="numpy")
def single_rounding(
    mean: np.ndarray, cov: np.ndarray, info: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """``(mean₃₂, info₃₂, bound)``: the mean and information matrix rounded to single precision
    (as doubles) and :func:`rounding_bound` of that rounding."""
    mean_rounded = mean.astype(np.float32).astype(np.float64)
    info_rounded = info.astype(np.float32).astype(np.float64)
    return (
        mean_rounded,
        info_rounded,
        rounding_bound(mean, cov, info, mean_rounded, info_rounded),
    )


_SEVEN = np.uint64(7)
_ONE_BYTE = np.uint64(0x80)


@numba.njit(cache=True)
def _varint_length(value: np.uint64) -> int:
    """Bytes of one unsigned LEB128 varint (7 bits a byte, at least one)."""
    length = 1
    while value >= _ONE_BYTE:
        value >>= _SEVEN
        length += 1
    return length


@numba.njit(cache=True)
def encoded_ids_bytes(ids: np.ndarray) -> int:
    """Length of :func:`~teamslam.msckf.consensus.messages.encode_ids` of ``int64`` ids, or ``-1``
    when
    they are not strictly increasing: the first id zigzag-coded, then the differences (taken
    as unsigned, exact over the whole 64-bit range)."""
    if ids.size == 0:
        return 0
    first = ids[0]
    total = _varint_length(np.uint64((first << 1) ^ (first >> 63)))
    for i in range(1, ids.size):
        if ids[i] <= ids[i - 1]:
            return -1
        total += _varint_length(np.uint64(ids[i]) - np.uint64(ids[i - 1]))
    return total


@numba.njit(cache=True)
def all_single(values: np.ndarray) -> bool:
    """Whether every entry of a ``float64`` array is exactly a float32 (``NaN`` never is)."""
    for value in values.ravel():
        if np.float64(np.float32(value)) != value:
            return False
    return True


@numba.njit(cache=True)
def symmetric_block(matrix: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``(B + Bᵀ) / 2`` of the block ``B = matrix[np.ix_(index, index)]``.

    ``B`` is gathered row by row first (each row of ``matrix`` read once, in order), then made
    symmetric inside the small block, which stays in cache: reading ``matrix`` by columns
    instead costs a cache line per entry."""
    k = index.size
    out = np.empty((k, k))
    for a in range(k):
        row = index[a]
        for b in range(k):
            out[a, b] = matrix[row, index[b]]
    for a in range(k):
        out[a, a] = 0.5 * (out[a, a] + out[a, a])
        for b in range(a + 1, k):
            value = 0.5 * (out[a, b] + out[b, a])
            out[a, b] = value
            out[b, a] = value
    return out


@numba.njit(cache=True)
def _is_in(sorted_values: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Whether each of the increasing ``values`` is in the increasing ``sorted_values``."""
    out = np.zeros(values.size, dtype=np.bool_)
    at = 0
    for i in range(values.size):
        while at < sorted_values.size and sorted_values[at] < values[i]:
            at += 1
        out[i] = at < sorted_values.size and sorted_values[at] == values[i]
    return out


@numba.njit(cache=True)
def merged_record(
    old_ids: np.ndarray,
    old_means: np.ndarray,
    old_covs: np.ndarray,
    old_steps: np.ndarray,
    ids: np.ndarray,
    means: np.ndarray,
    covs: np.ndarray,
    exchanged: np.ndarray,
    step: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The record of a link after an exchange, ordered by id: the old record's objects that are
    still in the map (``ids``) and were not exchanged now, and the objects of ``ids`` that were
    (their ``means``, ``covs`` and ``step``). ``old_ids``, ``ids`` and ``exchanged`` increase."""
    take = _is_in(exchanged, ids)
    keep = _is_in(ids, old_ids) & ~_is_in(exchanged, old_ids)
    count = int(take.sum() + keep.sum())
    out_ids = np.empty(count, dtype=np.int64)
    out_means = np.empty((count, 3))
    out_covs = np.empty((count, 3, 3))
    out_steps = np.empty(count, dtype=np.int64)
    a, i = 0, 0
    for row in range(count):
        while a < old_ids.size and not keep[a]:
            a += 1
        while i < ids.size and not take[i]:
            i += 1
        if i >= ids.size or (a < old_ids.size and old_ids[a] < ids[i]):
            out_ids[row] = old_ids[a]
            out_means[row] = old_means[a]
            out_covs[row] = old_covs[a]
            out_steps[row] = old_steps[a]
            a += 1
        else:
            out_ids[row] = ids[i]
            out_means[row] = means[i]
            out_covs[row] = covs[i]
            out_steps[row] = step
            i += 1
    return out_ids, out_means, out_covs, out_steps
