"""A detector's boxes for one image, and readers of the files detectors write.

:class:`ImageDetections` is what the front-end takes from any detector: per image, axis-aligned
boxes in the left (and optionally right) raw image in pixels, a class label, a score in
``[0, 1]`` and optionally an embedding vector per box (a re-identification network's output).
Boxes carry no object id: which object a box shows is decided by the tracker and the
association.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ImageDetections"]


@dataclass(frozen=True)
class ImageDetections:
    """The boxes a detector found in one image.

    Attributes
    ----------
    boxes
        ``(M, 4)`` float64 ``(x_min, y_min, x_max, y_max)`` in pixels of the raw image
        (OpenCV convention: the top-left pixel's centre is ``(0, 0)``), inside the image.
    classes
        ``(M,)`` int64 class labels ``≥ 0``.
    scores
        ``(M,)`` float64 scores in ``[0, 1]`` (``1`` when the detector wrote none).
    embeddings
        ``(M, D)`` float32 per-box embedding vectors, or ``None``.
    """

    boxes: np.ndarray
    classes: np.ndarray
    scores: np.ndarray
    embeddings: np.ndarray | None = None

    @classmethod
    def empty(cls, dimension: int | None = None) -> ImageDetections:
        """No box (with ``(0, dimension)`` embeddings when ``dimension`` is given)."""
        emb = None if dimension is None else np.zeros((0, dimension), np.float32)
        return cls(np.zeros((0, 4)), np.zeros(0, np.int64), np.zeros(0), emb)

    def __len__(self) -> int:
        return len(self.boxes)
