"""Objects that left the filter state: a robot's persistent map (bounded cost over a mission).

With ``objects.retire_after = N > 0`` an object unobserved for ``N`` frames retires — exact
marginalisation: its mean, 3×3 marginal and first estimate are kept here — and re-enters the
state with them, without cross-covariance, when observed again. Retired objects are never sent
in consensus; with ``consensus.persistent_map = true`` they are averaged with the neighbours'
in-state marginals of them (:func:`teamslam.msckf.consensus.average.persistent_average`).
Storing or re-entering ``k`` objects costs ``O(k)``. Why, and what re-entry approximates: the
concept page *The persistent map* (``docs/concepts/persistent-map.md``).
"""

from __future__ import annotations

import numpy as np

from teamslam.errors import InputError, InternalError

__all__ = ["PersistentMap"]


class PersistentMap:
    """Retired objects: id → mean, 3×3 marginal covariance, first estimate."""

    def __init__(self, capacity: int = 64) -> None:
        capacity = max(int(capacity), 1)
        self._means = np.zeros((capacity, 3))
        self._covs = np.zeros((capacity, 3, 3))
        self._fe = np.zeros((capacity, 3))
        self._row: dict[int, int] = {}
        self._free: list[int] = list(range(capacity - 1, -1, -1))

    def __len__(self) -> int:
        return len(self._row)

    def __contains__(self, object_id: object) -> bool:
        return int(object_id) in self._row

    @property
    def capacity(self) -> int:
        """Rows allocated (at most twice the largest size the map has had, or 64)."""
        return self._means.shape[0]

    def contains(self, ids: np.ndarray) -> np.ndarray:
        """Whether each id is stored (boolean array shaped like ``ids``)."""
        ids = np.asarray(ids, dtype=np.int64)
        row = self._row
        return np.fromiter((i in row for i in ids.ravel().tolist()), bool, ids.size).reshape(
            ids.shape
        )

    def _grow(self, needed: int) -> None:
        old = self.capacity
        new = old
        while new - len(self._row) < needed:
            new *= 2
        if new == old:
            return
        for name in ("_means", "_covs", "_fe"):
            a = getattr(self, name)
            b = np.zeros((new, *a.shape[1:]))
            b[:old] = a
            setattr(self, name, b)
        self._free.extend(range(new - 1, old - 1, -1))

    def store(self, ids: np.ndarray, means: np.ndarray, covs: np.ndarray, fe: np.ndarray) -> None:
        """Keep objects ``ids`` with their means ``(k, 3)``, covariances ``(k, 3, 3)`` and first
        estimates ``(k, 3)`` (an id already stored is overwritten)."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        if ids.size == 0:
            return
        self._grow(ids.size)
        rows = np.empty(ids.size, dtype=np.int64)
        for k, i in enumerate(ids.tolist()):
            row = self._row.get(i)
            if row is None:
                row = self._free.pop()
                self._row[i] = row
            rows[k] = row
        self._means[rows] = means
        self._covs[rows] = covs
        self._fe[rows] = fe

    def take(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Remove stored objects ``ids`` (all must be stored) and return their means, covariances
        and first estimates."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        try:
            rows = np.array([self._row.pop(i) for i in ids.tolist()], dtype=np.int64)
        except KeyError as exc:
            raise InternalError(f"object {exc.args[0]} is not in the persistent map") from None
        self._free.extend(rows.tolist())
        return self._means[rows].copy(), self._covs[rows].copy(), self._fe[rows].copy()

    def get(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Means, covariances and first estimates of stored objects ``ids`` (copies)."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        rows = np.array([self._row[i] for i in ids.tolist()], dtype=np.int64)
        return self._means[rows].copy(), self._covs[rows].copy(), self._fe[rows].copy()

    def arrays(self) -> dict[str, np.ndarray]:
        """Every stored object, sorted by id: ``ids``, ``means``, ``covs``, ``fe``."""
        ids = np.array(sorted(self._row), dtype=np.int64)
        rows = np.array([self._row[i] for i in ids.tolist()], dtype=np.int64)
        return {
            "ids": ids,
            "means": self._means[rows].copy(),
            "covs": self._covs[rows].copy(),
            "fe": self._fe[rows].copy(),
        }

    @classmethod
    def from_arrays(
        cls, ids: np.ndarray, means: np.ndarray, covs: np.ndarray, fe: np.ndarray
    ) -> PersistentMap:
        """A map holding these objects, after checking that they fit together.

        Raises
        ------
        InputError
            Shapes that disagree, repeated ids, non-finite values or a covariance that is not
            symmetric positive definite.
        """
        ids = np.asarray(ids, dtype=np.int64).ravel()
        k = ids.size
        means = np.asarray(means, dtype=float).reshape(-1, 3)
        covs = np.asarray(covs, dtype=float).reshape(-1, 3, 3)
        fe = np.asarray(fe, dtype=float).reshape(-1, 3)
        if not means.shape[0] == covs.shape[0] == fe.shape[0] == k:
            raise InputError(
                f"persistent map: {k} ids for {means.shape[0]} means, {covs.shape[0]} "
                f"covariances, {fe.shape[0]} first estimates"
            )
        if np.unique(ids).size != k:
            raise InputError("persistent map: repeated object ids")
        if not all(np.all(np.isfinite(a)) for a in (means, covs, fe)):
            raise InputError("persistent map: non-finite values")
        if k:
            if not np.allclose(covs, np.swapaxes(covs, 1, 2), rtol=1e-9, atol=1e-12):
                raise InputError("persistent map: a covariance is not symmetric")
            if np.any(np.linalg.eigvalsh(covs)[:, 0] <= 0):
                raise InputError("persistent map: a covariance is not positive definite")
        out = cls(capacity=max(64, 2 * k))
        out.store(ids, means, covs, fe)
        return out

    def copy(self) -> PersistentMap:
        """An independent copy."""
        a = self.arrays()
        out = PersistentMap(capacity=max(64, 2 * a["ids"].size))
        out.store(a["ids"], a["means"], a["covs"], a["fe"])
        return out
