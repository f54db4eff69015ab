"""The consensus messages: what one robot may tell a neighbour (distributed MSCKF paper, §V-B).

Round 1, :class:`MapIdsMessage`: the sender's map ids; round 2, :class:`CommonMarginalMessage`:
its marginal of the objects it shares with the receiver and its degree this step (with
information increments, also its prior). A message is aged by its step, or — between robots
that drop frames, whose steps are not comparable — by its frame's stamp (:class:`MessageAge`),
up to an age learned per neighbour from how late its messages arrive (:class:`MessageLags`).
Messages are plain data, moved by a
:class:`~teamslam.msckf.consensus.transport.Transport` and laid out on a network by
:mod:`teamslam.runtime.wire`; ids, strictly increasing, travel as variable-length deltas
(:func:`encode_ids`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from teamslam.association.summary import ObjectSummary
from teamslam.msckf.consensus.kernels import all_single, encoded_ids_bytes

__all__ = [
    "CommonMarginalMessage",
    "MapIdsMessage",
    "Message",
    "MessageAge",
    "MessageLags",
    "decode_ids",
    "encode_ids",
    "summary_wire_bytes",
]

HEADER_BYTES = 36  # the fixed header of every message on a wire (teamslam.runtime.wire)
STAMP_BYTES = 8  # a stamped message's frame stamp, after the header
_VARINT_GROUPS = 10  # 7-bit groups of a 64-bit integer


def _varint_values(ids: np.ndarray) -> np.ndarray:
    """The unsigned values written for strictly increasing ``ids``: the first id zigzag-coded
    (``2i`` for ``i ≥ 0``, ``−2i − 1`` below), then the positive differences."""
    ids = np.asarray(ids, dtype=np.int64)
    if ids.ndim != 1:
        raise ValueError("ids must be one-dimensional")
    if ids.size == 0:
        return np.zeros(0, dtype=np.uint64)
    if np.any(ids[1:] <= ids[:-1]):
        raise ValueError("ids must be strictly increasing")
    steps = ids[1:].view(np.uint64) - ids[:-1].view(np.uint64)  # exact, as unsigned
    first = ids[:1]
    zigzag = ((first << 1) ^ (first >> 63)).view(np.uint64)
    return np.concatenate([zigzag, steps])


# a value below 2^(7g) takes g bytes (at least one): the lengths by one binary search
_VARINT_LIMITS = np.left_shift(np.uint64(1), 7 * np.arange(1, _VARINT_GROUPS, dtype=np.uint64))


def _varint_lengths(values: np.ndarray) -> np.ndarray:
    return 1 + np.searchsorted(_VARINT_LIMITS, values, side="right")


def encode_ids(ids: np.ndarray) -> bytes:
    """Strictly increasing ids as LEB128 varints of the first id (zigzag) and the differences.

    Raises
    ------
    ValueError
        When the ids are not strictly increasing.
    """
    values = _varint_values(ids)
    if values.size == 0:
        return b""
    shifts = 7 * np.arange(_VARINT_GROUPS, dtype=np.uint64)
    groups = (values[:, None] >> shifts) & np.uint64(0x7F)
    lengths = _varint_lengths(values)
    position = np.arange(_VARINT_GROUPS)
    more = (position < (lengths - 1)[:, None]).astype(np.uint64) << np.uint64(7)
    return (groups | more)[position < lengths[:, None]].astype(np.uint8).tobytes()


def encoded_ids_size(ids: np.ndarray) -> int:
    """``len(encode_ids(ids))`` without building the bytes (one compiled pass,
    :func:`~teamslam.msckf.consensus.kernels.encoded_ids_bytes`).

    Raises
    ------
    ValueError
        When the ids are not strictly increasing.
    """
    ids = np.ascontiguousarray(ids, dtype=np.int64)
    if ids.ndim != 1:
        raise ValueError("ids must be one-dimensional")
    size = encoded_ids_bytes(ids)
    if size < 0:
        raise ValueError("ids must be strictly increasing")
    return int(size)


def decode_ids(data: bytes | np.ndarray, count: int) -> np.ndarray:
    """Inverse of :func:`encode_ids`: ``count`` strictly increasing ids from exactly ``data``.

    Raises
    ------
    ValueError
        Naming the problem: a different number of ids, a varint longer than 64 bits, or ids
        that leave the 64-bit range.
    """
    raw = np.frombuffer(data, dtype=np.uint8) if isinstance(data, bytes) else data
    if count == 0:
        if raw.size:
            raise ValueError(f"{raw.size} bytes of ids for 0 ids")
        return np.zeros(0, dtype=np.int64)
    ends = np.flatnonzero(raw < 0x80)
    if ends.size != count or ends[-1] != raw.size - 1:
        raise ValueError(f"the id bytes hold {ends.size} complete ids, the header says {count}")
    starts = np.concatenate([[0], ends[:-1] + 1])
    lengths = ends - starts + 1
    if lengths.max() > _VARINT_GROUPS:
        raise ValueError("an id longer than 64 bits")
    position = np.arange(raw.size) - np.repeat(starts, lengths)
    if np.any(raw[ends[lengths == _VARINT_GROUPS]] > 1):
        raise ValueError("an id longer than 64 bits")
    parts = (raw & np.uint8(0x7F)).astype(np.uint64) << (7 * position).astype(np.uint64)
    values = np.add.reduceat(parts, starts)
    first = values[:1]
    first = (first >> np.uint64(1)).view(np.int64) ^ -(first & np.uint64(1)).view(np.int64)
    steps = values[1:]
    if np.any(steps == 0):
        raise ValueError("ids are not strictly increasing")
    # unsigned sums wrap exactly; a sum past 2⁶³ − 1 comes back round below its predecessor
    ids = np.cumsum(np.concatenate([first.view(np.uint64), steps])).view(np.int64)
    if np.any(ids[1:] <= ids[:-1]):
        raise ValueError("ids leave the 64-bit range")
    return ids


def summary_wire_bytes(summary: ObjectSummary | None, n_ids: int | None = None) -> int:
    """Bytes an object summary adds to a round-1 message of ``n_ids`` map ids on a wire: per
    object its mean (3 × 8), the upper triangle of its covariance (6 × 8), where the sender's
    cameras were (3 × 4) and its class (8) when the map has classes, its appearance descriptor
    (2 per dimension) with the dimension and the histogram of same-object distances once when
    the map has appearance — the ids travel once, as the message's map ids; a summary of some
    of them (``association.sooner``) adds one bit per map id saying which."""
    if summary is None:
        return 0
    partial = n_ids is not None and len(summary) != n_ids
    return summary.nbytes - 8 * len(summary) + ((n_ids + 7) // 8 if partial else 0)


@dataclass(frozen=True)
class MapIdsMessage:
    """Round 1 of consensus: the ids of the objects in the sender's map.

    Attributes
    ----------
    ids
        Every object in the sender's map, strictly increasing.
    moved
        One flag per id: whether the sender's marginal of that object has moved since the two
        robots last exchanged it (``None``: all have — average every common object).
    summary
        With association by the robots themselves (``association.mode = own``): the sender's
        object summary (ids, means, marginal covariances, classes) on the steps its link
        exchanges summaries, else ``None``: of every id, or of some of them (those new to the
        link, sent before the interval: ``association.sooner``).
    stamp_ns
        The stamp (ns) of the sender's frame it was sent at, or ``None``. Robots that drop
        frames (live, asynchronous) count steps that are not comparable between them: their
        messages carry the stamp and are aged by it.
    """

    sender: int
    receiver: int
    step: int
    ids: np.ndarray
    moved: np.ndarray | None = None
    summary: ObjectSummary | None = None
    stamp_ns: int | None = None

    def nbytes(self) -> int:
        """Payload size on a wire (header, the stamp, the ids, one bit per id for ``moved``,
        the summary)."""
        flags = 0 if self.moved is None else (int(np.size(self.ids)) + 7) // 8
        return (
            _header_bytes(self.stamp_ns)
            + encoded_ids_size(self.ids)
            + flags
            + summary_wire_bytes(self.summary, int(np.size(self.ids)))
        )


@dataclass(frozen=True)
class CommonMarginalMessage:
    """Round 2: the sender's marginal of the objects it shares with the receiver (eq. 19).

    The marginal travels in moment form (``cov``) or in information form (``info``, exactly
    one of the two is given). The information form is what eq. 19 averages: a receiver then
    only checks it (one Cholesky factorisation) instead of inverting it, and the sender has
    inverted its own marginal of these objects anyway, for its own average (eq. 42).

    Attributes
    ----------
    ids
        The shared objects' ids, strictly increasing.
    mean
        Their marginal mean, ``3·len(ids)`` long, in the order of ``ids``.
    cov
        Moment form: the joint ``(3k, 3k)`` covariance, or ``(k, 3, 3)`` — each object's own
        block — for a per-object message; ``None`` in information form.
    degree
        How many neighbours the sender heard from in round 1 of this step.
    info
        Information form: ``Σ⁻¹`` of the joint marginal, ``(3k, 3k)``; ``None`` in moment form.
    prior_held
        Consensus on information increments: one flag per id, whether the object was in the
        sender's prior (its map right after its last exchange); ``None`` without a prior.
    prior_mean, prior_info
        The sender's prior marginal of the flagged objects (``3h`` and ``(3h, 3h)``, ``h`` the
        flags set, in the order of ``ids``), in information form; ``None`` without a prior.
        Only with ``info`` (a joint marginal in information form).
    stamp_ns
        The stamp (ns) of the sender's frame it was computed at, or ``None`` (see
        :class:`MapIdsMessage`).
    """

    sender: int
    receiver: int
    step: int
    ids: np.ndarray
    mean: np.ndarray
    cov: np.ndarray | None
    degree: int = 0
    info: np.ndarray | None = None
    prior_held: np.ndarray | None = None
    prior_mean: np.ndarray | None = None
    prior_info: np.ndarray | None = None
    stamp_ns: int | None = None

    def __post_init__(self) -> None:
        if (self.cov is None) == (self.info is None):
            raise ValueError(
                "a marginal message holds either a covariance or an information matrix"
            )
        if self.info is not None and np.ndim(self.info) != 2:
            raise ValueError("an information-form marginal is joint: info must be (3k, 3k)")
        parts = (self.prior_held, self.prior_mean, self.prior_info)
        if any(p is not None for p in parts):
            if any(p is None for p in parts):
                raise ValueError("a prior needs its flags, mean and information matrix")
            if self.info is None:
                raise ValueError("a prior travels only with a marginal in information form")

    @property
    def has_prior(self) -> bool:
        """Whether the message carries the sender's prior (consensus on increments)."""
        return self.prior_held is not None

    @property
    def matrix(self) -> np.ndarray:
        """The matrix the message carries: ``cov``, or ``info`` in information form."""
        return self.cov if self.info is None else self.info

    @property
    def per_object(self) -> bool:
        """Whether ``cov`` holds each object's own 3×3 block only."""
        return np.ndim(self.matrix) == 3

    @property
    def single_precision(self) -> bool:
        """Whether every number is exactly a float32 (sent in 4 bytes)."""
        arrays = [self.mean, self.matrix]
        if self.has_prior:
            arrays += [self.prior_mean, self.prior_info]
        return all(_exactly_single(np.asarray(a)) for a in arrays)

    def nbytes(self) -> int:
        """Payload size on a wire: ids, mean and the matrix's upper triangle(s); with a prior,
        one bit per id for its flags, its mean and its information matrix's upper triangle."""
        d = int(np.size(self.mean))
        k = int(np.size(self.ids))
        upper = 6 * k if self.per_object else d * (d + 1) // 2
        width = 4 if self.single_precision else 8
        prior = 0
        if self.has_prior:
            h = int(np.size(self.prior_mean))
            prior = (k + 7) // 8 + width * (h + h * (h + 1) // 2)
        return (
            _header_bytes(self.stamp_ns) + encoded_ids_size(self.ids) + width * (d + upper) + prior
        )


def _header_bytes(stamp_ns: int | None) -> int:
    """The header's bytes on a wire, with the frame stamp when the message carries one."""
    return HEADER_BYTES + (0 if stamp_ns is None else STAMP_BYTES)


def _exactly_single(values: np.ndarray) -> bool:
    """Whether every number of ``values`` is exactly a float32."""
    if values.dtype == np.float64:
        return bool(all_single(np.ascontiguousarray(values)))
    return np.array_equal(values.astype(np.float32), values)


Message = MapIdsMessage | CommonMarginalMessage


class MessageLags:
    """How late each neighbour's messages reach this robot, and the age up to which they are
    used, learned from their stamps (robots aged by stamp); messages found too old, counted.

    A message's lag is the stamp of this robot's frame at the first exchange that finds it in
    the mailbox minus the stamp of the neighbour's frame it was sent at: the neighbour's latency
    minus ours, plus the time on the way and until our next exchange. The newest message of a
    neighbour that keeps talking is replaced one of its intervals later, so it is at most its
    arrival lag plus that interval old; a neighbour's messages of a kind are accepted up to the
    ``quantile`` of their last ``window`` lags plus the median interval between them — its
    newest message is usable at that share of our exchanges however its lag compares with our
    own frame interval, and a neighbour that stops talking expires that long after its last
    message. The empirical quantile exists once ``1 / (1 − quantile)`` lags are known; until
    then the largest lag seen stands for it (a neighbour's first message is used). With
    ``quantile`` ``None`` the age limit given (the floor) applies alone. Derivation: the concept
    page *Consensus*.

    Parameters
    ----------
    quantile
        The share of the neighbour's arrival lags covered (``None``: nothing is learned).
    window
        How many of a neighbour's latest lags and intervals are kept.
    """

    def __init__(self, quantile: float | None = 0.95, window: int = 50) -> None:
        if quantile is not None and not 0.0 < quantile < 1.0:
            raise ValueError(f"the lag quantile must be in (0, 1), got {quantile}")
        self.quantile = quantile
        self.window = int(window)
        self.needed = 0 if quantile is None else math.ceil(1.0 / (1.0 - quantile) - 1e-9)
        self._latest: dict[tuple[int, type], Message] = {}
        self._lags: dict[tuple[int, type], deque[int]] = {}
        self._intervals: dict[tuple[int, type], deque[int]] = {}
        self._learned: dict[tuple[int, type], int | None] = {}
        #: messages discarded as older than their limit while the newest of their sender and
        #: kind, by sender
        self.too_old: dict[int, int] = {}

    def seen(self, message: Message, stamp_ns: int | None) -> None:
        """``message`` is in the mailbox at the exchange of our frame stamped ``stamp_ns``: the
        first time a neighbour's newer message is seen, its lag and interval are kept."""
        key = (message.sender, type(message))
        latest = self._latest.get(key)
        stamp = message.stamp_ns
        if stamp is None or stamp_ns is None:  # by step: only which one is the newest
            if latest is None or message.step > latest.step:
                self._latest[key] = message
            return
        if latest is not None and latest.stamp_ns is not None and stamp <= latest.stamp_ns:
            return
        self._latest[key] = message
        if self.quantile is None:
            return
        lags = self._lags.setdefault(key, deque(maxlen=self.window))
        lags.append(int(stamp_ns) - int(stamp))
        if latest is not None and latest.stamp_ns is not None:
            intervals = self._intervals.setdefault(key, deque(maxlen=self.window))
            intervals.append(int(stamp) - int(latest.stamp_ns))
        self._learned.pop(key, None)

    def learned_ns(self, sender: int, kind: type) -> int | None:
        """The age in ns up to which ``sender``'s ``kind`` messages are usable by its lags
        (``None``: no lag known)."""
        key = (sender, kind)
        if key not in self._learned:
            lags = self._lags.get(key, ())
            learned = None
            if self.quantile is not None and lags:
                q = self.quantile if len(lags) >= self.needed else 1.0  # the largest, until then
                lag = np.quantile(np.fromiter(lags, np.int64), q, method="higher")
                intervals = self._intervals.get(key, ())
                interval = np.median(np.fromiter(intervals, np.int64)) if intervals else 0
                learned = int(lag) + round(float(interval))
            self._learned[key] = learned
        return self._learned[key]

    def limit_ns(self, sender: int, kind: type, floor_ns: int) -> int:
        """The age limit of ``sender``'s ``kind`` messages: the learned one, never below
        ``floor_ns``."""
        learned = self.learned_ns(sender, kind)
        return floor_ns if learned is None else max(int(floor_ns), learned)

    def discarded(self, message: Message) -> None:
        """``message`` was discarded as expired: counted in :attr:`too_old` when it was its
        sender's newest of its kind (a message superseded by a newer one expires unused as a
        matter of course)."""
        if self._latest.get((message.sender, type(message))) is message:
            self.too_old[message.sender] = self.too_old.get(message.sender, 0) + 1

    def state_dict(self) -> dict[str, np.ndarray]:
        """What was learned, as arrays (a checkpoint's): each (sender, kind)'s kept lags and
        intervals; :meth:`load_state_dict` gives a resumed robot the same age limits."""
        keys = sorted(set(self._lags) | set(self._intervals), key=lambda k: (k[0], k[1].__name__))
        lags = [list(self._lags.get(k, ())) for k in keys]
        intervals = [list(self._intervals.get(k, ())) for k in keys]
        return {
            "senders": np.array([k[0] for k in keys], np.int64),
            "kinds": np.array([k[1].__name__ for k in keys], dtype="U32"),
            "counts": np.array([[len(a), len(b)] for a, b in zip(lags, intervals, strict=True)])
            .astype(np.int64)
            .reshape(-1, 2),
            "lags_ns": np.array([x for a in lags for x in a], np.int64),
            "intervals_ns": np.array([x for b in intervals for x in b], np.int64),
        }

    def load_state_dict(self, state: dict[str, np.ndarray]) -> None:
        """Take the lags and intervals of :meth:`state_dict` (a malformed state: ValueError)."""
        kinds = {cls.__name__: cls for cls in (MapIdsMessage, CommonMarginalMessage)}
        senders, names, counts = state["senders"], state["kinds"], state["counts"]
        values, gaps = np.asarray(state["lags_ns"]), np.asarray(state["intervals_ns"])
        counts = np.asarray(counts, np.int64).reshape(-1, 2)
        if not len(senders) == len(names) == len(counts) or np.any(counts < 0):
            raise ValueError("message lags: senders, kinds and counts of different lengths")
        if counts[:, 0].sum() != values.size or counts[:, 1].sum() != gaps.size:
            raise ValueError("message lags: the counts do not add up to the lags kept")
        lags: dict[tuple[int, type], deque[int]] = {}
        intervals: dict[tuple[int, type], deque[int]] = {}
        a = b = 0
        for sender, name, (n_lags, n_intervals) in zip(senders, names, counts, strict=True):
            if str(name) not in kinds:
                raise ValueError(f"message lags: unknown message kind {str(name)!r}")
            key = (int(sender), kinds[str(name)])
            lags[key] = deque((int(x) for x in values[a : a + n_lags]), maxlen=self.window)
            if n_intervals:
                intervals[key] = deque(
                    (int(x) for x in gaps[b : b + n_intervals]), maxlen=self.window
                )
            a, b = a + n_lags, b + n_intervals
        self._lags, self._intervals = lags, intervals
        self._learned.clear()

    def stale(self, sender: int, kind: type, age: MessageAge) -> bool:
        """Whether ``sender``'s newest ``kind`` message seen is too old at ``age`` (it was
        heard, but nothing of an accepted age)."""
        latest = self._latest.get((sender, kind))
        return latest is not None and age.expired(latest)


@dataclass(frozen=True)
class MessageAge:
    """Which messages an exchange accepts, by age.

    By step (``max_age_ns`` is ``None``): those of steps ``step − max_age`` to ``step``; a
    step counts the frames a robot processed, the same for every robot of a team that
    processes every frame. By stamp: those sent at a frame stamped ``stamp_ns − limit`` or
    later — robots that drop frames (live, asynchronous) process different numbers of frames,
    and only the stamps of their frames are comparable; ``limit`` is ``max_age_ns``, or with
    ``lags`` the age learned from the sender's lags when longer
    (:meth:`MessageLags.limit_ns`). A message of a later stamp (a neighbour ahead in time) is
    fresher, not stale: it is accepted.
    """

    step: int
    max_age: int
    stamp_ns: int | None = None
    max_age_ns: int | None = None
    lags: MessageLags | None = None

    def __post_init__(self) -> None:
        if self.max_age_ns is not None and self.stamp_ns is None:
            raise ValueError("ageing messages by stamp needs the current frame's stamp")

    @property
    def by_stamp(self) -> bool:
        """Whether messages are aged by their frame's stamp (else by step)."""
        return self.max_age_ns is not None

    def limit_ns(self, message: Message) -> int:
        """Aged by stamp: the oldest age in ns accepted of ``message``'s sender and kind."""
        if self.lags is None:
            return self.max_age_ns
        return self.lags.limit_ns(message.sender, type(message), self.max_age_ns)

    def expired(self, message: Message) -> bool:
        """Whether ``message`` is older than accepted (one of a later step or stamp is not;
        by stamp, one without a stamp is judged by :meth:`problem`)."""
        if self.by_stamp:
            stamp = message.stamp_ns
            return stamp is not None and stamp < self.stamp_ns - self.limit_ns(message)
        return self.step - message.step > self.max_age

    def problem(self, message: Message) -> str | None:
        """Why ``message`` cannot be used at this age (``None``: it can)."""
        if self.by_stamp:
            if message.stamp_ns is None:
                return (
                    f"message of step {message.step} without a frame stamp (robots that drop "
                    "frames age messages by it)"
                )
            if self.expired(message):
                return (
                    f"message of stamp {message.stamp_ns} ns at {self.stamp_ns} ns, older than "
                    f"{self.limit_ns(message) / 1e9:g} s"
                )
            return None
        if not self.step - self.max_age <= message.step <= self.step:
            return f"message of step {message.step} at {self.step}"
        return None
