"""From where a robot saw each of its objects: the views of its object summaries.

:class:`ObjectViews` keeps, per object, the sum of the unit directions from the object to the
camera over the frames it was observed, and their count; :meth:`ObjectViews.of` gives their
mean, with which association refuses a group matched to its mirror image
(:func:`~teamslam.association.flipped`). Recorded once per frame (:meth:`ObjectViews.record`).
See the concept page *Tracking* (``docs/concepts/tracking.md``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from teamslam.errors import InputError

__all__ = ["ObjectViews"]


class ObjectViews:
    """Per object: the directions from it to the cameras that observed it (see the module)."""

    def __init__(self) -> None:
        # id -> (Σ unit directions object → camera, observations)
        self._record: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return len(self._record)

    @property
    def ids(self) -> np.ndarray:
        """The objects with a view on record, increasing."""
        return np.array(sorted(self._record), dtype=np.int64)

    def record(
        self,
        frame: int,
        R_world_cam: np.ndarray,
        intrinsics: np.ndarray,
        history: Mapping[int, Sequence[tuple[int, np.ndarray]]],
    ) -> None:
        """Add to each object observed at ``frame`` the unit direction from it to the camera.

        The direction is the measurement's: the left image's bearing of the object, turned into
        the world frame by the camera's orientation ``R_world_cam``, reversed. Neither the
        camera's position nor the object's (which an update or consensus moves) enters, only
        the camera's orientation and what the image shows: whether the object was seen from
        above or below. Call once per frame.

        Parameters
        ----------
        frame
            The frame whose observations count (an object's newest observation must be of it).
        R_world_cam
            The left camera's orientation at ``frame`` (3×3).
        intrinsics
            The left camera's ``K`` (3×3).
        history
            Per object id its observations ``(frame, (u_l, v_l, u_r, v_r))``, oldest first.
        """
        k_inv = np.linalg.inv(intrinsics)
        for oid, observations in history.items():
            if not observations:
                continue
            seen, z = observations[-1]
            if seen != frame:
                continue
            bearing = R_world_cam @ (k_inv @ np.array([z[0], z[1], 1.0]))
            entry = self._record.setdefault(int(oid), np.zeros(4))
            entry[:3] -= bearing / np.linalg.norm(bearing)
            entry[3] += 1.0

    def of(self, ids: np.ndarray) -> np.ndarray:
        """Per object of ``ids``: the mean unit direction from it to the cameras that observed
        it (zeros where none is on record: :func:`~teamslam.association.flipped` then cannot
        use it). ``(n, 3)``."""
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        out = np.zeros((ids.size, 3))
        for k, oid in enumerate(ids.tolist()):
            entry = self._record.get(oid)
            if entry is not None:
                out[k] = entry[:3] / entry[3]
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        """The record as arrays: ``ids`` ``(n,)`` and ``sums`` ``(n, 4)`` (the directions' sum
        and the count) — :meth:`from_arrays` restores it."""
        ids = self.ids
        sums = np.array([self._record[i] for i in ids.tolist()], dtype=float).reshape(-1, 4)
        return {"ids": ids, "sums": sums}

    @classmethod
    def from_arrays(cls, ids: np.ndarray, sums: np.ndarray) -> ObjectViews:
        """The record :meth:`arrays` gave.

        Raises
        ------
        InputError
            Shapes that do not match, or a count that is not positive.
        """
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        sums = np.asarray(sums, dtype=float)
        if sums.shape != (ids.size, 4):
            raise InputError(f"views: {ids.size} ids need ({ids.size}, 4) sums, got {sums.shape}")
        if not np.all(np.isfinite(sums)) or np.any(sums[:, 3] <= 0):
            raise InputError("views: sums must be finite with positive counts")
        out = cls()
        out._record = {int(i): row.copy() for i, row in zip(ids.tolist(), sums, strict=True)}
        return out

    def merge(self, new: int, old: int) -> None:
        """Object ``new`` is object ``old`` seen again: its views count as ``old``'s."""
        entry = self._record.pop(int(new), None)
        if entry is None:
            return
        into = self._record.setdefault(int(old), np.zeros(4))
        into += entry
