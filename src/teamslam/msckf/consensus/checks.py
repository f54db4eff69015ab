"""Consensus, checking messages: every received message is checked here, once.

:func:`check_message` checks a message's kind, age (by step, or by its frame's stamp:
:class:`~teamslam.msckf.consensus.messages.MessageAge`), sender and receiver, and for a marginal
its ids, sizes, finiteness, symmetry and one Cholesky factorisation (:func:`receive_marginal`).
A message that fails is described by a reason and never reaches the state.
"""

from __future__ import annotations

from collections.abc import MutableSet
from collections.abc import Set as AbstractSet
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from teamslam.gaussian import NotPositiveDefiniteError, spd_inverse
from teamslam.msckf.consensus.kernels import (
    FINITE,
    NON_FINITE,
    NOT_SYMMETRIC,
    checked_symmetric_part,
)
from teamslam.msckf.consensus.messages import (
    CommonMarginalMessage,
    MapIdsMessage,
    MessageAge,
    MessageLags,
)
from teamslam.msckf.filter.state import MsckfState

__all__ = [
    "ReceivedMarginal",
    "check_message",
    "receive_marginal",
    "validate_marginal",
]


def check_message(
    message: object,
    kind: type,
    step: int,
    max_age: int,
    robot: int,
    neighbours: AbstractSet[int],
    state: MsckfState | None = None,
    per_object: bool = False,
    taken: AbstractSet[int] = frozenset(),
    heard: MutableSet[int] | None = None,
    stamp_ns: int | None = None,
    max_age_ns: int | None = None,
    persistent: bool = False,
    lags: MessageLags | None = None,
) -> tuple[str | None, MapIdsMessage | ReceivedMarginal | None]:
    """Whether a received message can be used in this step of consensus.

    Parameters
    ----------
    message
        What arrived.
    kind
        What this round expects: :class:`~teamslam.msckf.consensus.messages.MapIdsMessage` (round
        1) or
        :class:`~teamslam.msckf.consensus.messages.CommonMarginalMessage` (round 2).
    step, max_age
        The current step and the oldest one accepted (``step − max_age``).
    robot, neighbours
        The receiver and the robots it may hear from.
    state
        The receiver's state (round 2: the marginal is checked against its map).
    per_object
        Whether the receiver exchanges per-object marginals (round 2).
    taken
        Senders whose message of this round was already used: a second one is ignored.
    heard
        Round 2: the senders heard in round 1. In lock-step (``max_age = 0``) a marginal from
        a robot not heard is rejected; asynchronously its sender is added to ``heard`` (the
        link works), whether or not the marginal is then usable.
    stamp_ns, max_age_ns
        With ``max_age_ns``: messages are aged by their frame's stamp instead of their step —
        accepted when sent at a frame stamped ``stamp_ns − max_age_ns`` or later
        (:class:`~teamslam.msckf.consensus.messages.MessageAge`).
    persistent
        Round 2: the receiver's persistent map takes part in consensus — the marginal's objects
        in it are kept apart (:attr:`ReceivedMarginal.retired`), not dropped.
    lags
        With ``max_age_ns``: the age limits learned per neighbour, when longer
        (:class:`~teamslam.msckf.consensus.messages.MessageLags`).

    Returns
    -------
    reason, usable
        ``(None, message)`` for usable map ids, ``(None, marginal)`` for a usable marginal
        (:class:`ReceivedMarginal`, factorised once), ``(reason, None)`` for a rejected message
        and ``(None, None)`` for one ignored (a sender already in ``taken``).
    """
    if not isinstance(message, kind):
        return "unexpected message kind", None
    problem = MessageAge(step, max_age, stamp_ns, max_age_ns, lags).problem(message)
    if problem is not None:
        return problem, None
    if message.sender not in neighbours or message.receiver != robot:
        return (
            f"message from robot {message.sender} (not a neighbour) to robot {message.receiver}",
            None,
        )
    if message.sender in taken:
        return None, None
    if isinstance(message, MapIdsMessage):
        if message.moved is not None and np.shape(message.moved) != np.shape(message.ids):
            return "moved flags do not match the ids", None
        ids = np.asarray(message.ids)
        if ids.ndim != 1 or np.any(ids[1:] <= ids[:-1]):
            return "map ids are not strictly increasing", None
        return None, message
    if heard is not None and message.sender not in heard:
        if max_age == 0:
            return f"robot {message.sender} not heard in round 1", None
        heard.add(message.sender)
    if message.per_object != per_object:
        kinds = ("joint", "per-object")
        return (
            f"a {kinds[message.per_object]} marginal from robot {message.sender}; this "
            f"robot exchanges {kinds[per_object]} marginals",
            None,
        )
    return receive_marginal(state, message, persistent)


@dataclass(frozen=True)
class ReceivedMarginal:
    """A neighbour's marginal that passed every check, in information form.

    Attributes
    ----------
    sender
        Who sent it.
    ids
        Its objects (all in our map, no repeats).
    info, info_vector
        ``Σ⁻¹`` and ``Σ⁻¹ μ`` of the neighbour's marginal.
    prior
        Consensus on information increments: ``(held, P, η_P)`` — which of ``ids`` were in the
        neighbour's prior, and the information matrix and vector of its prior marginal of
        those, in the order of ``ids`` — or ``None`` (a message without a prior).
    retired
        With the persistent map in consensus: ``(ids, Ω, η)`` of the objects of the marginal
        that are in our persistent map — ``(r,)`` ids, ``(r, 3, 3)`` information matrices and
        ``(r, 3)`` information vectors of each one's own marginal — or ``None``; ``ids`` then
        holds the objects in our state only (possibly none).
    """

    sender: int
    ids: np.ndarray
    info: np.ndarray
    info_vector: np.ndarray
    per_object: bool = False
    prior: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    retired: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None


def receive_marginal(
    state: MsckfState, message: CommonMarginalMessage, persistent: bool = False
) -> tuple[str | None, ReceivedMarginal | None]:
    """Check a neighbour's marginal against our map and factorise it once.

    A marginal in moment form is inverted (its Cholesky factor gives the information matrix);
    one in information form is checked to be positive definite by its Cholesky factorisation.
    Objects in our persistent map — retired since the neighbour asked (an asynchronous
    message), or asked for because the persistent map takes part in consensus
    (``persistent``) — are marginalised out of it, and with ``persistent`` their own marginals
    kept apart (:attr:`ReceivedMarginal.retired`); an object we never had makes it unusable.
    Returns ``(None, marginal)`` when it can be used, ``(reason, None)`` when it cannot.
    """
    ids = np.asarray(message.ids)
    k = ids.size
    if ids.ndim != 1 or k == 0 or np.unique(ids).size != k:
        return "ids must be a non-empty list without repeats", None
    information = message.info is not None
    name = "information matrix" if information else "covariance"
    per_object = not information and np.ndim(message.cov) == 3
    shape = (k, 3, 3) if per_object else (3 * k, 3 * k)
    if np.shape(message.mean) != (3 * k,) or np.shape(message.matrix) != shape:
        return f"mean/{name} sizes do not match the ids", None
    mean = np.ascontiguousarray(message.mean, dtype=float)
    matrix = np.ascontiguousarray(message.matrix, dtype=float)
    if per_object:
        transposed = np.swapaxes(matrix, -1, -2)
        if not (np.isfinite(mean).all() and np.isfinite(matrix).all()):
            status = NON_FINITE
        elif np.abs(matrix - transposed).max() > 1e-9 * np.abs(matrix).max() + 1e-12:
            status = NOT_SYMMETRIC
        else:
            status = FINITE
        matrix = 0.5 * (matrix + transposed)
    else:  # one compiled pass
        status, matrix = checked_symmetric_part(mean, matrix)
    if status == NON_FINITE:
        return f"non-finite mean or {name}", None
    if status == NOT_SYMMETRIC:
        return f"{name} is not symmetric", None
    absent = state.object_slots(ids) < 0
    retired = None
    if absent.any():
        # an asynchronous message may be older than our last retirement: objects that left our
        # state for the persistent map are marginalised out of it (exact for a Gaussian);
        # objects we never had make the message unusable
        if not state.retired.contains(ids[absent]).all():
            return "ids not in this robot's map", None
        if absent.all() and not persistent:
            return "every object of the marginal has retired from this robot's state", None
        if information:  # marginalise in moment form (a rare path)
            try:
                matrix = spd_inverse(matrix, name)
            except NotPositiveDefiniteError:
                return f"{name} is not positive definite", None
            information = False
        if persistent:
            problem, retired = _retired_part(ids, mean, matrix, absent, per_object)
            if problem is not None:
                return problem, None
            if absent.all():
                empty = np.zeros((0, 0))
                return None, ReceivedMarginal(
                    int(message.sender),
                    ids[:0].astype(np.int64),
                    empty,
                    np.zeros(0),
                    per_object,
                    retired=retired,
                )
        keep = np.flatnonzero(~absent)
        coords = (3 * keep[:, None] + np.arange(3)).ravel()
        ids, mean, k = ids[keep], mean[coords], keep.size
        matrix = matrix[keep] if per_object else matrix[np.ix_(coords, coords)]
    if information:
        _, failed = lapack.dpotrf(matrix, lower=1)
        if failed != 0:
            return f"{name} is not positive definite", None
        info = matrix
    else:
        try:
            info = spd_inverse(matrix, name)
        except NotPositiveDefiniteError:
            return f"{name} is not positive definite", None
    if per_object:  # block-diagonal information of the per-object marginals
        blocks = info
        info = np.zeros((3 * k, 3 * k))
        index = 3 * np.arange(k)[:, None] + np.arange(3)
        info[index[:, :, None], index[:, None, :]] = blocks
    prior = None
    if message.has_prior and not absent.any():
        problem, prior = _received_prior(message, k)
        if problem is not None:
            return problem, None
    return None, ReceivedMarginal(
        int(message.sender), ids.astype(np.int64), info, info @ mean, per_object, prior, retired
    )


def _retired_part(
    ids: np.ndarray, mean: np.ndarray, cov: np.ndarray, absent: np.ndarray, per_object: bool
) -> tuple[str | None, tuple[np.ndarray, np.ndarray, np.ndarray] | None]:
    """``(ids, Ω, η)`` of each ``absent`` object's own marginal, from a marginal's mean and
    covariance (joint ``(3k, 3k)`` or per-object ``(k, 3, 3)``), or a reason."""
    which = np.flatnonzero(absent)
    if per_object:
        blocks = cov[which]
    else:
        index = 3 * which[:, None] + np.arange(3)
        blocks = cov[index[:, :, None], index[:, None, :]]
    if np.any(np.linalg.eigvalsh(blocks)[:, 0] <= 0):
        return "a retired object's covariance is not positive definite", None
    info = np.linalg.inv(blocks)
    info = 0.5 * (info + np.swapaxes(info, 1, 2))
    vector = np.einsum("kij,kj->ki", info, mean.reshape(-1, 3)[which])
    return None, (ids[which].astype(np.int64), info, vector)


def _received_prior(
    message: CommonMarginalMessage, k: int
) -> tuple[str | None, tuple[np.ndarray, np.ndarray, np.ndarray] | None]:
    """The checked prior of a marginal message: ``(held, P, η_P)``, or a reason."""
    held = np.asarray(message.prior_held)
    if held.shape != (k,) or held.dtype != bool:
        return "prior flags do not match the ids", None
    h = 3 * int(held.sum())
    mean = np.asarray(message.prior_mean, dtype=float)
    info = np.asarray(message.prior_info, dtype=float)
    if mean.shape != (h,) or info.shape != (h, h):
        return "prior mean/information sizes do not match its flags", None
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(info))):
        return "non-finite prior mean or information matrix", None
    if h and np.abs(info - info.T).max() > 1e-9 * np.abs(info).max() + 1e-12:
        return "prior information matrix is not symmetric", None
    info = 0.5 * (info + info.T)
    if h and lapack.dpotrf(info, lower=1)[1] != 0:
        return "prior information matrix is not positive definite", None
    return None, (held, info, info @ mean)


def validate_marginal(state: MsckfState, message: CommonMarginalMessage) -> str | None:
    """Why a received marginal cannot be used (``None`` when it can)."""
    return receive_marginal(state, message)[0]
