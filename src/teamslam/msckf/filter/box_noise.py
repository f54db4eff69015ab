"""Measurement noise of an object's box centre from a detector: a share of the box's size.

A detection with a box size travels as a *box row* of :data:`BOX_COLUMNS` numbers
``(u_l, v_l, u_r, v_r, w, h, c_ul, c_vl, c_ur, c_vr)``: the stereo box centre, the box's width
and height (units of ``K``) and per centre coordinate ``1`` where the box touches the image
border along that coordinate's axis (clipped: the centre of the visible part lies inward of the
object's by half the hidden extent, unknown). A plain row holds the centre only.

Per coordinate the variance is ``σ₀² + (α·s)² + c·s²`` (:func:`box_variances`): ``σ₀`` is
``filter.object_std``, ``α`` ``filter.object_size_share``, ``s`` the box's size along the
coordinate's axis (``w`` for ``u``, ``h`` for ``v``) and ``c`` the clipped flag (a hidden part
up to twice the visible one, at one σ; for ``u`` plus half the disparity, squared). Plain rows
keep ``σ₀²``. Derivation: the concept page *Boxes* (``docs/concepts/boxes.md``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["BOX_COLUMNS", "box_rows", "box_size2", "box_variances", "is_box"]

#: Width of a box row: the centre (4), the size (2), the clipped flags (4).
BOX_COLUMNS = 10
#: How many edge σ from the border an edge may lie and still count as the border's.
CLIP_EDGE_SIGMAS = 2.0


def is_box(rows: np.ndarray) -> bool:
    """Whether ``rows`` (``(..., 4)`` or ``(..., BOX_COLUMNS)``) are box rows."""
    return np.shape(rows)[-1] == BOX_COLUMNS


def box_size2(rows: np.ndarray) -> np.ndarray:
    """``(..., 4)`` squared box size along each centre coordinate's axis (``w², h², w², h²``)."""
    size = rows[..., 4:6]
    return np.concatenate([size, size], axis=-1) ** 2


def box_variances(rows: np.ndarray, std: float, share: float) -> np.ndarray:
    """``(..., 4)`` variance of each centre coordinate of box rows (module docstring)."""
    size2 = box_size2(rows)
    out = std**2 + (share**2 + rows[..., 6:10]) * size2
    # the hidden extents of the two images differ by the disparity: so may their centres' bias
    half_disparity2 = 0.25 * (rows[..., 0] - rows[..., 2]) ** 2
    out[..., 0] += rows[..., 6] * half_disparity2
    out[..., 2] += rows[..., 8] * half_disparity2
    return out


def box_rows(
    z: np.ndarray,
    sizes: np.ndarray,
    image_size: tuple[int, int] | None,
    std: float,
    share: float,
) -> np.ndarray:
    """Box rows of detections ``z`` (``(D, 4)``) with box sizes ``sizes`` (``(D, 2)``).

    A coordinate is clipped when an edge of its box lies within :data:`CLIP_EDGE_SIGMAS` edge
    σ (``√2`` times the centre's unclipped σ, one pixel at least) of the image's border
    ``[-0.5, W - 0.5] × [-0.5, H - 0.5]``: the border cut the box there, or the detector's
    noise moved its edge just inside. The right image's box is taken as wide as the left one's.
    Without ``image_size`` no box counts as clipped.
    """
    z = np.asarray(z, dtype=float)
    sizes = np.asarray(sizes, dtype=float)
    rows = np.zeros((z.shape[0], BOX_COLUMNS))
    rows[:, :4] = z
    rows[:, 4:6] = sizes
    if image_size is None or not z.shape[0]:
        return rows
    width, height = image_size
    sigma = np.sqrt(std**2 + (share * sizes) ** 2)  # (D, 2): u, v
    margin = -0.5 + np.maximum(CLIP_EDGE_SIGMAS * np.sqrt(2.0) * sigma, 1.0)
    half = 0.5 * sizes
    for column, axis, extent in ((0, 0, width), (1, 1, height), (2, 0, width), (3, 1, height)):
        centre = z[:, column]
        low = centre - half[:, axis] <= margin[:, axis]
        high = centre + half[:, axis] >= extent - 1.0 - margin[:, axis]
        rows[:, 6 + column] = low | high
    # a box cut at the top or bottom is cut in both images (the same rows after rectification)
    v_cut = np.maximum(rows[:, 7], rows[:, 9])
    rows[:, 7] = rows[:, 9] = v_cut
    return rows
