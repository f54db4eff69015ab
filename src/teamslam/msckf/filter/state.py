"""One robot's MSCKF state: a sliding window of body poses plus object landmarks (eq. 18).

The error state is a right perturbation ``(ρ, φ)`` per window pose (``T = T̂ · exp(ε^)``,
oldest first), then a 3-vector per object. **Every covariance edit goes through**
:class:`MsckfState` (augment, marginalise, add, update, replace the marginal, retire,
re-enter); a non-finite input is refused before any edit, and with ``debug=True`` each edit
checks that the covariance — with the persistent map's consider states — stays symmetric
positive definite. Retired objects are consider states (Schmidt–Kalman): every edit of the
active state edits their cross-covariance with it as it edits its own rows, none moves their
means or shrinks their covariance, and re-entry restores the exact joint. Callers reach the
layout through handles (:class:`PoseHandle`, :class:`ObjectHandle`); the state also keeps first
estimates, and
can hold several robots' windows (:class:`RobotWindow`). See the concept page *The filter*
(``docs/concepts/filter.md``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import scipy.linalg

from teamslam.errors import EstimationError, InputError, InternalError
from teamslam.gaussian import NotPositiveDefiniteError, replace_marginal_shift
from teamslam.geometry import se3
from teamslam.msckf.filter.persistent_map import PersistentMap
from teamslam.msckf.filter.update import MeasurementRows

__all__ = ["MsckfState", "ObjectHandle", "PoseHandle", "RobotWindow"]


@dataclass(frozen=True)
class PoseHandle:
    """Window poses of a state as a typed handle (OpenVINS' ``Type``): which poses they are and
    where their error-state columns are.

    A handle describes the layout at the time it was taken: it is valid until the window or the
    map changes (augment, marginalisation, object initialisation or retirement).

    Attributes
    ----------
    window_index
        Positions in the state's window (over all robots of a team state).
    frames
        Their frame indices.
    columns
        ``(…, 6)`` error-state columns ``(ρ, φ)`` of each pose.
    """

    window_index: np.ndarray
    frames: np.ndarray
    columns: np.ndarray
    size: ClassVar[int] = 6


@dataclass(frozen=True)
class ObjectHandle:
    """Object landmarks of a state as a typed handle: their slots in the map, ids and error-state
    columns (valid until the window or the map changes, as :class:`PoseHandle`).

    Attributes
    ----------
    slots
        Positions in the state's map.
    ids
        Their object ids.
    columns
        ``(…, 3)`` error-state columns of each object.
    """

    slots: np.ndarray
    ids: np.ndarray
    columns: np.ndarray
    size: ClassVar[int] = 3


class MsckfState:
    """Window poses (``T_world_body``), object landmarks and their joint covariance.

    Parameters
    ----------
    T_world_body
        The first pose.
    frame
        Its frame index.
    pose_cov
        Its 6×6 covariance.
    debug
        Check the covariance after every edit.
    robot
        The robot whose state this is, named in errors (``None``: a team state, whose errors
        name the robot of the edit when it is known).
    """

    def __init__(
        self,
        T_world_body: np.ndarray,
        frame: int,
        pose_cov: np.ndarray,
        debug: bool = False,
        robot: int | None = None,
    ) -> None:
        self.poses = np.asarray(T_world_body, dtype=float).reshape(1, 4, 4).copy()
        self.frames = np.array([frame], dtype=np.int64)
        self.robots = np.zeros(1, dtype=np.int64)
        self.pose_fe = self.poses.copy()
        self.object_ids = np.zeros(0, dtype=np.int64)
        self.objects = np.zeros((0, 3))
        self.object_fe = np.zeros((0, 3))
        self.object_last_seen = np.zeros(0, dtype=np.int64)
        self.retired = PersistentMap(dim=6)
        self._init_dropped()
        # every edit below keeps the covariance exactly symmetric; it starts so
        pose_cov = np.asarray(pose_cov, dtype=float).reshape(6, 6)
        self._cov = 0.5 * (pose_cov + pose_cov.T)
        self.debug = debug
        self.robot = robot

    # ------------------------------------------------------------------ snapshot
    def snapshot(self) -> dict[str, np.ndarray]:
        """The whole state as arrays (copies): window poses, frames, robots and first estimates,
        objects, their first estimates and the frame each was last observed, covariance, the
        persistent map of retired objects, and the objects marginalised out and not back
        (:meth:`marginalize_objects`; only when there are any)."""
        retired = {**self.retired.arrays(), **self.retired.consider_arrays()}
        # objects marginalised out by re-anchoring, if any (a snapshot without is as before)
        dropped = (
            {
                "dropped_ids": self.dropped_ids.copy(),
                "dropped_means": self.dropped_means.copy(),
                "dropped_covs": self.dropped_covs.copy(),
            }
            if self.dropped_ids.size
            else {}
        )
        return {
            "window_poses": self.poses.copy(),
            "window_frames": self.frames.copy(),
            "window_robots": self.robots.copy(),
            "window_pose_fe": self.pose_fe.copy(),
            "object_ids": self.object_ids.copy(),
            "objects": self.objects.copy(),
            "object_fe": self.object_fe.copy(),
            "cov": self._cov.copy(),
            "object_last_seen": self.object_last_seen.copy(),
            **{f"retired_{k}": v for k, v in retired.items()},
            **dropped,
        }

    def restore(self, snapshot: dict[str, np.ndarray]) -> None:
        """Put back a :meth:`snapshot`, after checking that its parts fit together.

        Raises
        ------
        ValueError
            Missing arrays, shapes that disagree, non-finite values or a covariance that is
            not symmetric positive definite; the state is then left as it was.
        """
        try:
            poses = np.asarray(snapshot["window_poses"], dtype=float)
            frames = np.asarray(snapshot["window_frames"], dtype=np.int64)
            ids = np.asarray(snapshot["object_ids"], dtype=np.int64)
            objects = np.asarray(snapshot["objects"], dtype=float).reshape(-1, 3)
            cov = np.asarray(snapshot["cov"], dtype=float)
            robots = np.asarray(snapshot["window_robots"], dtype=np.int64)
            pose_fe = np.asarray(snapshot["window_pose_fe"], dtype=float)
            object_fe = np.asarray(snapshot["object_fe"], dtype=float).reshape(-1, 3)
        except KeyError as exc:
            raise InputError(f"state snapshot lacks {exc.args[0]!r}") from None
        c, m = poses.shape[0], ids.size
        # snapshots written before the persistent map: nothing retired, objects seen now
        newest = int(frames.max()) if frames.size else 0
        last_seen = np.asarray(
            snapshot.get("object_last_seen", np.full(m, newest)), dtype=np.int64
        ).ravel()
        if last_seen.shape != (m,):
            raise InputError(f"state snapshot: {last_seen.size} last-seen frames for {m} objects")
        dim = 6 * c + 3 * m
        # snapshots written before consider states: retired objects uncorrelated
        retired = PersistentMap.from_arrays(
            *(
                snapshot.get(f"retired_{k}", np.zeros((0, *shape)))
                for k, shape in (("ids", ()), ("means", (3,)), ("covs", (3, 3)), ("fe", (3,)))
            ),
            *(snapshot.get(f"retired_{k}") for k in ("consider_ids", "joint", "cross", "age")),
            dim=dim,
        )
        if np.any(retired.contains(ids)):
            raise InputError("state snapshot: an object is both in the state and retired")
        if poses.shape != (c, 4, 4) or frames.shape != (c,) or c == 0:
            raise InputError(f"state snapshot: window poses {poses.shape}, frames {frames.shape}")
        if robots.shape != (c,) or pose_fe.shape != poses.shape or object_fe.shape != (m, 3):
            raise InputError("state snapshot: robots or first estimates do not match the state")
        if objects.shape != (m, 3) or np.unique(ids).size != m:
            raise InputError(f"state snapshot: {m} object ids for objects {objects.shape}")
        if cov.shape != (dim, dim):
            raise InputError(f"state snapshot: covariance {cov.shape}, state dimension {dim}")
        if not all(np.all(np.isfinite(a)) for a in (poses, objects, cov, pose_fe, object_fe)):
            raise InputError("state snapshot: non-finite values")
        if not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-12):
            raise InputError("state snapshot: covariance is not symmetric")
        try:
            np.linalg.cholesky(_with_consider(cov, retired))
        except np.linalg.LinAlgError:
            raise InputError(
                "state snapshot: covariance (with the persistent map's) is not positive definite"
            ) from None
        # snapshots written before re-anchoring: nothing dropped
        dropped = [
            np.asarray(snapshot.get(f"dropped_{k}", np.zeros((0, *shape))), dtype=kind)
            for k, shape, kind in (
                ("ids", (), np.int64),
                ("means", (3,), float),
                ("covs", (3, 3), float),
            )
        ]
        d = dropped[0].size
        if dropped[0].shape != (d,) or dropped[1].shape != (d, 3) or dropped[2].shape != (d, 3, 3):
            raise InputError("state snapshot: dropped objects' means or covariances do not match")
        if not all(np.all(np.isfinite(a)) for a in dropped[1:]):
            raise InputError("state snapshot: non-finite values")
        self.poses, self.frames, self.object_ids, self.objects = poses, frames, ids, objects
        self.robots, self.pose_fe, self.object_fe = robots, pose_fe, object_fe
        self.object_last_seen, self.retired = last_seen, retired
        self.dropped_ids, self.dropped_means, self.dropped_covs = dropped
        self._cov = 0.5 * (cov + cov.T)

    def _init_dropped(self) -> None:
        """No object marginalised out yet (:meth:`marginalize_objects`)."""
        self.dropped_ids = np.zeros(0, dtype=np.int64)
        self.dropped_means = np.zeros((0, 3))
        self.dropped_covs = np.zeros((0, 3, 3))

    @classmethod
    def team(
        cls, T_world_body: np.ndarray, frame: int, pose_cov: np.ndarray, debug: bool = False
    ) -> MsckfState:
        """One state for a team: robot ``i`` starts at ``T_world_body[i]`` (``(R, 4, 4)``), each
        with covariance ``pose_cov``, uncorrelated."""
        first = np.asarray(T_world_body, dtype=float).reshape(-1, 4, 4)
        state = cls(first[0], frame, pose_cov, debug)
        n = first.shape[0]
        state.poses = first.copy()
        state.pose_fe = first.copy()
        state.frames = np.full(n, frame, dtype=np.int64)
        state.robots = np.arange(n, dtype=np.int64)
        state._cov = np.kron(np.eye(n), np.asarray(pose_cov, dtype=float).reshape(6, 6))
        state.retired.resize(state.dim)
        return state

    @classmethod
    def from_arrays(
        cls,
        T_world_body: np.ndarray,
        frames: np.ndarray,
        object_ids: np.ndarray,
        objects: np.ndarray,
        cov: np.ndarray,
        *,
        robots: np.ndarray | None = None,
        object_fe: np.ndarray | None = None,
        object_last_seen: np.ndarray | None = None,
        robot: int | None = None,
        debug: bool = False,
        check: bool = True,
    ) -> MsckfState:
        """A state holding these window poses ``(c, 4, 4)`` (with their frames and, for a team
        state, robots), objects ``(m, 3)`` with their ids, and joint covariance; first estimates
        are the estimates (objects': ``object_fe`` if given), every object last seen at the
        newest frame (or at ``object_last_seen``).

        ``check=False`` takes the arrays as they are (a state that already failed, for tests of
        what follows); otherwise they are checked as :meth:`restore` checks a snapshot.
        """
        poses = np.asarray(T_world_body, dtype=float).reshape(-1, 4, 4)
        c = poses.shape[0]
        frames = np.asarray(frames, dtype=np.int64).reshape(c)
        objects = np.asarray(objects, dtype=float).reshape(-1, 3)
        state = cls(poses[0], int(frames[0]), np.eye(6), debug, robot)
        snapshot = {
            "window_poses": poses,
            "window_frames": frames,
            "window_robots": np.zeros(c, np.int64) if robots is None else np.asarray(robots),
            "window_pose_fe": poses.copy(),
            "object_ids": np.asarray(object_ids, dtype=np.int64),
            "objects": objects,
            "object_fe": objects.copy() if object_fe is None else np.asarray(object_fe, float),
            "cov": np.asarray(cov, dtype=float),
            "object_last_seen": (
                np.full(objects.shape[0], int(frames.max()), dtype=np.int64)
                if object_last_seen is None
                else np.asarray(object_last_seen, dtype=np.int64)
            ),
        }
        if check:
            state.restore(snapshot)
            return state
        state.poses, state.frames = poses.copy(), frames.copy()
        state.robots = snapshot["window_robots"].astype(np.int64)
        state.pose_fe, state.object_ids = poses.copy(), snapshot["object_ids"].copy()
        state.objects, state.object_fe = objects.copy(), snapshot["object_fe"].reshape(-1, 3)
        state.object_last_seen = snapshot["object_last_seen"].copy()
        state._cov = snapshot["cov"].copy()
        state.retired = PersistentMap(dim=state.dim)
        return state

    def window(self, robot: int) -> RobotWindow:
        """Robot ``robot``'s window as a state of its own (shares this state's arrays)."""
        if not np.any(self.robots == robot):
            raise InternalError(f"robot {robot} has no pose in this state")
        return RobotWindow(self, robot)

    # ------------------------------------------------------------------ layout
    @property
    def cov(self) -> np.ndarray:
        """The joint covariance of the error state, read-only (a view: every edit goes
        through this class; :meth:`covariance` gives the block of some columns)."""
        view = self._cov.view()
        view.flags.writeable = False
        return view

    @property
    def n_poses(self) -> int:
        """Poses in the window."""
        return self.frames.size

    @property
    def n_objects(self) -> int:
        """Object landmarks in the map."""
        return self.object_ids.size

    @property
    def dim(self) -> int:
        """Error-state dimension ``6c + 3m``."""
        return 6 * self.n_poses + 3 * self.n_objects

    def pose_columns(self, window_index: np.ndarray) -> np.ndarray:
        """Error-state columns ``(k, 6)`` of window poses."""
        return 6 * np.asarray(window_index)[..., None] + np.arange(6)

    def object_columns(self, slots: np.ndarray) -> np.ndarray:
        """Error-state columns ``(k, 3)`` of object slots."""
        return 6 * self.n_poses + 3 * np.asarray(slots)[..., None] + np.arange(3)

    def pose(self, window_index: np.ndarray | int) -> PoseHandle:
        """Handle of the window poses at ``window_index`` (positions in the window)."""
        index = np.asarray(window_index, dtype=np.int64)
        return PoseHandle(index, self.frames[index], self.pose_columns(index))

    def newest_pose(self) -> PoseHandle:
        """Handle of the newest window pose."""
        return self.pose(self.n_poses - 1)

    def object(self, slots: np.ndarray | int) -> ObjectHandle:
        """Handle of the objects in map ``slots``."""
        slots = np.asarray(slots, dtype=np.int64)
        return ObjectHandle(slots, self.object_ids[slots], self.object_columns(slots))

    def object_slots(self, ids: np.ndarray) -> np.ndarray:
        """Slots of object ids in the map (``-1`` where absent)."""
        ids = np.asarray(ids, dtype=np.int64)
        if self.n_objects == 0:
            return np.full(ids.shape, -1, dtype=np.int64)
        order = np.argsort(self.object_ids)
        pos = np.clip(np.searchsorted(self.object_ids[order], ids), 0, self.n_objects - 1)
        found = self.object_ids[order[pos]] == ids
        return np.where(found, order[pos], -1)

    def window_index(self, frames: np.ndarray) -> np.ndarray:
        """Window positions of frame indices (``-1`` where not in the window)."""
        frames = np.asarray(frames, dtype=np.int64)
        pos = np.clip(np.searchsorted(self.frames, frames), 0, self.n_poses - 1)
        return np.where(self.frames[pos] == frames, pos, -1)

    @property
    def window_columns(self) -> slice:
        """Error-state columns of the window poses."""
        return slice(0, 6 * self.n_poses)

    @property
    def current_pose(self) -> np.ndarray:
        """Newest window pose."""
        return self.poses[-1]

    def current_pose_cov(self) -> np.ndarray:
        """6×6 covariance of the newest pose."""
        s = slice(6 * (self.n_poses - 1), 6 * self.n_poses)
        return self.cov[s, s]

    def covariance(self, columns: np.ndarray | slice | PoseHandle | ObjectHandle) -> np.ndarray:
        """The covariance of error-state ``columns``: ``(k, k)`` for a list or a slice (a
        read-only view), ``(…, k, k)`` for a stack of lists ``(…, k)`` (a copy); a handle
        gives the joint covariance of all its columns."""
        if isinstance(columns, PoseHandle | ObjectHandle):
            columns = columns.columns.ravel()
        if isinstance(columns, slice):
            return self.cov[columns, columns]
        columns = np.asarray(columns)
        if columns.ndim == 1:
            return self._cov[np.ix_(columns, columns)]
        return self._cov[columns[..., :, None], columns[..., None, :]]

    def cross_covariance(self, columns: np.ndarray) -> np.ndarray:
        """``(k, dim)``: the covariance of error-state ``columns`` with the whole state."""
        return self._cov[np.asarray(columns), :]

    def with_consider(self) -> tuple[np.ndarray, np.ndarray]:
        """The joint covariance of the active error state and the persistent map's consider
        states ``(dim + 3r, dim + 3r)`` (the active state first, then the retired objects'
        coordinates), and the retired ids in that order."""
        return _with_consider(self._cov, self.retired), self.retired.row_ids()

    def object_covs(self) -> np.ndarray:
        """``(m, 3, 3)`` marginal covariance of each object."""
        cols = self.object_columns(np.arange(self.n_objects))
        return self._cov[cols[:, :, None], cols[:, None, :]]

    def full_map(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every object the robot has mapped — in the state, retired, and marginalised out
        (:meth:`marginalize_objects`) and not back yet, with its marginal when it left — sorted
        by id: ids, ``(m, 3)`` means and ``(m, 3, 3)`` marginal covariances."""
        retired = self.retired.arrays()
        ids = np.concatenate([self.object_ids, retired["ids"], self.dropped_ids])
        means = np.concatenate([self.objects, retired["means"], self.dropped_means])
        covs = np.concatenate([self.object_covs(), retired["covs"], self.dropped_covs])
        order = np.argsort(ids)
        return ids[order], means[order], covs[order]

    def _check(self, what: str) -> None:
        if not self.debug:
            return
        if not np.allclose(self._cov, self._cov.T, atol=1e-9 * max(1.0, np.abs(self._cov).max())):
            raise NotPositiveDefiniteError(f"covariance lost symmetry after {what}")
        if self.retired.n_consider and self.retired.dim != self.dim:
            raise InternalError(f"the persistent map's columns lost the state's after {what}")
        try:
            np.linalg.cholesky(_with_consider(self._cov, self.retired))
        except np.linalg.LinAlgError:
            raise NotPositiveDefiniteError(
                f"covariance not positive definite after {what}"
            ) from None

    def where(self, robot: int | None = None) -> str:
        """``"robot r, frame t"`` of the newest frame, for error messages (``robot`` defaults
        to the state's own robot; a team state without one names the frame only)."""
        frames = self.frames
        if robot is not None and self.robot is None and np.any(self.robots == robot):
            frames = frames[self.robots == robot]  # a robot's window in a team state
        robot = self.robot if robot is None else robot
        frame = f"frame {int(frames.max())}"
        return frame if robot is None else f"robot {int(robot)}, {frame}"

    def check_finite(self, what: str, *arrays: np.ndarray, robot: int | None = None) -> None:
        """Raise :class:`~teamslam.errors.EstimationError` naming robot, frame and ``what``
        unless every entry of ``arrays`` is finite (call it before any edit: the estimate is then
        left as it was)."""
        for a in arrays:
            if not np.all(np.isfinite(a)):
                raise EstimationError(
                    f"{self.where(robot)}: non-finite {what}; the estimate is left as it was"
                )

    # ------------------------------------------------------------------ edits
    def augment(
        self,
        odometry: np.ndarray,
        frame: int,
        odometry_cov: np.ndarray,
        robot: int = 0,
        jacobian_step: np.ndarray | None = None,
    ) -> None:
        """Append ``T_new = T_last · δT`` (eq. 22) with ``ε_new = Ad(δT⁻¹) ε_last + w`` (eq. 23).

        Parameters
        ----------
        odometry
            ``δT``, the relative pose that moves the estimate.
        frame
            Frame index of the new pose.
        odometry_cov
            ``W``.
        robot
            Whose window grows (the new pose goes after that robot's newest pose).
        jacobian_step
            The relative pose at which the Jacobian ``Ad(δ⁻¹)`` is evaluated (default
            ``odometry``); see :mod:`teamslam.msckf.filter.linearization`.
        """
        odometry = np.asarray(odometry, dtype=float)
        mine = np.flatnonzero(self.robots == robot)
        if mine.size == 0:
            raise InternalError(f"robot {robot} has no pose in this state")
        last_index = int(mine[-1])
        new_pose = self.poses[last_index] @ odometry
        step = odometry if jacobian_step is None else np.asarray(jacobian_step, dtype=float)
        jac = se3.adjoint(se3.inverse(step))
        last = slice(6 * last_index, 6 * last_index + 6)
        split = 6 * (last_index + 1)
        cross = jac @ self._cov[last, :]  # (6, dim): new pose with everything
        block = jac @ self._cov[last, last] @ jac.T + odometry_cov
        n = self.dim
        cov = np.empty((n + 6, n + 6))
        # the new pose goes after the robot's newest pose: four block copies
        new = slice(split, split + 6)
        after = slice(split + 6, n + 6)
        cov[:split, :split] = self._cov[:split, :split]
        cov[:split, after] = self._cov[:split, split:]
        cov[after, :split] = self._cov[split:, :split]
        cov[after, after] = self._cov[split:, split:]
        cov[new, :split] = cross[:, :split]
        cov[new, after] = cross[:, split:]
        cov[:split, new] = cross[:, :split].T
        cov[after, new] = cross[:, split:].T
        cov[new, new] = 0.5 * (block + block.T)
        self._cov = cov
        # the consider states' covariance with the new pose: C Φᵀ
        self._consider_columns(
            lambda c: np.concatenate([c[:, :split], c[:, last] @ jac.T, c[:, split:]], axis=1)
        )
        at = last_index + 1
        self.poses = np.insert(self.poses, at, new_pose, axis=0)
        self.pose_fe = np.insert(self.pose_fe, at, new_pose, axis=0)
        self.frames = np.insert(self.frames, at, frame)
        self.robots = np.insert(self.robots, at, robot)
        self._check("augment")

    def marginalize_oldest(self, robot: int = 0) -> None:
        """Drop the robot's oldest window pose (its rows and columns of the covariance)."""
        first = int(np.flatnonzero(self.robots == robot)[0])
        if first == 0:
            self._cov = self._cov[6:, 6:].copy()
        else:
            keep = np.ones(self.dim, dtype=bool)
            keep[6 * first : 6 * first + 6] = False
            self._cov = self._cov[np.ix_(keep, keep)]
        self._consider_columns(lambda c: np.delete(c, np.s_[6 * first : 6 * first + 6], axis=1))
        self.poses = np.delete(self.poses, first, axis=0)
        self.pose_fe = np.delete(self.pose_fe, first, axis=0)
        self.frames = np.delete(self.frames, first)
        self.robots = np.delete(self.robots, first)
        self._check("marginalisation")

    def add_object(
        self,
        object_id: int,
        position: np.ndarray,
        cov_pp: np.ndarray,
        cov_ps: np.ndarray,
        robot: int | None = None,
        first_estimate: np.ndarray | None = None,
        from_columns: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        """Append an object with its covariance and cross-covariance with the state (eq. 30).

        ``from_columns = (G, columns)`` says how its error depends on the state's — ``δp =
        G δx[columns] +`` noise independent of the state, so that ``cov_ps = G Σ[columns, :]``
        — and gives its cross-covariance with the persistent map's consider states,
        ``G Σ[columns, consider]``; it is needed once objects have retired.

        Its first estimate is ``first_estimate`` — the point at which the initialisation's
        Jacobians were evaluated, so that the directions its cross-covariance carries are those
        of its first estimate — or ``position``. It counts as observed at the newest window
        frame.

        Raises
        ------
        EstimationError
            Non-finite position or covariances (named with robot and frame); the state is left
            as it was.
        """
        self.check_finite(
            f"initialisation of object {int(object_id)}", position, cov_pp, cov_ps, robot=robot
        )
        first = position if first_estimate is None else first_estimate
        self.check_finite(f"first estimate of object {int(object_id)}", first, robot=robot)
        if self.retired.n_consider and from_columns is None:
            raise InternalError(
                "an object initialised next to retired objects needs its map from the state "
                "(from_columns) for its cross-covariance with them"
            )
        n = self.dim
        cov = np.empty((n + 3, n + 3))
        cov[:n, :n] = self._cov
        cov[n:, :n] = cov_ps
        cov[:n, n:] = cov_ps.T
        cov[n:, n:] = 0.5 * (cov_pp + cov_pp.T)
        self._cov = cov
        if from_columns is not None:
            gain, columns = from_columns
            self._consider_columns(
                lambda c: np.concatenate([c, c[:, np.asarray(columns)] @ gain.T], axis=1)
            )
        else:
            self._consider_columns(None)
        self._forget_dropped(np.array([int(object_id)]))  # a re-anchored object entering again
        self.object_ids = np.append(self.object_ids, int(object_id))
        self.objects = np.vstack([self.objects, np.asarray(position, dtype=float)])
        self.object_fe = np.vstack([self.object_fe, np.asarray(first, dtype=float)])
        self.object_last_seen = np.append(self.object_last_seen, int(self.frames.max()))
        self._check("object initialisation")

    def marginalize_objects(self, slots: np.ndarray) -> None:
        """Drop the objects in ``slots`` from the state: their rows and columns of the
        covariance (exact marginalisation; what their past observations gave the poses and the
        other objects stays), their columns of the persistent map's cross-covariance, their
        means and first estimates. An object dropped so can enter again only from observations
        made after it (as a new object), so that none is counted twice; until it does, the map
        (:meth:`full_map`) reports it with its mean and marginal covariance as it left.
        """
        slots = np.unique(np.asarray(slots, dtype=np.int64))
        if slots.size == 0:
            return
        ids = self.object_ids[slots]
        cols = self.object_columns(slots)
        self._forget_dropped(ids)
        self.dropped_ids = np.concatenate([self.dropped_ids, ids])
        self.dropped_means = np.concatenate([self.dropped_means, self.objects[slots]])
        marginals = self._cov[cols[:, :, None], cols[:, None, :]]
        self.dropped_covs = np.concatenate([self.dropped_covs, marginals])
        cols = cols.ravel()
        keep = np.ones(self.dim, dtype=bool)
        keep[cols] = False
        self._cov = self._cov[np.ix_(keep, keep)]
        self._consider_columns(lambda c: c[:, keep])
        self._remove_object_entries(slots)
        self._check("object marginalisation")

    def _forget_dropped(self, ids: np.ndarray) -> None:
        """Remove objects ``ids`` from those marginalised out and not back."""
        stay = ~np.isin(self.dropped_ids, ids)
        if not stay.all():
            self.dropped_ids = self.dropped_ids[stay]
            self.dropped_means = self.dropped_means[stay]
            self.dropped_covs = self.dropped_covs[stay]

    def _remove_object_entries(self, slots: np.ndarray) -> None:
        """Remove the objects in ``slots`` from the per-object arrays (ids, means, first
        estimates, last seen); their covariance columns are the caller's."""
        kept = np.ones(self.n_objects, dtype=bool)
        kept[slots] = False
        self.object_ids = self.object_ids[kept]
        self.objects = self.objects[kept]
        self.object_fe = self.object_fe[kept]
        self.object_last_seen = self.object_last_seen[kept]

    def mark_seen(self, slots: np.ndarray, frame: int) -> None:
        """Record that the objects in ``slots`` were observed at ``frame``."""
        self.object_last_seen[np.asarray(slots, dtype=np.int64)] = int(frame)

    def retire_objects(self, slots: np.ndarray, max_consider: int = 0) -> int:
        """Move objects out of the active state into the persistent map as consider states.

        Their rows and columns leave the active covariance (whose marginal is unchanged); the
        persistent map keeps their means, first estimates, joint covariance, cross-covariance
        with the active state and with the objects retired before — every number the joint had.
        With ``max_consider > 0`` at most that many retired objects stay consider states: the
        earliest retired of the others keep their means and marginals only (exact
        marginalisation; they re-enter without correlations). Returns how many lost them.
        """
        slots = np.unique(np.asarray(slots, dtype=np.int64))
        if slots.size == 0:
            return 0
        cols = self.object_columns(slots).ravel()
        keep = np.ones(self.dim, dtype=bool)
        keep[cols] = False
        joint = self._cov[np.ix_(cols, cols)]
        cross = self._cov[np.ix_(cols, keep)]
        if self.retired.n_consider:
            consider = self.retired.cross
            with_retired = consider[:, cols].T
            self.retired.set_columns(consider[:, keep])
        else:
            with_retired = np.zeros((cols.size, 0))
            self.retired.resize(int(keep.sum()))
        self.retired.add(
            self.object_ids[slots],
            self.objects[slots],
            self.object_fe[slots],
            joint,
            with_retired,
            cross,
        )
        self._cov = self._cov[np.ix_(keep, keep)]
        self._remove_object_entries(slots)
        loosened = self.retired.loosen(max_consider)
        self._check("object retirement")
        return loosened

    def reenter_objects(self, ids: np.ndarray, frame: int) -> None:
        """Bring retired objects ``ids`` back into the active state, observed at ``frame``.

        Each comes back with its stored mean and first estimate, and the joint covariance comes
        back whole: theirs, their cross-covariance with the active state and with the objects
        that stay retired (:mod:`teamslam.msckf.filter.persistent_map`).
        """
        ids = np.asarray(ids, dtype=np.int64).ravel()
        if ids.size == 0:
            return
        means, fe, joint, cross, with_retired = self.retired.take(ids)
        n, k = self.dim, ids.size
        cov = np.empty((n + 3 * k, n + 3 * k))
        cov[:n, :n] = self._cov
        cov[n:, :n] = cross
        cov[:n, n:] = cross.T
        cov[n:, n:] = joint
        self._cov = cov
        self._consider_columns(lambda c: np.concatenate([c, with_retired], axis=1))
        self.object_ids = np.concatenate([self.object_ids, ids])
        self.objects = np.vstack([self.objects, means])
        self.object_fe = np.vstack([self.object_fe, fe])
        self.object_last_seen = np.concatenate(
            [self.object_last_seen, np.full(k, int(frame), dtype=np.int64)]
        )
        self._check("object re-entry")

    def _consider_columns(self, edit: Callable[[np.ndarray], np.ndarray] | None) -> None:
        """After an edit of the active state's columns: the consider states' cross-covariance
        ``edit(C)`` (an empty map follows the new dimension)."""
        if self.retired.n_consider:
            self.retired.set_columns(edit(self.retired.cross))
        else:
            self.retired.resize(self._cov.shape[0])

    def correct(self, delta: np.ndarray) -> None:
        """Apply an error-state correction: ``T ← T · exp(δ_T)``, ``p ← p + δ_p`` (eqs. 21, 28)."""
        c = self.n_poses
        self.poses = self.poses @ se3.exp(delta[: 6 * c].reshape(c, 6))
        self.objects = self.objects + delta[6 * c :].reshape(-1, 3)

    def _innovation_factor(
        self, jacobian: np.ndarray, noise_cov: np.ndarray, columns: np.ndarray | None = None
    ) -> tuple[np.ndarray, tuple[np.ndarray, bool], np.ndarray, np.ndarray]:
        """``P Hᵀ`` and the Cholesky factor of ``S = H P Hᵀ + R``, on the columns the rows
        touch only (feature rows touch only window poses), and the rows ``H`` on those columns
        with the columns.

        ``jacobian`` is over the error-state ``columns`` (default: all, in order); its columns
        that are exactly zero are left out.
        """
        touched = np.any(jacobian != 0.0, axis=0)
        if columns is None:
            cols = np.flatnonzero(touched)
            h = jacobian[:, cols]
        else:
            cols = np.asarray(columns)[touched]
            h = jacobian[:, touched]
        pht = self._cov[:, cols] @ h.T
        innovation_cov = h @ pht[cols] + noise_cov
        try:  # upper factor: S = Uᵀ U
            factor = scipy.linalg.cho_factor(0.5 * (innovation_cov + innovation_cov.T), lower=False)
        except np.linalg.LinAlgError:
            raise NotPositiveDefiniteError(
                "innovation covariance is not positive definite"
            ) from None
        return pht, factor, h, cols

    def update(
        self,
        jacobian: np.ndarray,
        residual: np.ndarray,
        noise_cov: np.ndarray,
        robot: int | None = None,
        columns: np.ndarray | None = None,
    ) -> np.ndarray:
        """Kalman update (eqs. 26–28, ``S = 0``) with a Cholesky-factored innovation covariance.

        ``jacobian`` is compact over the error-state ``columns`` (increasing; OpenVINS'
        ``H_order``, e.g. :class:`~teamslam.msckf.filter.update.MeasurementRows`), or full width
        (``columns=None``). Returns the applied correction.

        Raises
        ------
        EstimationError
            A non-finite Jacobian, residual or noise (named with robot — ``robot``, else the
            state's own — and frame); the state is left exactly as it was.
        NotPositiveDefiniteError
            The innovation covariance is not positive definite (state left as it was).
        """
        self.check_finite("measurement Jacobian", jacobian, robot=robot)
        self.check_finite("measurement residual", residual, robot=robot)
        self.check_finite("measurement noise", noise_cov, robot=robot)
        pht, (upper, _), h, cols = self._innovation_factor(jacobian, noise_cov, columns)
        # S = Uᵀ U: with W = U⁻ᵀ (P Hᵀ)ᵀ the gain is K = Wᵀ U⁻ᵀ and P⁺ = P − Wᵀ W, one
        # symmetric rank-k product (BLAS syrk): exactly symmetric, half the flops of K (P Hᵀ)ᵀ
        whitened = scipy.linalg.solve_triangular(upper, pht.T, trans="T", check_finite=False)
        step = scipy.linalg.solve_triangular(upper, residual, trans="T", check_finite=False)
        delta = whitened.T @ step
        self.check_finite("correction of the update", delta, robot=robot)
        self._cov = self._cov - whitened.T @ whitened
        if self.retired.n_consider:
            # Schmidt: the consider states' gain is zero, their means and covariance stay;
            # their cross-covariance becomes C (I − K H)ᵀ = C − (U⁻ᵀ H Cᵀ)ᵀ W
            consider = self.retired.cross
            seen = scipy.linalg.solve_triangular(
                upper, h @ consider[:, cols].T, trans="T", check_finite=False
            )
            consider -= seen.T @ whitened
        self.correct(delta)
        self._check("update")
        return delta

    def update_rows(self, rows: MeasurementRows, robot: int | None = None) -> np.ndarray:
        """:meth:`update` with stacked rows (compact or full width)."""
        return self.update(
            rows.jacobian, rows.residual, np.diag(rows.variance), robot=robot, columns=rows.columns
        )

    def iterated_update(
        self,
        rows_at: Callable[[], MeasurementRows | tuple[np.ndarray, np.ndarray, np.ndarray]],
        iterations: int,
        tolerance: float = 1e-2,
        robot: int | None = None,
    ) -> tuple[np.ndarray, int]:
        """Iterated EKF update: Gauss–Newton on the prior and a nonlinear measurement.

        ``rows_at()`` returns the rows — :class:`~teamslam.msckf.filter.update.MeasurementRows`
        (compact over their columns) or ``(H, r, σ²)`` over the whole error state: Jacobian,
        residual ``z − h(x)`` and per-row noise variance — linearised at the state's current
        mean; it must return the same rows (same measurements, same order) every time. With
        ``x₀`` the prior mean, ``P`` its covariance and ``δᵢ`` the error of iterate
        ``xᵢ = x₀ ⊞ δᵢ`` (``δ₀ = 0``),

            ``δᵢ₊₁ = Kᵢ (rᵢ + Hᵢ δᵢ)``,  ``Kᵢ = P Hᵢᵀ (Hᵢ P Hᵢᵀ + R)⁻¹``,

        (Bell and Cathey 1993: the Gauss–Newton step on ``‖δ‖²_P⁻¹ + ‖z − h(x₀ ⊞ δ)‖²_R⁻¹``); the
        mean moves to ``x₀ ⊞ δ`` and the covariance is ``(I − K H) P`` with the last
        linearisation. One iteration is the EKF update (:meth:`update`). It stops early once no
        predicted measurement moves by more than ``tolerance`` of its noise std between
        linearisations. Only the mean is moved between linearisations; the covariance is
        touched once.

        Returns
        -------
        delta, linearisations
            The applied correction (``x₀ ⊞ delta`` is the new mean) and how many
            linearisations were used.

        Raises
        ------
        EstimationError
            Non-finite rows at any linearisation (robot and frame named); the state is left as
            it was.
        """

        def linearise() -> MeasurementRows:
            got = rows_at()
            rows = got if isinstance(got, MeasurementRows) else MeasurementRows(*got)
            self.check_finite(
                "measurement rows", rows.jacobian, rows.residual, rows.variance, robot=robot
            )
            return rows

        poses, objects = self.poses, self.objects
        rows = linearise()
        delta = np.zeros(self.dim)
        used = 1
        try:
            for _ in range(iterations - 1):
                if rows.rows == 0:
                    break
                # H δ as a full-width product: the sum over every column keeps the arithmetic
                # (and the results, bit for bit) of full-width rows; P Hᵀ and S stay compact
                wide = rows.full(self.dim)
                pht, factor, _, _ = self._innovation_factor(
                    rows.jacobian, np.diag(rows.variance), rows.columns
                )
                step = pht @ scipy.linalg.cho_solve(factor, rows.residual + wide @ delta)
                moved = np.abs(wide @ (step - delta)) / np.sqrt(rows.variance)
                delta = step
                self.poses, self.objects = poses, objects
                self.correct(delta)
                rows = linearise()
                used += 1
                if moved.max() <= tolerance:
                    break
        finally:
            self.poses, self.objects = poses, objects
        applied = np.zeros(self.dim)
        if rows.rows:
            applied = self.update(
                rows.jacobian,
                rows.residual + rows.full(self.dim) @ delta,
                np.diag(rows.variance),
                robot=robot,
                columns=rows.columns,
            )
        return applied, used

    def replace_marginal(
        self,
        index: np.ndarray,
        mean: np.ndarray,
        cov: np.ndarray,
        info: np.ndarray | None = None,
    ) -> None:
        """Consensus: give the ``index`` block (object coordinates) a new marginal (Prop. 2).

        The error-state mean of every other entry shifts by ``A (μ̄ʸ − μʸ)``; window poses take
        that shift through ``T ← T · exp(δ)`` (eq. 21), other objects additively. First
        estimates are left as they were (why: :mod:`teamslam.msckf.filter.linearization`). ``info``
        is the inverse of the block's current covariance when the caller already has it.
        The joint is rebuilt block by block (:func:`~teamslam.gaussian.replace_marginal_shift`).

        Raises
        ------
        EstimationError
            A non-finite new marginal; the state is left as it was.
        InternalError
            Coordinates that are not objects', or sizes that do not match.
        """
        index = np.asarray(index, dtype=np.int64)
        slot_cols = index - 6 * self.n_poses
        if np.any(slot_cols < 0):
            raise InternalError("consensus may only replace object coordinates")
        mean = np.asarray(mean, dtype=float)
        cov = np.asarray(cov, dtype=float)
        k = index.size
        if mean.shape != (k,) or cov.shape != (k, k):
            raise InternalError(f"new marginal {mean.shape}, {cov.shape} for {k} coordinates")
        self.check_finite("consensus marginal", mean, cov)
        if self.retired.n_consider:
            self._consider_consensus(index, cov, info)
        shift_y = mean - self.objects.ravel()[slot_cols]
        delta, self._cov = replace_marginal_shift(self._cov, index, shift_y, cov, info)
        self.correct(delta)
        self._check("consensus")

    def average_retired(self, ids: np.ndarray, means: np.ndarray, covs: np.ndarray) -> None:
        """Consensus on the persistent map: retired objects ``ids`` take new means ``(k, 3)`` and
        3×3 marginals ``covs``, one object ``y`` at a time.

        Prop. 2 with everything else a consider state of that average: no other mean moves, the
        object's cross-covariances follow Prop. 2, ``Σ_zy ← A_z Σ̄ʸ`` with ``A_z = Σ_zy Σʸ⁻¹``,
        and where the average loses information (``Σ̄ʸ − Σʸ`` has positive eigenvalues
        ``D₊``) the rest grows by ``A D₊ Aᵀ``, what Prop. 2 would add to it, so the joint stays a
        covariance; where it adds information nothing else changes (Schmidt).

        Raises
        ------
        EstimationError
            A non-finite mean or marginal; the state is left as it was.
        """
        ids = np.asarray(ids, dtype=np.int64).ravel()
        covs = np.asarray(covs, dtype=float).reshape(-1, 3, 3)
        means = np.asarray(means, dtype=float).reshape(-1, 3)
        self.check_finite("consensus marginal of retired objects", means, covs)
        retired = self.retired
        loose = ~retired.is_consider(ids)
        retired.set_loose(ids[loose], means[loose], covs[loose])  # uncorrelated: replaced
        for object_id, mean, cov in zip(
            ids[~loose].tolist(), means[~loose], covs[~loose], strict=True
        ):
            y = retired.coordinates(np.array([object_id]))
            consider, joint = retired.cross, retired.joint
            sigma_y = joint[np.ix_(y, y)]
            info = scipy.linalg.cho_solve(
                scipy.linalg.cho_factor(sigma_y), np.eye(3), check_finite=False
            )
            from_active = consider[y].T @ info  # (d, 3)
            from_retired = joint[:, y] @ info  # (3r, 3), zero on y itself
            from_retired[y] = 0.0
            cov = 0.5 * (cov + cov.T)
            values, vectors = np.linalg.eigh(cov - sigma_y)
            lost = values > 0
            if lost.any():
                root = vectors[:, lost] * np.sqrt(values[lost])
                grow_a, grow_r = from_active @ root, from_retired @ root
                self._cov = self._cov + 0.5 * (grow_a @ grow_a.T + (grow_a @ grow_a.T).T)
                consider += grow_r @ grow_a.T
                joint += 0.5 * (grow_r @ grow_r.T + (grow_r @ grow_r.T).T)
            consider[y] = (from_active @ cov).T
            column = from_retired @ cov
            joint[:, y] = column
            joint[y, :] = column.T
            joint[np.ix_(y, y)] = cov
            retired.set_mean(object_id, mean)
        self._check("consensus on the persistent map")

    def _consider_consensus(
        self, index: np.ndarray, cov_y: np.ndarray, info: np.ndarray | None
    ) -> None:
        """The persistent map's part of :meth:`replace_marginal` (before the active state's).

        A neighbour's average is a consider update for the retired objects (Schmidt): their
        means and covariance stay, their cross-covariance with the active state follows Prop. 2
        as the active state's own rows do, ``C ← C + B (Σ̄ʸ − Σʸ) Σʸ⁻¹ Σ[y, :]`` with
        ``B = C[:, y] Σʸ⁻¹`` (so ``C[:, y] ← B Σ̄ʸ``). Where the average loses information
        (``Σ̄ʸ − Σʸ`` has positive eigenvalues ``D₊``) a fixed consider covariance would no longer
        fit the joint: it grows by ``B D₊ Bᵀ``, what Prop. 2 would add to it, so the joint
        stays a covariance (conservative where the average adds information).
        """
        rows = self._cov[index, :]
        sigma_y = rows[:, index]
        if info is None:
            info = scipy.linalg.cho_solve(
                scipy.linalg.cho_factor(sigma_y), np.eye(index.size), check_finite=False
            )
        consider = self.retired.cross
        regression = consider[:, index] @ info
        change = 0.5 * (cov_y + cov_y.T) - sigma_y
        consider += (regression @ change @ info) @ rows
        values, vectors = np.linalg.eigh(change)
        lost = values > 0
        if lost.any():
            grow = regression @ (vectors[:, lost] * np.sqrt(values[lost]))
            joint = self.retired.joint
            joint += 0.5 * (grow @ grow.T + (grow @ grow.T).T)


def _shared(name: str, doc: str) -> property:
    """A read-only attribute of :class:`RobotWindow` that is the shared state's ``name``."""
    return property(lambda window: getattr(window.state, name), doc=doc)


class RobotWindow:
    """One robot's window inside a (team) :class:`MsckfState`, with the single-robot interface.

    Window quantities (``poses``, ``pose_fe``, ``frames``, ``n_poses``, ``current_pose``,
    column maps, :meth:`augment`, :meth:`marginalize_oldest`) are the robot's; the map, the
    covariance and the updates are the shared state's, each named below (nothing else is
    forwarded); errors of the updates name this robot.
    """

    def __init__(self, state: MsckfState, robot: int) -> None:
        self.state = state
        self.robot = int(robot)

    # the shared state's map and covariance, by name (nothing else is forwarded)
    cov = _shared("cov", "The shared joint covariance (read-only).")
    dim = _shared("dim", "Error-state dimension of the shared state.")
    objects = _shared("objects", "The shared map's objects ``(m, 3)``.")
    object_ids = _shared("object_ids", "The shared map's object ids.")
    object_fe = _shared("object_fe", "First estimates of the shared map's objects.")
    object_last_seen = _shared("object_last_seen", "Frame each object was last observed.")
    retired = _shared("retired", "The shared persistent map.")
    n_objects = _shared("n_objects", "Objects in the shared map.")
    object_slots = _shared("object_slots", ":meth:`MsckfState.object_slots`.")
    object = _shared("object", ":meth:`MsckfState.object`.")
    covariance = _shared("covariance", ":meth:`MsckfState.covariance`.")
    cross_covariance = _shared("cross_covariance", ":meth:`MsckfState.cross_covariance`.")
    full_map = _shared("full_map", ":meth:`MsckfState.full_map` of the shared map.")
    mark_seen = _shared("mark_seen", ":meth:`MsckfState.mark_seen`.")
    retire_objects = _shared("retire_objects", ":meth:`MsckfState.retire_objects`.")
    reenter_objects = _shared("reenter_objects", ":meth:`MsckfState.reenter_objects`.")
    snapshot = _shared("snapshot", ":meth:`MsckfState.snapshot` of the shared state.")
    restore = _shared("restore", ":meth:`MsckfState.restore` of the shared state.")

    def where(self) -> str:
        """``"robot r, frame t"`` of this robot's newest frame."""
        return self.state.where(self.robot)

    def pose(self, window_index: np.ndarray | int) -> PoseHandle:
        """Handle of the robot's window poses at ``window_index`` (positions in its window)."""
        a, _ = self._range()
        index = a + np.asarray(window_index, dtype=np.int64)
        return PoseHandle(index, self.state.frames[index], self.state.pose_columns(index))

    def newest_pose(self) -> PoseHandle:
        """Handle of the robot's newest pose."""
        return self.pose(self.n_poses - 1)

    # the robot's own window

    def _range(self) -> tuple[int, int]:
        robots = self.state.robots
        return (
            int(np.searchsorted(robots, self.robot, "left")),
            int(np.searchsorted(robots, self.robot, "right")),
        )

    @property
    def poses(self) -> np.ndarray:
        """The robot's window poses (oldest first)."""
        a, b = self._range()
        return self.state.poses[a:b]

    @property
    def pose_fe(self) -> np.ndarray:
        """First estimates of the robot's window poses."""
        a, b = self._range()
        return self.state.pose_fe[a:b]

    @property
    def frames(self) -> np.ndarray:
        """Frame indices of the robot's window."""
        a, b = self._range()
        return self.state.frames[a:b]

    @property
    def n_poses(self) -> int:
        """Poses in the robot's window."""
        a, b = self._range()
        return b - a

    @property
    def window_columns(self) -> slice:
        """Error-state columns of the robot's window poses."""
        a, b = self._range()
        return slice(6 * a, 6 * b)

    def pose_columns(self, window_index: np.ndarray) -> np.ndarray:
        """Error-state columns ``(k, 6)`` of the robot's window poses."""
        a, _ = self._range()
        return 6 * (a + np.asarray(window_index))[..., None] + np.arange(6)

    def window_index(self, frames: np.ndarray) -> np.ndarray:
        """Positions of frame indices in the robot's window (``-1`` where absent)."""
        own = self.frames
        frames = np.asarray(frames, dtype=np.int64)
        pos = np.clip(np.searchsorted(own, frames), 0, own.size - 1)
        return np.where(own[pos] == frames, pos, -1)

    @property
    def current_pose(self) -> np.ndarray:
        """The robot's newest pose."""
        return self.poses[-1]

    def current_pose_cov(self) -> np.ndarray:
        """6×6 covariance of the robot's newest pose."""
        _, b = self._range()
        s = slice(6 * (b - 1), 6 * b)
        return self.state.cov[s, s]

    def augment(
        self,
        odometry: np.ndarray,
        frame: int,
        odometry_cov: np.ndarray,
        jacobian_step: np.ndarray | None = None,
    ) -> None:
        """:meth:`MsckfState.augment` of this robot's window."""
        self.state.augment(odometry, frame, odometry_cov, self.robot, jacobian_step)

    def marginalize_oldest(self) -> None:
        """:meth:`MsckfState.marginalize_oldest` of this robot's window."""
        self.state.marginalize_oldest(self.robot)

    def update(
        self,
        jacobian: np.ndarray,
        residual: np.ndarray,
        noise_cov: np.ndarray,
        columns: np.ndarray | None = None,
    ) -> np.ndarray:
        """:meth:`MsckfState.update` of the shared state, errors naming this robot."""
        return self.state.update(jacobian, residual, noise_cov, robot=self.robot, columns=columns)

    def update_rows(self, rows: MeasurementRows) -> np.ndarray:
        """:meth:`MsckfState.update_rows` of the shared state, errors naming this robot."""
        return self.state.update_rows(rows, robot=self.robot)

    def iterated_update(
        self,
        rows_at: Callable[[], MeasurementRows | tuple[np.ndarray, np.ndarray, np.ndarray]],
        iterations: int,
        tolerance: float = 1e-2,
    ) -> tuple[np.ndarray, int]:
        """:meth:`MsckfState.iterated_update` of the shared state, errors naming this robot."""
        return self.state.iterated_update(rows_at, iterations, tolerance, robot=self.robot)

    def add_object(
        self,
        object_id: int,
        position: np.ndarray,
        cov_pp: np.ndarray,
        cov_ps: np.ndarray,
        first_estimate: np.ndarray | None = None,
        from_columns: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        """:meth:`MsckfState.add_object` to the shared state, errors naming this robot."""
        self.state.add_object(
            object_id,
            position,
            cov_pp,
            cov_ps,
            robot=self.robot,
            first_estimate=first_estimate,
            from_columns=from_columns,
        )

    def check_finite(self, what: str, *arrays: np.ndarray) -> None:
        """:meth:`MsckfState.check_finite`, naming this robot."""
        self.state.check_finite(what, *arrays, robot=self.robot)


def _with_consider(cov: np.ndarray, retired: PersistentMap) -> np.ndarray:
    """The joint covariance of the active state and the persistent map's consider states."""
    if retired.n_consider == 0:
        return cov
    n, cross = cov.shape[0], retired.cross
    out = np.empty((n + cross.shape[0], n + cross.shape[0]))
    out[:n, :n] = cov
    out[n:, :n] = cross
    out[:n, n:] = cross.T
    out[n:, n:] = retired.joint
    return out
