"""teamslam's wire format for consensus messages: versioned, compact, validated binary.

A fixed little-endian header (magic ``b"TSLM"``, :data:`FORMAT_VERSION`, kind, degree, team
id, sender, receiver, step, sizes), the sender's frame stamp when the kind says so
(:data:`STAMPED`: messages of robots that drop frames), then the payload: ids as LEB128 varint
deltas, then moved flags, or a mean and the upper triangle of a covariance or information
matrix in float64 or float32, object summaries (with class labels, with appearance descriptors
in int8 codes and a histogram of same-object distances in varints), or a prior, by kind.
Older versions are refused by name. No pickle, no code: :func:`decode` checks every field and
raises :class:`WireError` naming the first problem, and a transport drops and counts such a
message.
Byte by byte: the docs' reference page *Wire format*.
"""

from __future__ import annotations

import hashlib
import struct

import numpy as np

from teamslam.association.appearance import BINS
from teamslam.association.summary import ObjectSummary, descriptor_codes
from teamslam.errors import InputError
from teamslam.msckf.consensus.messages import (
    CommonMarginalMessage,
    MapIdsMessage,
    Message,
    decode_ids,
    encode_ids,
)

__all__ = ["FORMAT_VERSION", "MAX_MESSAGE_BYTES", "WireError", "decode", "encode", "team_id"]

MAGIC = b"TSLM"
FORMAT_VERSION = 8
KIND_IDS = 1
KIND_IDS_SUMMARY = 8  # 9: with class labels
KIND_IDS_APPEARANCE = 12  # a summary with appearance; 13: with class labels too
_IDS_KINDS = (
    KIND_IDS,
    KIND_IDS_SUMMARY,
    KIND_IDS_SUMMARY + 1,
    KIND_IDS_APPEARANCE,
    KIND_IDS_APPEARANCE + 1,
)
#: bytes per object of a summary by kind (without its appearance)
_PER_SUMMARY = {KIND_IDS: 0, 8: 84, 9: 92, 12: 84, 13: 92}
#: an appearance block: its dimension (uint16), then n × D int8 codes, then BINS counts as
#: LEB128 varints
_APPEARANCE_HEAD = struct.Struct("<H")
MAX_APPEARANCE = 4096
KIND_MARGINAL = 2  # joint float64; 3 joint float32; 4 per object float64; 5 per object float32
# (per object, float32, information form) → kind
_MARGINAL_KINDS = {
    (False, False, False): 2,
    (False, True, False): 3,
    (True, False, False): 4,
    (True, True, False): 5,
    (False, False, True): 6,
    (False, True, True): 7,
}
KIND_PRIOR = 10  # joint information matrix with the sender's prior, float64; 11: float32
_TRIU3 = np.triu_indices(3)
HEADER = struct.Struct("<4sBBHQHHIIII")  # HEADER_BYTES long
#: a kind with this bit set: the message's frame stamp (int64 ns) follows the header
STAMPED = 0x80
STAMP = struct.Struct("<q")  # STAMP_BYTES long
MAX_MESSAGE_BYTES = 16 * 1024 * 1024
MAX_IDS = 100_000


class WireError(InputError):
    """A received message that cannot be used; the message names the reason."""


def team_id(name: str) -> int:
    """64-bit id of a team name (the first 8 bytes of its SHA-256)."""
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "little")


def encode(message: Message, team: int) -> bytes:
    """Serialise a message."""
    ids = np.asarray(message.ids, dtype=np.int64)
    try:
        id_bytes = encode_ids(ids)
    except ValueError as error:
        raise WireError(f"cannot encode the ids: {error}") from error
    if isinstance(message, MapIdsMessage):
        flags = b""
        if message.moved is not None:
            moved = np.asarray(message.moved, dtype=bool)
            if moved.shape != ids.shape:
                raise WireError(f"{moved.size} moved flags for {ids.size} ids")
            flags = np.packbits(moved, bitorder="little").tobytes()
        kind, summary, partial = KIND_IDS, b"", 0
        if message.summary is not None:
            held = ids
            if not np.array_equal(message.summary.ids, ids):
                # a summary of some of the ids (those new to the link): one bit per id says which
                mask = np.isin(ids, message.summary.ids)
                held, partial = ids[mask], 1
            kind, summary = _encode_summary(message.summary, held)
            if partial:
                summary = np.packbits(mask, bitorder="little").tobytes() + summary
        header = HEADER.pack(
            MAGIC,
            FORMAT_VERSION,
            kind | _stamped(message),
            partial,
            team,
            message.sender,
            message.receiver,
            message.step,
            ids.size,
            len(id_bytes),
            len(flags),
        )
        return header + _stamp(message) + id_bytes + flags + summary
    per_object, single = message.per_object, message.single_precision
    information = message.info is not None
    dtype = "<f4" if single else "<f8"
    mean = np.ascontiguousarray(message.mean, dtype=dtype)
    d = mean.size
    matrix = np.asarray(message.matrix, dtype=dtype)
    upper = matrix[:, _TRIU3[0], _TRIU3[1]].ravel() if per_object else matrix[np.triu_indices(d)]
    kind = _MARGINAL_KINDS[per_object, single, information]
    prior = b""
    if message.has_prior:
        kind = KIND_PRIOR + int(single)
        prior = _encode_prior(message, ids.size, dtype)
    header = HEADER.pack(
        MAGIC,
        FORMAT_VERSION,
        kind | _stamped(message),
        min(int(message.degree), 0xFFFF),
        team,
        message.sender,
        message.receiver,
        message.step,
        ids.size,
        len(id_bytes),
        d,
    )
    return header + _stamp(message) + id_bytes + mean.tobytes() + upper.tobytes() + prior


def _stamped(message: Message) -> int:
    """The kind's :data:`STAMPED` bit of a message."""
    return 0 if message.stamp_ns is None else STAMPED


def _stamp(message: Message) -> bytes:
    """The frame stamp's bytes of a message (none without one)."""
    if message.stamp_ns is None:
        return b""
    try:
        return STAMP.pack(int(message.stamp_ns))
    except struct.error as error:
        raise WireError(f"frame stamp {message.stamp_ns} does not fit 64 bits") from error


def _encode_prior(message: CommonMarginalMessage, n: int, dtype: str) -> bytes:
    """Flags, mean and information matrix's upper triangle of a marginal's prior."""
    held = np.asarray(message.prior_held, dtype=bool)
    if held.shape != (n,):
        raise WireError(f"{held.size} prior flags for {n} ids")
    mean = np.ascontiguousarray(message.prior_mean, dtype=dtype)
    h = 3 * int(held.sum())
    info = np.asarray(message.prior_info, dtype=dtype)
    if mean.shape != (h,) or info.shape != (h, h):
        raise WireError(f"a prior of {h // 3} flagged objects with mean {mean.shape}")
    flags = np.packbits(held, bitorder="little").tobytes()
    return flags + mean.tobytes() + info[np.triu_indices(h)].tobytes()


def _decode_prior(
    data: bytes, offset: int, n: int, dtype: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`_encode_prior` from ``offset`` to the end of ``data``."""
    flag_bytes = (n + 7) // 8
    width = np.dtype(dtype).itemsize
    if len(data) < offset + flag_bytes:
        raise WireError("truncated prior flags")
    bits = np.frombuffer(data, dtype=np.uint8, count=flag_bytes, offset=offset)
    held = np.unpackbits(bits, count=n, bitorder="little").astype(bool)
    h = 3 * int(held.sum())
    expected = offset + flag_bytes + width * (h + h * (h + 1) // 2)
    if len(data) != expected:
        raise WireError(f"length {len(data)} bytes, the prior's flags say {expected}")
    offset += flag_bytes
    mean = np.frombuffer(data, dtype=dtype, count=h, offset=offset).astype(float)
    values = np.frombuffer(data, dtype=dtype, count=h * (h + 1) // 2, offset=offset + width * h)
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(values))):
        raise WireError("non-finite prior mean or information matrix")
    info = np.zeros((h, h))
    info[np.triu_indices(h)] = values
    return held, mean, info + np.triu(info, 1).T


def _encode_summary(summary: ObjectSummary, ids: np.ndarray) -> tuple[int, bytes]:
    """Kind and bytes of an object summary riding on a map-ids message: of ``ids`` (the
    message's, or those of them its bit mask names), in their order."""
    if not np.array_equal(summary.ids, ids):
        raise WireError("an object summary must hold the message's ids, in their order")
    means = np.ascontiguousarray(summary.means, dtype="<f8")
    upper = np.ascontiguousarray(summary.covs[:, _TRIU3[0], _TRIU3[1]], dtype="<f8")
    views = np.zeros((ids.size, 3)) if summary.views is None else summary.views
    out = means.tobytes() + upper.tobytes() + np.ascontiguousarray(views, "<f4").tobytes()
    kind = KIND_IDS_SUMMARY
    if summary.classes is not None:
        kind += 1
        out += np.ascontiguousarray(summary.classes, "<i8").tobytes()
    if summary.appearance is None:
        return kind, out
    dim = summary.appearance.shape[1]
    if dim > MAX_APPEARANCE:
        raise WireError(f"appearance of {dim} dimensions (at most {MAX_APPEARANCE})")
    looks = descriptor_codes(summary.appearance).tobytes()
    counts = _encode_counts(summary.same_counts)
    kind += KIND_IDS_APPEARANCE - KIND_IDS_SUMMARY
    return kind, out + _APPEARANCE_HEAD.pack(dim) + looks + counts


def _encode_counts(counts: np.ndarray) -> bytes:
    """Non-negative counts (below 2³²) as LEB128 varints, 7 bits a byte, low bits first."""
    out = bytearray()
    for value in np.asarray(counts, dtype=np.int64).tolist():
        while value >= 0x80:
            out.append((value & 0x7F) | 0x80)
            value >>= 7
        out.append(value)
    return bytes(out)


def _counts_end(data: bytes, offset: int) -> int:
    """Where the :data:`BINS` varint counts starting at ``offset`` end."""
    raw = np.frombuffer(data, dtype=np.uint8, offset=min(offset, len(data)))
    ends = np.flatnonzero(raw < 0x80)
    if ends.size < BINS:
        raise WireError(f"truncated appearance histogram ({len(data)} bytes)")
    return offset + int(ends[BINS - 1]) + 1


def _appearance_size(data: bytes, offset: int, n: int) -> int:
    """Bytes of the appearance block at ``offset`` (its dimension and histogram read from
    it)."""
    if len(data) < offset + _APPEARANCE_HEAD.size:
        raise WireError(f"truncated appearance ({len(data)} bytes, its header at {offset})")
    (dim,) = _APPEARANCE_HEAD.unpack_from(data, offset)
    if not 1 <= dim <= MAX_APPEARANCE:
        raise WireError(f"appearance of {dim} dimensions (1 to {MAX_APPEARANCE})")
    counts = offset + _APPEARANCE_HEAD.size + dim * n
    return _counts_end(data, counts) - offset


def _decode_appearance(data: bytes, offset: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    (dim,) = _APPEARANCE_HEAD.unpack_from(data, offset)
    offset += _APPEARANCE_HEAD.size
    codes = np.frombuffer(data, dtype=np.int8, count=dim * n, offset=offset)
    if np.any(codes == -128):
        raise WireError("an appearance code out of range (-128) in an object summary")
    offset += dim * n
    end = _counts_end(data, offset)
    raw = np.frombuffer(data, dtype=np.uint8, count=end - offset, offset=offset)
    ends = np.flatnonzero(raw < 0x80)
    starts = np.concatenate([[0], ends[:-1] + 1])
    if np.max(ends - starts + 1) > 5:
        raise WireError("an appearance count longer than 32 bits")
    position = np.arange(raw.size) - np.repeat(starts, ends - starts + 1)
    parts = (raw & 0x7F).astype(np.int64) << (7 * position)
    counts = np.add.reduceat(parts, starts)
    if counts.max(initial=0) > np.iinfo(np.uint32).max:
        raise WireError("an appearance count beyond 32 bits")
    return codes.reshape(n, dim).astype(float), counts


def _decode_summary(
    data: bytes, offset: int, sender: int, ids: np.ndarray, classes: bool, appearance: bool
) -> ObjectSummary:
    n = ids.size
    means = np.frombuffer(data, dtype="<f8", count=3 * n, offset=offset).astype(float)
    upper = np.frombuffer(data, dtype="<f8", count=6 * n, offset=offset + 24 * n).astype(float)
    views = np.frombuffer(data, dtype="<f4", count=3 * n, offset=offset + 72 * n).astype(float)
    labels = None
    if classes:
        labels = np.frombuffer(data, dtype="<i8", count=n, offset=offset + 84 * n).astype(np.int64)
    if not (np.all(np.isfinite(means)) and np.all(np.isfinite(upper))):
        raise WireError("non-finite object summary")
    if not np.all(np.isfinite(views)):
        raise WireError("non-finite camera positions in an object summary")
    looks = counts = None
    if appearance:
        looks, counts = _decode_appearance(data, offset + (92 if classes else 84) * n, n)
    covs = np.zeros((n, 3, 3))
    covs[:, _TRIU3[0], _TRIU3[1]] = upper.reshape(n, 6)
    covs = covs + np.triu(covs, 1).swapaxes(-1, -2)
    try:
        return ObjectSummary(
            sender, ids, means.reshape(n, 3), covs, labels, views.reshape(n, 3), looks, counts
        )
    except InputError as error:
        raise WireError(f"bad object summary: {error}") from error


def decode(data: bytes, team: int, n_robots: int, max_bytes: int = MAX_MESSAGE_BYTES) -> Message:
    """Parse and validate a message.

    Raises
    ------
    WireError
        Truncated, oversized, bad magic, unknown version or kind, another team, an unknown robot,
        sizes that disagree, ids that are not strictly increasing or non-finite numbers.
    """
    if len(data) > max_bytes:
        raise WireError(f"oversized message ({len(data)} bytes > {max_bytes})")
    if len(data) < HEADER.size:
        raise WireError(f"truncated header ({len(data)} of {HEADER.size} bytes)")
    magic, version, kind, degree, team_of, sender, receiver, step, n_ids, c, d = HEADER.unpack_from(
        data
    )
    if magic != MAGIC:
        raise WireError("not a teamslam message (bad magic)")
    if version != FORMAT_VERSION:
        if 1 <= version < FORMAT_VERSION:
            raise WireError(
                f"format version {version} is no longer read (this robot speaks version "
                f"{FORMAT_VERSION}: update the sender)"
            )
        raise WireError(f"unknown format version {version}")
    stamp_ns, base = None, HEADER.size
    if kind & STAMPED:
        kind &= ~STAMPED
        if len(data) < HEADER.size + STAMP.size:
            raise WireError(f"truncated frame stamp ({len(data)} bytes)")
        (stamp_ns,) = STAMP.unpack_from(data, HEADER.size)
        base += STAMP.size
    if team_of != team:
        raise WireError("message from another team")
    if sender >= n_robots or receiver >= n_robots:
        raise WireError(f"unknown robot (sender {sender}, receiver {receiver}, team of {n_robots})")
    if n_ids > MAX_IDS:
        raise WireError(f"too many ids ({n_ids})")
    if kind in _IDS_KINDS:
        if d not in (0, (n_ids + 7) // 8) or (n_ids == 0 and d != 0):
            raise WireError(f"map-ids message with {d} bytes of flags for {n_ids} ids")
        # the degree field of a map-ids message: 1 when its summary holds some of the ids
        if degree not in (0, 1) or (degree == 1 and kind == KIND_IDS):
            raise WireError("map-ids message with a degree")
        mask_bytes = (n_ids + 7) // 8 if degree == 1 else 0
        held = n_ids
        if degree == 1:
            if len(data) < base + c + d + mask_bytes:
                raise WireError(f"truncated summary mask ({len(data)} bytes)")
            bits = np.frombuffer(data, dtype=np.uint8, count=mask_bytes, offset=base + c + d)
            held = int(np.unpackbits(bits, bitorder="little")[:n_ids].sum())
        expected = base + c + d + mask_bytes + _PER_SUMMARY[kind] * held
        if kind >= KIND_IDS_APPEARANCE:
            expected += _appearance_size(data, expected, held)
    elif kind in _MARGINAL_KINDS.values() or kind in (KIND_PRIOR, KIND_PRIOR + 1):
        if d != 3 * n_ids or n_ids == 0:
            raise WireError(f"marginal of {n_ids} objects with mean length {d}")
        per_object, width = kind in (4, 5), 4 if kind in (3, 5, 7, KIND_PRIOR + 1) else 8
        information = kind in (6, 7, KIND_PRIOR, KIND_PRIOR + 1)
        upper = 6 * n_ids if per_object else d * (d + 1) // 2
        expected = base + c + width * (d + upper)
    else:
        raise WireError(f"unknown message kind {kind}")
    with_prior = kind in (KIND_PRIOR, KIND_PRIOR + 1)
    if len(data) != expected and not (with_prior and len(data) > expected):
        raise WireError(f"length {len(data)} bytes, header says {expected}")
    if not n_ids <= c <= 10 * n_ids:
        raise WireError(f"{c} bytes for {n_ids} ids")
    try:
        ids = decode_ids(np.frombuffer(data, dtype=np.uint8, count=c, offset=base), n_ids)
    except ValueError as error:
        raise WireError(f"bad ids: {error}") from error
    if kind in _IDS_KINDS:
        moved = None
        if d:
            bits = np.frombuffer(data, dtype=np.uint8, count=d, offset=base + c)
            moved = np.unpackbits(bits, count=n_ids, bitorder="little").astype(bool)
        summary, held_ids, offset = None, ids, base + c + d
        if degree == 1:
            bits = np.frombuffer(data, dtype=np.uint8, count=mask_bytes, offset=offset)
            mask = np.unpackbits(bits, bitorder="little").astype(bool)
            if mask[n_ids:].any():
                raise WireError("summary mask names ids the message does not hold")
            held_ids, offset = ids[mask[:n_ids]], offset + mask_bytes
        if kind != KIND_IDS:
            summary = _decode_summary(
                data,
                offset,
                int(sender),
                held_ids,
                kind in (KIND_IDS_SUMMARY + 1, KIND_IDS_APPEARANCE + 1),
                kind >= KIND_IDS_APPEARANCE,
            )
        return MapIdsMessage(int(sender), int(receiver), int(step), ids, moved, summary, stamp_ns)
    offset = base + c
    dtype = "<f4" if width == 4 else "<f8"
    mean = np.frombuffer(data, dtype=dtype, count=d, offset=offset).astype(float)
    values = np.frombuffer(data, dtype=dtype, count=upper, offset=offset + width * d)
    values = values.astype(float)
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(values))):
        raise WireError(
            "non-finite mean or " + ("information matrix" if information else "covariance")
        )
    if per_object:
        matrix = np.zeros((n_ids, 3, 3))
        matrix[:, _TRIU3[0], _TRIU3[1]] = values.reshape(n_ids, 6)
        matrix = matrix + np.triu(matrix, 1).swapaxes(-1, -2)
    else:
        matrix = np.zeros((d, d))
        matrix[np.triu_indices(d)] = values
        matrix = matrix + np.triu(matrix, 1).T
    head = (int(sender), int(receiver), int(step), ids, mean)
    if with_prior:
        held, prior_mean, prior_info = _decode_prior(data, expected, n_ids, dtype)
        return CommonMarginalMessage(
            *head,
            None,
            int(degree),
            info=matrix,
            prior_held=held,
            prior_mean=prior_mean,
            prior_info=prior_info,
            stamp_ns=stamp_ns,
        )
    if information:
        return CommonMarginalMessage(*head, None, int(degree), info=matrix, stamp_ns=stamp_ns)
    return CommonMarginalMessage(*head, matrix, int(degree), stamp_ns=stamp_ns)
