"""The seeds of the association: consistent sets from the candidates' own neighbourhoods.

When no maximum consistent set gathers an answer, every candidate pair with its shared
neighbourhood's consistent set (three pairs or more) fixes a transform; the transforms are ranked
by a bounding-sphere count of the objects they could gather
(:func:`~teamslam.association.kernels.gathered_objects`) and the best few are judged like the
consistent sets (:func:`~teamslam.association.gate.support`, :func:`~teamslam.association.mirror.
flipped`).
"""

from __future__ import annotations

import numpy as np

from teamslam.association.distances import nearest_neighbours
from teamslam.association.gate import support
from teamslam.association.kernels import gathered_objects
from teamslam.association.mirror import flipped
from teamslam.association.settings import AssociationSettings
from teamslam.association.summary import ObjectSummary
from teamslam.association.transform import rigid_transforms

__all__ = ["seed_sets"]


def seed_sets(
    a: ObjectSummary,
    b: ObjectSummary,
    ia: np.ndarray,
    ib: np.ndarray,
    members: np.ndarray,
    geo_a: tuple[np.ndarray, np.ndarray],
    geo_b: tuple[np.ndarray, np.ndarray],
    found: list,
    settings: AssociationSettings,
    looks: np.ndarray | None = None,
) -> tuple[list, int]:
    """Consistent sets seeded by the candidates' neighbourhoods, for a link whose largest
    consistent sets gathered no answer.

    Every candidate pair with two neighbour pairs or more in its shared neighbourhood's
    consistent set (``members``, from :func:`~teamslam.association.candidates.
    neighbourhood_sets`) fixes a transform (the pairs weighted alike); the transforms are
    ranked by :func:`~teamslam.association.kernels.gathered_objects` (most first, ties by
    order), and while one could gather ``min_inliers`` objects, those whose seed pair no earlier
    set's first gate passed go through :func:`~teamslam.association.gate.support`, up to
    ``rivals + 1`` of them (mirror images included).

    ``looks`` is the appearance term of the pairs' assignment cost (:func:`~teamslam.
    association.gate.support`), or ``None``.

    Returns
    -------
    sets, refused
        Entries for ``found`` (``rows, cols, transform, seed pairs' ids, seed indices``, as the
        consistent sets of :func:`~teamslam.association.answer.associate`), and the number
        refused as mirror images (:func:`~teamslam.association.mirror.flipped`).
    """
    need = settings.min_inliers
    k = settings.neighbours
    if ia.size == 0:
        return [], 0
    mem = members[ia, ib]  # (h, k): i · k_b + j, -1 beyond the set
    valid = mem >= 0
    score_ok = valid.sum(axis=1) >= 2  # with the anchor, three pairs fix a transform
    if not score_ok.any():
        return [], 0
    xs, ys, mem, valid = ia[score_ok], ib[score_ok], mem[score_ok], valid[score_ok]
    near_a, near_b = nearest_neighbours(geo_a[0], k), nearest_neighbours(geo_b[0], k)
    k_b = near_b.shape[1]  # fewer than k in a map of k objects or fewer
    slot_a, slot_b = np.where(valid, mem // k_b, 0), np.where(valid, mem % k_b, 0)
    rows = np.concatenate([xs[:, None], near_a[xs[:, None], slot_a]], axis=1)
    cols = np.concatenate([ys[:, None], near_b[ys[:, None], slot_b]], axis=1)
    weight = np.concatenate([np.ones((xs.size, 1)), valid.astype(float)], axis=1)
    t = rigid_transforms(a.means[rows], b.means[cols], weight)
    reach = gathered_objects(
        np.ascontiguousarray(t[:, :3, :3]),
        np.ascontiguousarray(t[:, :3, 3]),
        a.means,
        b.means,
        a.top_variances(),
        b.top_variances(),
        settings.gate_threshold,
    )
    explained = np.zeros((len(a), len(b)), dtype=bool)
    for rows_f, cols_f, *_ in found:
        explained[rows_f, cols_f] = True
    out, refused = [], 0
    for h in np.lexsort((np.arange(reach.size), -reach)):  # most reach first, ties by order
        if reach[h] < need or len(out) + refused > settings.rivals:
            break
        if explained[xs[h], ys[h]]:
            continue
        seed = weight[h] > 0
        ca, cb = rows[h][seed], cols[h][seed]
        got_rows, got_cols, t_h, passed = support(a, b, ca, cb, settings, looks)
        explained |= passed
        if got_rows.size >= need and flipped(a, b, got_rows, got_cols, t_h, settings):
            refused += 1
            continue
        out.append((got_rows, got_cols, t_h, np.column_stack([a.ids[ca], b.ids[cb]]), (ca, cb)))
    return out, refused
