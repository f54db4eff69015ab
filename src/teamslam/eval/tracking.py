"""How well each robot tracked its own object detections (against the truth of each detection).

Each detection's id, as the filter used it (:attr:`ObjectTracker.log
<teamslam.msckf.objects.tracking.ObjectTracker.log>`), is scored against the dataset's truth of
that detection (:attr:`~teamslam.datasets.model.FrameDetections.truth`): CLEAR-MOT
(``MOTA = 1 − (FN + FP + IDSW) / GT``, fragmentations; Bernardin & Stiefelhagen 2008), IDF1
(Ristani et al. 2016), and objects created against true objects detected (false objects
apart).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from teamslam.errors import InputError

__all__ = [
    "hypotheses_of",
    "identity_map",
    "idf1_losses",
    "merge_audit",
    "mot_metrics",
    "object_truth",
    "revisit_precision",
    "tracking_metrics",
]


def mot_metrics(offsets: np.ndarray, truth: np.ndarray, hypothesis: np.ndarray) -> dict:
    """CLEAR-MOT, IDF1 and object counts of one robot's detections.

    Parameters
    ----------
    offsets
        ``(frames + 1,)`` detection offsets per frame.
    truth
        ``(D,)`` team object id of each detection, ``-1`` for a false one.
    hypothesis
        ``(D,)`` object id the tracker gave each detection, ``-1`` for none.

    Returns
    -------
    dict
        ``gt``, ``fn``, ``fp``, ``id_switches``, ``fragmentations``, ``mota``, ``idtp``,
        ``idf1``, ``objects_true``, ``objects_created``, ``false_objects`` (ids given only to
        false detections), ``frames``.
    """
    offsets = np.asarray(offsets, dtype=np.int64)
    truth = np.asarray(truth, dtype=np.int64)
    hyp = np.asarray(hypothesis, dtype=np.int64)
    if truth.shape != hyp.shape or offsets[-1] != truth.size:
        raise ValueError(
            f"{truth.size} truths, {hyp.size} hypotheses and {offsets[-1]} detections disagree"
        )
    frame = np.repeat(np.arange(offsets.size - 1), np.diff(offsets))
    real, named = truth >= 0, hyp >= 0
    gt = int(real.sum())
    fn = int((real & ~named).sum())
    fp = int((~real & named).sum())
    # the true detections in the order of their object, then of time
    order = np.lexsort((frame[real], truth[real]))
    g, h = truth[real][order], hyp[real][order]
    matched = h >= 0
    same_object = np.concatenate([[False], g[1:] == g[:-1]])
    # identity switches: between consecutive matched detections of one object
    gm, hm = g[matched], h[matched]
    switches = int(np.sum((gm[1:] == gm[:-1]) & (hm[1:] != hm[:-1])))
    # fragmentations: matched runs of an object after its first one
    run_start = matched & ~(same_object & np.concatenate([[False], matched[:-1]]))
    starts_per_object = np.bincount(np.unique(g, return_inverse=True)[1], weights=run_start)
    fragmentations = int(np.sum(np.maximum(starts_per_object - 1, 0)))
    # IDF1: the best one-to-one map of true objects to ids
    both = real & named
    idtp = int(np.sum(identity_map(truth, hyp) == hyp) if both.any() else 0)
    hypotheses = int(named.sum())
    true_ids = set(np.unique(hyp[both]).tolist())
    created = np.unique(hyp[named])
    return {
        "frames": int(offsets.size - 1),
        "gt": gt,
        "fn": fn,
        "fp": fp,
        "id_switches": switches,
        "fragmentations": fragmentations,
        "mota": float(1.0 - (fn + fp + switches) / gt) if gt else float("nan"),
        "idtp": idtp,
        "idf1": float(2 * idtp / (gt + hypotheses)) if gt + hypotheses else float("nan"),
        "objects_true": int(np.unique(truth[real]).size),
        "objects_created": int(created.size),
        "false_objects": int(sum(1 for i in created.tolist() if i not in true_ids)),
    }


def identity_map(truth: np.ndarray, hyp: np.ndarray) -> np.ndarray:
    """Per detection the id its true object has under the one-to-one map of true objects to
    ids agreeing on the most detections (IDF1's map; Ristani et al. 2016).

    Parameters
    ----------
    truth, hyp
        ``(n,)`` per detection its true object (``-1``: false) and the id it was given
        (``-1``: none).

    Returns
    -------
    numpy.ndarray
        ``(n,)`` the id the map gives the detection's true object; ``-2`` for a false detection
        or an object the map leaves without an id. A detection was named rightly where it equals
        ``hyp``.
    """
    both = (truth >= 0) & (hyp >= 0)
    out = np.full(truth.size, -2, np.int64)
    if not both.any():
        return out
    gu, gi = np.unique(truth[both], return_inverse=True)
    hu, hi = np.unique(hyp[both], return_inverse=True)
    counts = np.zeros((gu.size, hu.size))
    np.add.at(counts, (gi, hi), 1.0)
    rows, cols = linear_sum_assignment(-counts)
    keep = counts[rows, cols] > 0
    mapped = np.full(gu.size, -2, np.int64)
    mapped[rows[keep]] = hu[cols[keep]]
    real = truth >= 0
    pos = np.clip(np.searchsorted(gu, truth[real]), 0, gu.size - 1)
    out[real] = np.where(gu[pos] == truth[real], mapped[pos], -2)
    return out


def idf1_losses(
    offsets: np.ndarray, truth: np.ndarray, hypothesis: np.ndarray, revisit_gap: int
) -> dict:
    """Where one robot's IDF1 is lost: ``GT + H − 2·IDTP = FN + FP + 2·(wrong ids)``.

    Parameters
    ----------
    offsets, truth, hypothesis
        As :func:`mot_metrics`.
    revisit_gap
        Frames: a true detection named with an id other than its object's (under IDF1's map)
        is a *revisit* loss when that id's detections of the object are all more than this
        many frames away (the object was left and seen again, and named anew), else a loss
        *within a pass* (a switch to a neighbour, a track lost and restarted, a merge).

    Returns
    -------
    dict
        ``missed`` (FN), ``false`` (FP), ``wrong_revisit``, ``wrong_within_pass``,
        ``wrong_unmapped`` (of an object IDF1's map leaves without an id), and ``loss``
        (``GT + H − 2·IDTP``).
    """
    offsets = np.asarray(offsets, dtype=np.int64)
    truth = np.asarray(truth, dtype=np.int64)
    hyp = np.asarray(hypothesis, dtype=np.int64)
    frame = np.repeat(np.arange(offsets.size - 1), np.diff(offsets))
    real, named = truth >= 0, hyp >= 0
    mapped = identity_map(truth, hyp)
    wrong = np.flatnonzero(real & named & (mapped != hyp))
    revisit = within = unmapped = 0
    for k in wrong.tolist():
        if mapped[k] < 0:
            unmapped += 1
            continue
        own = frame[(hyp == mapped[k]) & (truth == truth[k])]
        if np.min(np.abs(own - frame[k])) > revisit_gap:
            revisit += 1
        else:
            within += 1
    fn, fp = int((real & ~named).sum()), int((~real & named).sum())
    return {
        "missed": fn,
        "false": fp,
        "wrong_revisit": revisit,
        "wrong_within_pass": within,
        "wrong_unmapped": unmapped,
        "loss": fn + fp + 2 * int(wrong.size),
    }


def revisit_precision(
    offsets: np.ndarray,
    truth: np.ndarray,
    hypothesis: np.ndarray,
    revisits: list[tuple[int, int, int]],
) -> tuple[int, int]:
    """How many of a robot's re-identifications were right.

    Parameters
    ----------
    offsets, truth, hypothesis
        As :func:`mot_metrics`.
    revisits
        ``(frame, row of the frame's detections, object id)`` of each detection given to an
        object not seen for a while (:attr:`ObjectTracker.revisits
        <teamslam.msckf.objects.tracking.ObjectTracker.revisits>`).

    Returns
    -------
    tuple
        ``(right, judged)``: a re-identification is judged when the object's earlier detections
        (before that frame) include true ones, and right when the detection is of the true
        object most of them were.
    """
    offsets = np.asarray(offsets, dtype=np.int64)
    truth = np.asarray(truth, dtype=np.int64)
    hyp = np.asarray(hypothesis, dtype=np.int64)
    right = judged = 0
    for frame, row, oid in revisits:
        k = offsets[frame] + row
        before = truth[: offsets[frame]][(hyp[: offsets[frame]] == oid)]
        before = before[before >= 0]
        if not before.size:
            continue
        values, counts = np.unique(before, return_counts=True)
        judged += 1
        right += int(truth[k] == values[np.argmax(counts)])
    return right, judged


def merge_audit(truth: np.ndarray, first_ids: np.ndarray, merges: np.ndarray) -> dict:
    """How many of a robot's object merges (loop closure, re-identification) were right.

    A merge ``(new, old)`` joins two objects the tracker had named apart; it is judged by the
    detections each took under its own id (``first_ids``, before any merge renamed them), the
    old one's up to the new one's first: right when most of both are of one true object,
    wrong when of two (unjudged when either took only false detections). Merges of new
    objects into one old object whose detections are of one true object form a *pass*: a
    revisit that the tracker named anew several times and merged each time (``largest_pass``
    counts the merges of the largest one).

    Parameters
    ----------
    truth
        ``(D,)`` team object id of each detection, ``-1`` for a false one.
    first_ids
        ``(D,)`` the id the tracker gave each detection when it named it (``-1``: none):
        :attr:`ObjectTracker.log <teamslam.msckf.objects.tracking.ObjectTracker.log>`, not
        :meth:`~teamslam.msckf.objects.tracking.ObjectTracker.hypotheses`.
    merges
        ``(k, 2)`` ``(new id, old id)`` of each merge, in the order made.

    Returns
    -------
    dict
        ``merges``, ``right``, ``wrong``, ``unjudged``; ``passes`` and ``passes_wrong`` (the
        distinct ``(old id, true object of new)`` of the judged merges, and of the wrong ones);
        ``largest_pass``.
    """
    truth = np.asarray(truth, dtype=np.int64)
    first = np.asarray(first_ids, dtype=np.int64)
    if truth.shape != first.shape:
        raise InputError(f"{truth.size} detections but {first.size} ids")
    merges = np.asarray(merges, dtype=np.int64).reshape(-1, 2)
    ids, true_ids = object_truth(truth, first)
    of = dict(zip(ids.tolist(), true_ids.tolist(), strict=True))
    right = wrong = 0
    passes: dict[tuple[int, int], list[bool]] = {}
    for new, old in merges.tolist():
        a = of.get(new, -1)
        # the old object as it was: its detections before the new one's first
        seen = np.flatnonzero(first == new)
        end = seen[0] if seen.size else truth.size
        mine = truth[:end][first[:end] == old]
        mine = mine[mine >= 0]
        if a < 0 or not mine.size:
            continue
        values, counts = np.unique(mine, return_counts=True)
        b = int(values[np.argmax(counts)])
        right += int(a == b)
        wrong += int(a != b)
        passes.setdefault((old, a), []).append(a == b)
    return {
        "merges": int(merges.shape[0]),
        "right": right,
        "wrong": wrong,
        "unjudged": int(merges.shape[0]) - right - wrong,
        "passes": len(passes),
        "passes_wrong": sum(1 for v in passes.values() if not v[0]),
        "largest_pass": max((len(v) for v in passes.values()), default=0),
    }


def object_truth(truth: np.ndarray, hypothesis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which true object each object a robot's tracker named is: the one most of its
    detections are (``-1`` when most are false detections).

    Parameters
    ----------
    truth, hypothesis
        Per detection its true object (``-1``: false) and the id the tracker gave it (``-1``:
        none), as :func:`mot_metrics`.

    Returns
    -------
    ids, team_ids
        The tracker's ids and their true objects, the form of
        :meth:`~teamslam.datasets.model.TeamDataset.true_objects`.
    """
    truth = np.asarray(truth, dtype=np.int64)
    hyp = np.asarray(hypothesis, dtype=np.int64)
    if truth.shape != hyp.shape:
        raise InputError(f"{truth.size} detections but {hyp.size} hypotheses")
    named = hyp >= 0
    pairs, counts = np.unique(
        np.column_stack([hyp[named], truth[named]]), axis=0, return_counts=True
    )
    if not pairs.size:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # per id the row with the most detections (ties: the smaller true id, for determinism)
    order = np.lexsort((pairs[:, 1], -counts, pairs[:, 0]))
    first = np.r_[True, np.diff(pairs[order, 0]) != 0]
    best = pairs[order[first]]
    return best[:, 0].copy(), best[:, 1].copy()


def tracking_metrics(
    dataset, hypotheses: list[np.ndarray], records: list[dict] | None = None
) -> dict | None:
    """``metrics.json["tracking"]``: :func:`mot_metrics` per robot and over the team.

    Parameters
    ----------
    dataset
        The team dataset (each tracking robot's detections carry their truth).
    hypotheses
        Per robot the ids its tracker gave its detections (``(D_i,)``, ``-1`` for none; an
        empty array for a robot that did not track), e.g. :func:`hypotheses_of` of the agents.
    records
        Per robot what its driver recorded of its tracker
        (:meth:`~teamslam.msckf.team.RobotDriver.tracking_record`: the ids as first given,
        the merges, the overconfidence factor), or ``None``: then no merge audit.

    Returns
    -------
    dict or None
        ``{"robots": [...], "team": {...}, "false_objects_per_1000_frames": x}``; ``None``
        when no robot tracked detections with ground truth. With ``records`` each robot's
        entry also holds ``merges`` (:func:`merge_audit`) and ``object_overconfidence``, and
        the team's the merge counts summed.
    """
    robots, parts, audits = [], [], []
    for k, (robot, hyp) in enumerate(zip(dataset.robots, hypotheses, strict=True)):
        det = robot.detections
        if det is None or det.truth is None or hyp is None or hyp.size != det.truth.size:
            robots.append(None)
            continue
        robots.append(mot_metrics(det.offsets, det.truth, hyp))
        parts.append(robots[-1])
        record = records[k] if records is not None else {}
        first = np.asarray(record.get("tracking_first_ids", []), np.int64)
        if first.size == det.truth.size and "tracking_merges" in record:
            robots[-1]["merges"] = merge_audit(det.truth, first, record["tracking_merges"])
            robots[-1]["object_overconfidence"] = float(record.get("object_overconfidence", 1.0))
            audits.append(robots[-1]["merges"])
    if not parts:
        return None
    team = {
        k: sum(p[k] for p in parts)
        for k in parts[0]
        if k not in ("mota", "idf1", "merges", "object_overconfidence")
    }
    if audits and len(audits) == len(parts):
        team["merges"] = {
            k: (max if k == "largest_pass" else sum)(a[k] for a in audits) for k in audits[0]
        }
    team["mota"] = float(1 - (team["fn"] + team["fp"] + team["id_switches"]) / team["gt"])
    team["idf1"] = float(2 * team["idtp"] / (team["gt"] + team["gt"] - team["fn"] + team["fp"]))
    return {
        "robots": robots,
        "team": team,
        "false_objects_per_1000_frames": 1000.0 * team["false_objects"] / max(team["frames"], 1),
    }


def hypotheses_of(agents) -> list[np.ndarray]:
    """Per agent the ids its tracker gave each detection so far (empty without a tracker)."""
    return [
        np.zeros(0, np.int64) if agent.tracker is None else agent.tracker.hypotheses()
        for agent in agents
    ]
