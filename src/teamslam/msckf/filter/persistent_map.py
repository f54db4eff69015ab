"""Objects that left the filter state: a robot's persistent map of consider states.

With ``objects.retire_after = N > 0`` (or a budget, ``objects.max_active``) an object unobserved
for a while retires: it leaves the filter's active state but keeps its mean, first estimate, its
joint covariance with every other retired object and its cross-covariance with the active error
state — a Schmidt–Kalman *consider* state. :class:`~teamslam.msckf.filter.state.MsckfState`
edits the cross-covariance with every edit of the active state (propagation, update,
marginalisation, initialisation, consensus) and never moves a retired mean nor shrinks the
retired covariance (gain zero); re-entry puts an object back with its exact joint covariance.
This class only stores: rows are kept packed (row ``k`` of the cross-covariance is coordinate
``k`` of the retired objects), arrays double their capacity when full. Retiring or re-entering
``k`` objects costs ``O(k (d + r))`` for ``r`` retired objects and an active state of ``d``
coordinates; the storage is ``O(r (d + r))``. Why, and what each edit does: the concept page
*The persistent map* (``docs/concepts/persistent-map.md``).
"""

from __future__ import annotations

import numpy as np

from teamslam.errors import InputError, InternalError

__all__ = ["PersistentMap"]


class _Marginals:
    """Retired objects kept without correlations: id → mean, 3×3 marginal, first estimate."""

    def __init__(self) -> None:
        self.means: dict[int, np.ndarray] = {}
        self.covs: dict[int, np.ndarray] = {}
        self.fe: dict[int, np.ndarray] = {}

    def put(self, ids: np.ndarray, means: np.ndarray, covs: np.ndarray, fe: np.ndarray) -> None:
        for k, i in enumerate(np.asarray(ids, dtype=np.int64).ravel().tolist()):
            self.means[i], self.covs[i], self.fe[i] = means[k].copy(), covs[k].copy(), fe[k].copy()

    def pop(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.means.pop(i), self.covs.pop(i), self.fe.pop(i)


def _coords(rows: np.ndarray) -> np.ndarray:
    """``(3k,)`` coordinates of object rows ``(k,)``."""
    return (3 * np.asarray(rows, dtype=np.int64)[:, None] + np.arange(3)).ravel()


class PersistentMap:
    """Retired objects as consider states: id → mean and first estimate, with their joint
    covariance and their cross-covariance with the filter's active error state.

    Parameters
    ----------
    capacity
        Objects allocated at first (doubled when full).
    dim
        Coordinates of the active error state (columns of :attr:`cross`).
    """

    def __init__(self, capacity: int = 64, dim: int = 0) -> None:
        capacity = max(int(capacity), 1)
        self._means = np.zeros((capacity, 3))
        self._fe = np.zeros((capacity, 3))
        self._ids = np.zeros(capacity, dtype=np.int64)
        self._joint = np.zeros((3 * capacity, 3 * capacity))
        self._cross = np.zeros((3 * capacity, int(dim)))
        self._age = np.zeros(capacity, dtype=np.int64)  # retirement order of each row
        self._retired = 0
        self._row: dict[int, int] = {}
        self._loose = _Marginals()

    def __len__(self) -> int:
        return len(self._row) + len(self._loose.means)

    def __contains__(self, object_id: object) -> bool:
        return int(object_id) in self._row or int(object_id) in self._loose.means

    @property
    def n_consider(self) -> int:
        """Objects kept as consider states (correlated with the state)."""
        return len(self._row)

    @property
    def capacity(self) -> int:
        """Objects allocated (at most twice the largest size the map has had, or 64)."""
        return self._means.shape[0]

    @property
    def dim(self) -> int:
        """Coordinates of the active state the cross-covariance spans."""
        return self._cross.shape[1]

    @property
    def cross(self) -> np.ndarray:
        """``(3r, dim)``: covariance of the retired coordinates (in row order) with the active
        error state, a writable view (edited by the state only)."""
        return self._cross[: 3 * self.n_consider]

    @property
    def joint(self) -> np.ndarray:
        """``(3r, 3r)``: joint covariance of the retired coordinates (row order), a writable
        view (edited by the state only)."""
        n = 3 * self.n_consider
        return self._joint[:n, :n]

    def rows(self, ids: np.ndarray) -> np.ndarray:
        """Rows of consider states ``ids`` (all must be consider states)."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        try:
            return np.array([self._row[i] for i in ids.tolist()], dtype=np.int64)
        except KeyError as exc:
            raise InternalError(f"object {exc.args[0]} is not in the persistent map") from None

    def coordinates(self, ids: np.ndarray) -> np.ndarray:
        """``(3k,)`` rows of :attr:`cross` and :attr:`joint` of consider states ``ids``."""
        return _coords(self.rows(ids))

    def contains(self, ids: np.ndarray) -> np.ndarray:
        """Whether each id is stored (boolean array shaped like ``ids``)."""
        ids = np.asarray(ids, dtype=np.int64)
        row, loose = self._row, self._loose.means
        return np.fromiter(
            (i in row or i in loose for i in ids.ravel().tolist()), bool, ids.size
        ).reshape(ids.shape)

    def is_consider(self, ids: np.ndarray) -> np.ndarray:
        """Whether each id is a consider state (boolean array shaped like ``ids``)."""
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
        n = len(self._row)
        for name in ("_means", "_fe", "_ids", "_age"):
            a = getattr(self, name)
            b = np.zeros((new, *a.shape[1:]), dtype=a.dtype)
            b[:n] = a[:n]
            setattr(self, name, b)
        joint = np.zeros((3 * new, 3 * new))
        joint[: 3 * n, : 3 * n] = self._joint[: 3 * n, : 3 * n]
        cross = np.zeros((3 * new, self.dim))
        cross[: 3 * n] = self._cross[: 3 * n]
        self._joint, self._cross = joint, cross

    # ------------------------------------------------------------------ the active columns
    def resize(self, dim: int) -> None:
        """An empty map's cross-covariance spans ``dim`` active coordinates."""
        if self.n_consider:
            raise InternalError("the persistent map's columns follow the state's edits")
        if self._cross.shape[1] != int(dim):
            self._cross = np.zeros((self._cross.shape[0], int(dim)))

    def set_columns(self, cross: np.ndarray) -> None:
        """Replace the cross-covariance by ``cross`` ``(3r, d)`` (after an edit of the active
        state that changes its columns)."""
        n = 3 * self.n_consider
        out = np.zeros((self._cross.shape[0], cross.shape[1]))
        out[:n] = cross
        self._cross = out

    # ------------------------------------------------------------------ objects in and out
    def add(
        self,
        ids: np.ndarray,
        means: np.ndarray,
        fe: np.ndarray,
        joint: np.ndarray,
        with_retired: np.ndarray,
        cross: np.ndarray,
    ) -> None:
        """Append objects ``ids`` (none stored yet) with means and first estimates ``(k, 3)``,
        their joint covariance ``(3k, 3k)``, its cross-covariance with the objects already stored
        ``(3k, 3r)`` (row order) and with the active state ``(3k, dim)``."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        if ids.size == 0:
            return
        if np.any(self.contains(ids)) or np.unique(ids).size != ids.size:
            raise InternalError("an object enters the persistent map twice")
        self._grow(ids.size)
        n, k = self.n_consider, ids.size
        rows = np.arange(n, n + k)
        for i, row in zip(ids.tolist(), rows.tolist(), strict=True):
            self._row[i] = row
        self._ids[rows] = ids
        self._age[rows] = self._retired + np.arange(k)
        self._retired += k
        self._means[rows] = means
        self._fe[rows] = fe
        new = slice(3 * n, 3 * (n + k))
        self._joint[new, : 3 * n] = with_retired
        self._joint[: 3 * n, new] = np.asarray(with_retired).T
        self._joint[new, new] = 0.5 * (joint + joint.T)
        self._cross[new] = cross

    def store(self, ids: np.ndarray, means: np.ndarray, covs: np.ndarray, fe: np.ndarray) -> None:
        """Append objects ``ids`` uncorrelated with everything else: means ``(k, 3)``, 3×3
        covariances ``(k, 3, 3)`` and first estimates ``(k, 3)``."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        covs = np.asarray(covs, dtype=float).reshape(-1, 3, 3)
        k = ids.size
        joint = np.zeros((3 * k, 3 * k))
        for j in range(k):
            joint[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] = covs[j]
        self.add(
            ids,
            means,
            fe,
            joint,
            np.zeros((3 * k, 3 * self.n_consider)),
            np.zeros((3 * k, self.dim)),
        )

    def take(
        self, ids: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Remove stored objects ``ids`` (all must be stored) and return what they had.

        Returns
        -------
        means, fe, joint, cross, with_retired
            ``(k, 3)`` means and first estimates, ``(3k, 3k)`` their joint covariance,
            ``(3k, dim)`` their cross-covariance with the active state and ``(3r', 3k)`` the
            cross-covariance of the consider states that stay (in their row order after the
            removal) with them; an object kept without correlations has zeros there.
        """
        ids = np.asarray(ids, dtype=np.int64).ravel()
        if not np.all(self.contains(ids)):
            missing = ids[~self.contains(ids)][0]
            raise InternalError(f"object {missing} is not in the persistent map")
        correlated = self.is_consider(ids)
        if correlated.all():
            return self._take_consider(ids)
        k = ids.size
        means, fe = np.zeros((k, 3)), np.zeros((k, 3))
        joint = np.zeros((3 * k, 3 * k))
        cross = np.zeros((3 * k, self.dim))
        c = _coords(np.flatnonzero(correlated))
        m, f, j, x, column = self._take_consider(ids[correlated])
        means[correlated], fe[correlated] = m, f
        joint[np.ix_(c, c)], cross[c] = j, x
        with_retired = np.zeros((column.shape[0], 3 * k))
        with_retired[:, c] = column
        for pos in np.flatnonzero(~correlated).tolist():
            mean, cov, first = self._loose.pop(int(ids[pos]))
            means[pos], fe[pos] = mean, first
            joint[3 * pos : 3 * pos + 3, 3 * pos : 3 * pos + 3] = cov
        return means, fe, joint, cross, with_retired

    def loosen(self, keep: int) -> int:
        """Keep at most ``keep`` consider states: the earliest retired of the others lose their
        correlations (their means, marginals and first estimates stay). Returns how many."""
        n = self.n_consider
        if keep <= 0 or n <= keep:
            return 0
        oldest = np.argsort(self._age[:n], kind="stable")[: n - keep]
        ids = self._ids[oldest].copy()
        means, fe, joint, _, _ = self._take_consider(ids)
        blocks = _coords(np.arange(ids.size)).reshape(-1, 3)
        self._loose.put(ids, means, joint[blocks[:, :, None], blocks[:, None, :]], fe)
        return int(ids.size)

    def _take_consider(
        self, ids: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        ids = np.asarray(ids, dtype=np.int64).ravel()
        rows = self.rows(ids)
        n, k = self.n_consider, ids.size
        coords = _coords(rows)
        means, fe = self._means[rows].copy(), self._fe[rows].copy()
        joint = self._joint[np.ix_(coords, coords)]
        cross = self._cross[coords].copy()
        column = self._joint[: 3 * n, coords].copy()
        # pack: the rows of the last k objects that stay move into the holes below n − k
        holes = np.sort(rows[rows < n - k])
        tail = np.setdiff1d(np.arange(n - k, n), rows)
        for i in ids.tolist():
            del self._row[i]
        if holes.size:
            self._ids[holes] = self._ids[tail]
            self._age[holes] = self._age[tail]
            self._means[holes] = self._means[tail]
            self._fe[holes] = self._fe[tail]
            for i, row in zip(self._ids[holes].tolist(), holes.tolist(), strict=True):
                self._row[i] = row
            h, t = _coords(holes), _coords(tail)
            self._joint[h, : 3 * n] = self._joint[t, : 3 * n]
            self._joint[: 3 * n, h] = self._joint[: 3 * n, t]
            self._cross[h] = self._cross[t]
            column[h] = column[t]
        return means, fe, joint, cross, column[: 3 * (n - k)]

    # ------------------------------------------------------------------ reading
    def get(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Means, 3×3 marginal covariances and first estimates of stored objects ``ids``."""
        ids = np.asarray(ids, dtype=np.int64).ravel()
        correlated = self.is_consider(ids)
        if correlated.all():
            rows = self.rows(ids)
            return self._means[rows].copy(), self._blocks(rows), self._fe[rows].copy()
        means, covs, fe = (
            np.zeros((ids.size, 3)),
            np.zeros((ids.size, 3, 3)),
            np.zeros((ids.size, 3)),
        )
        rows = self.rows(ids[correlated])
        means[correlated], covs[correlated] = self._means[rows], self._blocks(rows)
        fe[correlated] = self._fe[rows]
        loose = self._loose
        for pos in np.flatnonzero(~correlated).tolist():
            i = int(ids[pos])
            if i not in loose.means:
                raise InternalError(f"object {i} is not in the persistent map")
            means[pos], covs[pos], fe[pos] = loose.means[i], loose.covs[i], loose.fe[i]
        return means, covs, fe

    def set_loose(self, ids: np.ndarray, means: np.ndarray, covs: np.ndarray) -> None:
        """New means and marginals of objects kept without correlations (consensus)."""
        for k, i in enumerate(np.asarray(ids, dtype=np.int64).ravel().tolist()):
            self._loose.means[i], self._loose.covs[i] = means[k].copy(), covs[k].copy()

    def _blocks(self, rows: np.ndarray) -> np.ndarray:
        c = _coords(rows).reshape(-1, 3)
        return self._joint[c[:, :, None], c[:, None, :]]

    def row_ids(self) -> np.ndarray:
        """The consider states' ids in row order (the order of :attr:`cross` and
        :attr:`joint`)."""
        return self._ids[: self.n_consider].copy()

    def arrays(self) -> dict[str, np.ndarray]:
        """Every stored object, sorted by id: ``ids``, ``means``, ``covs`` (3×3 marginals) and
        ``fe``, in that order (``O(r)``; the correlations: :meth:`consider_arrays`)."""
        ids = np.array(sorted([*self._row, *self._loose.means]), dtype=np.int64)
        means, covs, fe = self.get(ids)
        return {"ids": ids, "means": means, "covs": covs, "fe": fe}

    def consider_arrays(self) -> dict[str, np.ndarray]:
        """The consider states in row order: ``consider_ids``, ``joint`` ``(3c, 3c)``,
        ``cross`` ``(3c, dim)`` and ``age`` (the order they retired in)."""
        c = self.n_consider
        return {
            "consider_ids": self._ids[:c].copy(),
            "joint": self.joint.copy(),
            "cross": self.cross.copy(),
            "age": self._age[:c].copy(),
        }

    def set_mean(self, object_id: int, mean: np.ndarray) -> None:
        """A stored object's new mean (consensus on the persistent map)."""
        self._means[self.rows(np.array([object_id]))[0]] = mean

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_arrays(
        cls,
        ids: np.ndarray,
        means: np.ndarray,
        covs: np.ndarray,
        fe: np.ndarray,
        consider_ids: np.ndarray | None = None,
        joint: np.ndarray | None = None,
        cross: np.ndarray | None = None,
        age: np.ndarray | None = None,
        dim: int = 0,
    ) -> PersistentMap:
        """A map holding these objects (:meth:`arrays`, :meth:`consider_arrays`), after checking
        that they fit together.

        Objects not in ``consider_ids`` (all without it: a map written before consider states)
        are kept without correlations; the consider states have the joint covariance ``joint``
        and the cross-covariance ``cross`` with an active state of ``dim`` coordinates.

        Raises
        ------
        InputError
            Shapes that disagree, repeated or unknown ids, non-finite values, covariances that
            are not symmetric positive definite or marginals that are not the joint's blocks.
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
        consider = np.zeros(0, np.int64) if consider_ids is None else np.asarray(consider_ids)
        consider = consider.astype(np.int64).ravel()
        c = consider.size
        where = {i: p for p, i in enumerate(ids.tolist())}
        if any(i not in where for i in consider.tolist()) or np.unique(consider).size != c:
            raise InputError("persistent map: consider states that are not in the map")
        pos = np.array([where[i] for i in consider.tolist()], dtype=np.int64)
        joint = np.zeros((0, 0)) if joint is None else np.asarray(joint, dtype=float)
        cross = np.zeros((3 * c, dim)) if cross is None else np.asarray(cross, dtype=float)
        age = np.arange(c) if age is None else np.asarray(age, dtype=np.int64).ravel()
        if joint.shape != (3 * c, 3 * c) or cross.shape != (3 * c, dim) or age.shape != (c,):
            raise InputError(
                f"persistent map: joint {joint.shape}, cross-covariance {cross.shape} and "
                f"{age.size} ages for {c} consider states and a state of dimension {dim}"
            )
        if not (np.all(np.isfinite(joint)) and np.all(np.isfinite(cross))):
            raise InputError("persistent map: non-finite values")
        if not np.allclose(joint, joint.T, rtol=1e-9, atol=1e-12):
            raise InputError("persistent map: the joint covariance is not symmetric")
        blocks = _coords(np.arange(c)).reshape(-1, 3)
        if not np.array_equal(joint[blocks[:, :, None], blocks[:, None, :]], covs[pos]):
            raise InputError("persistent map: marginals that are not the joint's blocks")
        out = cls(capacity=max(64, 2 * c), dim=dim)
        out.add(consider, means[pos], fe[pos], joint, np.zeros((3 * c, 0)), cross)
        out._age[:c] = age
        out._retired = int(age.max()) + 1 if c else 0
        loose = np.ones(k, bool)
        loose[pos] = False
        out._loose.put(ids[loose], means[loose], covs[loose], fe[loose])
        return out

    def copy(self) -> PersistentMap:
        """An independent copy."""
        return PersistentMap.from_arrays(**self.arrays(), **self.consider_arrays(), dim=self.dim)
