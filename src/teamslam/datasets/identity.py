"""Object ids without an oracle: give each robot its own numbering, keep the identity as truth.

Team datasets from instance annotations or from a simulator carry *global* object ids: an object
seen by three robots has the same id in all three. A real team has no such oracle — each robot's
tracker numbers its own objects. :func:`strip_object_ids` turns a global-id dataset into one with
*per-robot* ids: every robot's objects get fresh ids, and which per-robot ids are the same object
is kept in :attr:`~teamslam.datasets.model.TeamDataset.object_identity` — ground truth, like the
object positions, for evaluation only.

The fresh ids are drawn at random (seeded) from a range far larger than the number of objects
and are *disjoint across robots*: a filter that still matched objects by equal ids finds nothing
in common (instead of averaging unrelated objects), and the ground-truth map keyed by id stays
unambiguous — it holds one row per per-robot id, and equal positions mean the same object.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from teamslam.datasets.model import DatasetError, FrameDetections, FrameObservations, TeamDataset

__all__ = ["oracle_object_ids", "strip_object_ids"]

#: Fresh ids are drawn from ``[1, ID_RANGE_FACTOR · objects)`` (at least ``[1, 10⁶)``).
ID_RANGE_FACTOR = 1000


def strip_object_ids(dataset: TeamDataset, to: str = "per-robot", seed: int = 0) -> TeamDataset:
    """The same team with each robot's objects renumbered on their own.

    Parameters
    ----------
    dataset
        A dataset with ``global`` object ids.
    to
        The new scope: ``"per-robot"``, or ``"none"`` — no ids at all: every robot's object
        observations become detections (:class:`~teamslam.datasets.model.FrameDetections`, the
        class labels kept) whose ground truth is the team object id, and each robot's filter
        tracks them itself (a dataset whose robots already carry detections, e.g. simulated
        with clutter, keeps those).
    seed
        Seed of the fresh ids (the same seed gives the same dataset).

    Returns
    -------
    TeamDataset
        Observations, class labels and per-object appearance under the new ids (no id shared
        by two robots), the ground-truth map keyed by the new ids, ``object_id_scope =
        "per-robot"`` and the identity ``(robot, new id, old id)`` in ``object_identity``.

    Raises
    ------
    DatasetError
        When ``to`` is not ``"per-robot"`` or the ids are not global.
    """
    if to == "none":
        return _strip_to_none(dataset)
    if to != "per-robot":
        raise DatasetError(
            f"strip_object_ids can only renumber to 'per-robot' ids or remove them ('none'), "
            f"not {to!r}"
        )
    if dataset.object_id_scope != "global":
        raise DatasetError(
            f"object ids are already {dataset.object_id_scope!r}; only global ids can be stripped"
        )
    rng = np.random.default_rng(seed)
    own = [np.unique(r.objects.ids) for r in dataset.robots]
    total = sum(ids.size for ids in own)
    high = max(ID_RANGE_FACTOR * total, 10**6)
    fresh = rng.choice(high - 1, size=total, replace=False).astype(np.int64) + 1
    robots, identity = [], []
    start = 0
    for i, (robot, old) in enumerate(zip(dataset.robots, own, strict=True)):
        new = fresh[start : start + old.size]
        start += old.size
        # old ids are sorted, new ones random: the order of the new ids says nothing either
        renumber = _renumber(old, new)
        obs = robot.objects
        objects = FrameObservations(obs.offsets, renumber(obs.ids), obs.measurements)
        classes = robot.object_classes
        if classes is not None:
            classes = classes[np.isin(classes[:, 0], old)]
            classes = np.column_stack([renumber(classes[:, 0]), classes[:, 1]])
        looks_ids, looks = robot.object_appearance_ids, robot.object_appearance
        if looks is not None:
            seen = np.isin(looks_ids, old)
            looks_ids, looks = renumber(looks_ids[seen]), looks[seen]
        robots.append(
            replace(
                robot,
                objects=objects,
                object_classes=classes,
                object_appearance_ids=looks_ids,
                object_appearance=looks,
            )
        )
        identity.append(np.column_stack([np.full(old.size, i), new, old]))
    identity_rows = np.concatenate(identity).astype(np.int64).reshape(-1, 3)
    truth = dataset.object_position(identity_rows[:, 2])
    known = np.all(np.isfinite(truth), axis=1)
    metadata = dict(dataset.metadata)
    metadata["object_ids"] = {"stripped_from": "global", "seed": int(seed)}
    return replace(
        dataset,
        robots=robots,
        object_ids=identity_rows[known, 1],
        object_positions=truth[known],
        metadata=metadata,
        object_id_scope="per-robot",
        object_identity=identity_rows,
    )


def oracle_object_ids(dataset: TeamDataset) -> TeamDataset:
    """The same team given the true object of every detection: the oracle beside which own
    tracking and association are scored.

    Every robot's detections with a true object (``truth ≥ 0``) and a stereo measurement
    become its object observations under the team object id (the first of two boxes of one
    object in a frame); false boxes are left out; each object's class is the one its boxes
    give most often. The detections stay (with ids the filter does not read them).

    Raises
    ------
    DatasetError
        When the ids are not ``none`` or a robot's detections carry no truth.
    """
    if dataset.object_id_scope != "none":
        raise DatasetError("oracle ids need a dataset of detections without ids ('none')")
    robots = []
    for i, robot in enumerate(dataset.robots):
        det = robot.detections
        if det is None or det.truth is None:
            raise DatasetError(f"robot {i}: detections without truth; no oracle ids to give")
        frames, rows_ids, classes = [], [], []
        for k in range(det.frames):
            a, b = det.offsets[k], det.offsets[k + 1]
            truth, z = det.truth[a:b], det.measurements[a:b]
            keep = (truth >= 0) & np.all(np.isfinite(z), axis=1)
            ids, first = np.unique(truth[keep], return_index=True)
            frames.append((ids, z[keep][first]))
            if det.classes is not None:
                rows_ids.append(ids)
                classes.append(det.classes[a:b][keep][first])
        object_classes = None
        if det.classes is not None and rows_ids:
            ids, labels = np.concatenate(rows_ids), np.concatenate(classes)
            pairs, counts = np.unique(np.column_stack([ids, labels]), axis=0, return_counts=True)
            order = np.lexsort((-counts, pairs[:, 0]))  # by id, most frequent class first
            pairs = pairs[order]
            first = np.concatenate([[True], pairs[1:, 0] != pairs[:-1, 0]])
            object_classes = pairs[first].astype(np.int64).reshape(-1, 2)
        robots.append(
            replace(
                robot,
                objects=FrameObservations.from_frames(frames),
                object_classes=object_classes,
            )
        )
    return replace(dataset, robots=robots, object_id_scope="global")


def _strip_to_none(dataset: TeamDataset) -> TeamDataset:
    """Every robot's objects as detections without ids; the truth as team object ids."""
    if dataset.object_id_scope == "none":
        raise DatasetError("object ids are already removed ('none')")
    robots = []
    for i, robot in enumerate(dataset.robots):
        detections = robot.detections
        if detections is None:
            ids, team = dataset.true_objects(i)
            truth = robot.objects.ids.copy()
            if dataset.object_id_scope == "per-robot":
                truth = np.full(robot.objects.ids.shape, -1, dtype=np.int64)
                if ids.size:
                    order = np.argsort(ids)
                    pos = np.clip(np.searchsorted(ids[order], robot.objects.ids), 0, ids.size - 1)
                    hit = ids[order[pos]] == robot.objects.ids
                    truth[hit] = team[order[pos[hit]]]
            detections = FrameDetections.from_observations(
                robot.objects, truth, robot.object_classes
            )
        robots.append(
            replace(
                robot,
                objects=FrameObservations.empty(robot.frames),
                object_classes=None,
                detections=detections,
                object_appearance_ids=None,
                object_appearance=None,
            )
        )
    object_ids, positions = dataset.object_ids, dataset.object_positions
    if dataset.object_id_scope == "per-robot" and dataset.object_identity.size:
        # the map keyed by team object ids (the truth of the detections)
        team, first = np.unique(dataset.object_identity[:, 2], return_index=True)
        truth = dataset.object_position(dataset.object_identity[first, 1])
        known = np.all(np.isfinite(truth), axis=1)
        object_ids, positions = team[known], truth[known]
    metadata = dict(dataset.metadata)
    metadata["object_ids"] = {"stripped_from": dataset.object_id_scope, "to": "none"}
    return replace(
        dataset,
        robots=robots,
        object_ids=object_ids,
        object_positions=positions,
        metadata=metadata,
        object_id_scope="none",
        object_identity=np.zeros((0, 3), np.int64),
    )


def _renumber(old: np.ndarray, new: np.ndarray):
    """A function mapping ids of ``old`` (sorted, unique) to the ``new`` id at the same place."""

    def apply(ids: np.ndarray) -> np.ndarray:
        ids = np.asarray(ids, dtype=np.int64)
        pos = np.searchsorted(old, ids)
        return new[pos].astype(np.int64) if ids.size else ids.copy()

    return apply
