"""Settings of one robot's distributed MSCKF.

Where a run's settings come from — camera-scaled defaults, the dataset's sensor model,
calibration, a config file, flags — is decided in :mod:`teamslam.msckf.settings.sources`; this
module
only holds and validates them.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from teamslam.errors import InputError
from teamslam.gaussian import chi2_quantile

__all__ = ["MsckfConfig"]


def _is_count(value, least: int) -> bool:
    """Whether ``value`` is an integer (not a bool) of at least ``least``."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= least


@dataclass(frozen=True)
class MsckfConfig:
    """Noise levels, window size, thresholds.

    Attributes
    ----------
    window
        Window size ``c`` (number of body poses kept).
    odometry_std
        Six per-axis std of the odometry noise per step, translation ``(x, y, z)`` in metres then
        rotation ``(x, y, z)`` in radians (body frame, right perturbation):
        ``W = diag(odometry_std)²``.
    feature_std, object_std
        Std of each stereo coordinate of geometric features and of object box centres, in the
        units of the camera intrinsics (pixels; normalised coordinates when ``K = I``).
    min_track_length
        Fewest observations of a geometric feature used in an MSCKF update.
    object_init_observations
        Observations of an object (inside the window) needed to initialise it.
    object_min_depth, object_max_depth
        Accepted distance of a new object from the current pose (metres).
    gate_probability
        Chi-square gate: a feature or object whose normalised innovation exceeds this quantile
        of χ²(dof) — dof = its residual length — is rejected.
    object_loss, object_loss_scale
        Robust object updates for heavy-tailed detections: ``none`` (Gaussian), ``huber`` or
        ``cauchy``. An accepted object whose innovation has Mahalanobis distance ``d`` (in
        standard deviations of its predicted innovation) is updated with its measurement
        variance divided by the weight ``w(d)`` — Huber ``min(1, c/d)``, Cauchy
        ``1/(1 + (d/c)²)`` with ``c = object_loss_scale`` — one reweighting step of the
        M-estimator, unit-free like the gate.
    use_geometric_features, use_objects
        Which measurements to use.
    initial_pose_std
        Std of the first pose (tiny: robots start from a known pose in the common frame).
    consensus_kl_threshold
        Consensus averages a common object with a neighbour only when its marginal has moved,
        on either robot, since the two last exchanged it: by more than this Kullback–Leibler
        divergence (nats; unit-free, so the same for any camera or scale). 0 averages every
        common object at every step, as the paper does.
    consensus_set
        Which common objects consensus averages jointly: ``all`` (the paper: every common
        object that moved, so the joint inverted each step grows with the shared map) or
        ``active`` (a bounded set: the objects the window can still change — observed within
        the window, or with mutual information above ``consensus_active_information`` with the
        window poses — and the others only when they moved by more than
        ``consensus_inactive_kl_threshold``); lock-step exchanges only;
        :mod:`teamslam.msckf.consensus.selection` derives what it loses.
    consensus_active_information
        With ``consensus_set = active``: an object not observed within the window is active
        while its mutual information with the window poses exceeds this (nats, unit-free;
        default ``inf``: only the objects observed within the window are active — on a route
        that revisits one area every mapped object stays correlated with the poses).
    consensus_inactive_kl_threshold
        With ``consensus_set = active``: an inactive object is averaged with a neighbour when
        its marginal moved by more than this Kullback–Leibler divergence (nats) since the pair
        last exchanged it (active objects, and objects the pair averaged in the previous
        exchange — an average once started runs to agreement — use
        ``consensus_kl_threshold``).
    consensus_per_object
        Send each common object's own 3×3 marginal instead of the joint marginal of all of
        them (the cross-object covariances are dropped from the message, not from the filter):
        the message grows linearly instead of quadratically with the objects shared.
    consensus_float32
        Send means and covariances in single precision (half the bytes) where rounding is
        harmless: a message goes in float32 only when the rounded marginal is within
        :data:`~teamslam.msckf.consensus.FLOAT32_MAX_KL` (1e-4 nats) of the exact one, else in
        float64 (:func:`~teamslam.msckf.consensus.common_marginal_message`).
    consensus_hybrid
        Hybrid consensus: the new information each robot gathered since its last exchange
        enters the neighbours' averages at full weight instead of the Metropolis weight (after
        HCMCI, Battistelli et al. 2015), with gains that never count one robot's new
        information twice; the plain average (``False``, the paper's) is conservative by about
        the number of robots averaging. Joint marginals, lock-step exchanges only;
        :mod:`teamslam.msckf.consensus`.
    consensus_increments
        Consensus on information increments: hybrid consensus (its messages, gains and
        priors) in which the robot's own new information enters its average exactly once on
        every object — each neighbour's marginal is completed against our prior rather than
        our current marginal — so partial maps and partial exchanges no longer dilute it (the
        hybrid rule counts it less than once wherever a message lacks some averaged object).
        Never counts an increment twice on any graph, with link loss and partial maps; joint
        marginals, lock-step exchanges only; :mod:`teamslam.msckf.consensus.average`.
    consensus_iterations
        Consensus exchanges per step (``L``, default 1): both rounds and the average are run
        ``L`` times before each frame, every exchange with its own messages and link losses, so
        estimates on a sparse graph come closer to the network average at ``L`` times the
        messages. With hybrid consensus or increments each robot's new information is sent at
        its gain in the first exchange only (the later ones average the fused estimates, a
        convex combination), so no increment is counted twice for any ``L``. Lock-step only
        (asynchronous robots exchange once per step); every robot of a team must use the same
        ``L``; :mod:`teamslam.msckf.consensus.protocol`.
    linearization
        Where Jacobians are evaluated: ``std`` (current estimate), ``fej`` (first estimates)
        ``ideal`` (ground truth, simulation only) or ``oc`` (observability-constrained);
        :mod:`teamslam.msckf.filter.linearization`.
    object_retire_after
        Frames an object may go unobserved before it leaves the filter state for the robot's
        persistent map (its mean and 3×3 marginal kept; it re-enters with them when observed
        again): this bounds the state, and so the cost per frame, over a long mission. 0 never
        retires an object (the state keeps every object it initialised). Policy, exactness and
        what it means for consensus: :mod:`teamslam.msckf.filter.persistent_map`.
    debug
        Check the covariance after every edit.
    object_init_max_relative_std
        An object enters the state only once its initial position is certain relative to its
        distance: the largest standard deviation of its initial covariance (eq. 30, the largest
        axis) at most this fraction of its distance from the current pose. A less certain
        object waits for more observations inside the window (unit-free). Far objects seen by
        stereo from a few frames are strongly nonlinear in depth; their linearised initial
        covariance is then overconfident, and every filter (``std`` and ``fej`` alike) inherits
        that. 0 (the default) initialises as soon as ``object_init_observations`` are in the
        window. On the simulated stereo team 0.1 brings the object ANEES of every filter into
        the χ² band; on real detections with a calibrated noise it can keep objects from
        entering at all (fewer common objects for consensus), so it is not the default.
    object_update_iterations
        Linearisations of the object rows per frame: 1 is the EKF update of the paper (objects
        and geometric features in one stacked update, every Jacobian at the prior); ``k > 1``
        updates with the features first, then with the objects by an iterated EKF (Gauss–Newton
        on the prior and the object measurements, :meth:`MsckfState.iterated_update`): the
        object rows are linearised again at the updated estimate up to ``k − 1`` times, until
        no predicted measurement moves by more than a hundredth of its noise std. Every row
        keeps the linearisation policy's pose Jacobians (first estimates for ``fej``). Measured
        (README, "Consistency of the 3D team filter"): with ``fej`` it brings the centralised
        filter's object ANEES into the χ² band (5.4 → 1.1, 20 runs) and the KITTI 00 object NIS
        to 1.0; with ``std`` and ``oc``, which lack ``fej``'s linearisation noise, it makes both
        filters markedly more overconfident; on small simulated teams it moved ``fej``'s RMSE
        either way by up to 58%; a KITTI 00 run takes about 3× as long. Off by default.
    track_gate_probability
        Object tracking (a robot with detections without ids,
        :mod:`teamslam.msckf.objects.tracking`):
        a detection may be assigned to a predicted object or track only when its squared
        Mahalanobis distance under the filter's innovation covariance is at most this quantile
        of χ²(4).
    track_birth_probability
        The outer gate, a wider quantile of χ²(4) than ``track_gate_probability``: an object
        of the state seen within the last ``N`` frames (``track_confirm_frames``), or a track,
        that took no detection this frame takes one left outside every gate but inside its
        outer gate when the pair is alone there (a detector's heavy-tailed error keeps its
        object); such a detection, when not alone, starts no track (one object, one id). A
        detection near an object that took another one starts a track (a detector boxes an
        object once per frame); objects unseen for longer block nothing. Set it to
        ``track_gate_probability`` to turn the outer gate off.
    track_confirm_hits, track_confirm_frames
        A tentative track is confirmed after ``M = track_confirm_hits`` detections within its
        first ``N = track_confirm_frames`` frames, and dropped otherwise; a confirmed track not
        yet in the state is dropped after ``N`` frames without a detection. 0 takes the
        defaults ``M = object_init_observations`` and ``N = M + 2``.
    track_loop_closure
        Loop closure in each tracking robot's own map (:mod:`teamslam.msckf.objects.loop_closure`):
        the
        objects it created last are matched by the shape of the group against its objects
        unseen for longer than the window (the own association's rules), and each accepted
        pair is merged in the filter (an EKF update with ``x_new − x_old = 0``, then the new
        object leaves the state).
    association
        Which objects of two neighbours are the same: ``oracle`` (equal ids — the dataset's ids
        are team-wide) or ``own`` (each robot names its own objects; each link finds its
        correspondences from exchanged object summaries, :mod:`teamslam.association`, and
        consensus averages the matched pairs).
    association_interval
        With ``own``: steps between two exchanges of object summaries on a link (each exchange
        runs a full association when the link's table is due, else grows it).
    association_revoke_probability
        With ``own``: probability of the ``χ²₃`` test of each matched pair's consensus
        innovation; a pair that fails is left out of the average and revoked for good. The
        default 0.99999 (a threshold of 25.9) suits filters that are somewhat overconfident
        (KITTI 00: 0.999 revoked 107 pairs, 0.99999 89, with higher precision and recall); a
        neighbour 20 m off with a tiny covariance gives values of 10⁸ and more.
    consensus_innovation_check
        With ``oracle``: the same ``χ²₃`` test of each common object's consensus innovation; a
        neighbour's marginal in which most objects fail (a member that sends marginals far off
        with a tiny covariance) is left out of the step's average. On by default (security that
        must be switched on is not security); an honest run differs from one without it only
        when most objects of one message fail (KITTI 00: 4 of 5886 messages).
    """

    window: int = 20
    odometry_std: tuple[float, ...] = (0.02, 0.02, 0.02, 0.004, 0.004, 0.004)
    feature_std: float = 1.0
    object_std: float = 2.0
    min_track_length: int = 3
    object_init_observations: int = 3
    object_min_depth: float = 1.0
    object_max_depth: float = 40.0
    gate_probability: float = 0.95
    object_loss: str = "none"
    object_loss_scale: float = 2.0
    use_geometric_features: bool = True
    use_objects: bool = True
    initial_pose_std: float = 1e-4
    consensus_kl_threshold: float = 1e-3
    consensus_set: str = "all"
    consensus_active_information: float = float("inf")
    consensus_inactive_kl_threshold: float = 0.3
    consensus_per_object: bool = False
    consensus_float32: bool = True
    consensus_hybrid: bool = False
    consensus_increments: bool = False
    consensus_iterations: int = 1
    linearization: str = "std"
    object_retire_after: int = 0
    debug: bool = False
    object_init_max_relative_std: float = 0.0
    object_update_iterations: int = 1
    track_gate_probability: float = 0.99
    track_birth_probability: float = 0.999999
    track_confirm_hits: int = 0
    track_confirm_frames: int = 0
    track_loop_closure: bool = False
    association: str = "oracle"
    association_interval: int = 5
    association_revoke_probability: float = 0.99999
    consensus_innovation_check: bool = True

    def __post_init__(self) -> None:
        if not _is_count(self.window, 2):
            raise InputError("window must be an integer of at least 2 poses")
        odometry = self.odometry_std
        if isinstance(odometry, int | float):
            raise InputError("odometry_std must be six numbers (x, y, z in m; rx, ry, rz in rad)")
        odometry = tuple(float(v) for v in odometry)
        if len(odometry) != 6 or not all(np.isfinite(v) and v > 0 for v in odometry):
            raise InputError("odometry_std must be six positive numbers")
        object.__setattr__(self, "odometry_std", odometry)
        for name in ("feature_std", "object_std", "initial_pose_std", "object_min_depth"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (np.isfinite(value) and value > 0):
                raise InputError(f"{name} must be a positive number")
        if not self.object_max_depth > self.object_min_depth:
            raise InputError("object_max_depth must exceed object_min_depth")
        threshold = self.consensus_kl_threshold
        if isinstance(threshold, bool) or not (np.isfinite(threshold) and threshold >= 0):
            raise InputError("consensus_kl_threshold must be a number ≥ 0 (nats)")
        if self.consensus_set not in ("all", "active"):
            raise InputError(f"consensus_set must be all or active, not {self.consensus_set!r}")
        for name in ("consensus_active_information", "consensus_inactive_kl_threshold"):
            value = getattr(self, name)
            if isinstance(value, bool) or not value >= 0:  # inf: never by this test
                raise InputError(f"{name} must be a number ≥ 0 (nats; inf allowed)")
        for name in ("consensus_hybrid", "consensus_increments"):
            if getattr(self, name) and self.consensus_per_object:
                raise InputError(
                    f"{name} needs joint marginals: it cannot be used with consensus_per_object"
                )
        if not _is_count(self.consensus_iterations, 1):
            raise InputError("consensus_iterations must be an integer of at least 1 (exchanges)")
        if self.object_loss not in ("none", "huber", "cauchy"):
            raise InputError(f"object_loss must be none, huber or cauchy, not {self.object_loss!r}")
        scale = self.object_loss_scale
        if isinstance(scale, bool) or not (np.isfinite(scale) and scale > 0):
            raise InputError("object_loss_scale must be a positive number (standard deviations)")
        if not 0 < self.gate_probability < 1:
            raise InputError("gate_probability must lie in (0, 1)")
        if self.linearization not in ("std", "fej", "ideal", "oc"):
            raise InputError(
                f"linearization must be std, fej, ideal or oc, not {self.linearization!r}"
            )
        if not _is_count(self.object_retire_after, 0):
            raise InputError(
                "object_retire_after must be an integer number of frames ≥ 0 (0: never retire)"
            )
        for name in ("min_track_length", "object_init_observations"):
            if not _is_count(getattr(self, name), 2):
                raise InputError(f"{name} must be an integer of at least 2 observations")
        if not _is_count(self.object_update_iterations, 1):
            raise InputError(
                "object_update_iterations must be an integer of at least 1 (1: the EKF update)"
            )
        if self.association not in ("oracle", "own"):
            raise InputError(f"association must be oracle or own, not {self.association!r}")
        if not _is_count(self.association_interval, 1):
            raise InputError("association_interval must be an integer number of steps ≥ 1")
        revoke = self.association_revoke_probability
        if isinstance(revoke, bool) or not 0.0 < revoke < 1.0:
            raise InputError("association_revoke_probability must lie in (0, 1)")
        relative = self.object_init_max_relative_std
        if isinstance(relative, bool) or not (np.isfinite(relative) and relative >= 0):
            raise InputError(
                "object_init_max_relative_std must be a number ≥ 0 (a fraction of the distance; "
                "0: no wait)"
            )

        self._validate_tracking()

    def _validate_tracking(self) -> None:
        if not isinstance(self.track_loop_closure, bool | np.bool_):
            raise InputError(
                f"track_loop_closure must be true or false, got {self.track_loop_closure!r}"
            )
        for name in ("track_gate_probability", "track_birth_probability"):
            if not 0 < getattr(self, name) < 1:
                raise InputError(f"{name} must lie in (0, 1)")
        for name in ("track_confirm_hits", "track_confirm_frames"):
            if not _is_count(getattr(self, name), 0):
                raise InputError(f"{name} must be an integer ≥ 0 (0: the default)")
        hits = self.track_confirm_hits or self.object_init_observations
        frames = self.track_confirm_frames or hits + 2
        if frames < hits:
            raise InputError(
                f"track_confirm_frames ({frames}) must be at least track_confirm_hits ({hits})"
            )

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """Every setting's name."""
        return tuple(f.name for f in fields(cls))

    def odometry_cov(self) -> np.ndarray:
        """``W`` (6×6)."""
        return np.diag(np.square(self.odometry_std))

    def robust_weight(self, mahalanobis: np.ndarray) -> np.ndarray:
        """The object update's weight ``w(d)`` for Mahalanobis distances ``d`` (1: Gaussian)."""
        d = np.asarray(mahalanobis, dtype=float)
        c = self.object_loss_scale
        if self.object_loss == "huber":
            return np.minimum(1.0, c / np.maximum(d, 1e-300))
        if self.object_loss == "cauchy":
            return 1.0 / (1.0 + (d / c) ** 2)
        return np.ones_like(d)

    def gate(self, dof: int | np.ndarray) -> float | np.ndarray:
        """Chi-square threshold for residuals of ``dof`` entries (each quantile computed once)."""
        dof = np.asarray(dof, dtype=np.int64)
        if dof.ndim == 0:
            return chi2_quantile(self.gate_probability, int(dof))
        values, index = np.unique(dof, return_inverse=True)
        table = np.array([chi2_quantile(self.gate_probability, int(d)) for d in values])
        return table[index].reshape(dof.shape)

    def with_(self, **changes) -> MsckfConfig:
        """A copy with some fields changed."""
        return replace(self, **changes)

    def to_json(self) -> dict:
        """Every setting as plain JSON (the association settings only when not all default:
        a run with oracle ids records what it always did)."""
        out = {
            f.name: list(getattr(self, f.name))
            if isinstance(getattr(self, f.name), tuple)
            else getattr(self, f.name)
            for f in fields(self)
        }
        defaults = {f.name: f.default for f in fields(self) if f.name in _ASSOCIATION_FIELDS}
        if all(out[name] == value for name, value in defaults.items()):
            for name in _ASSOCIATION_FIELDS:
                del out[name]
        return out


_ASSOCIATION_FIELDS = (
    "association",
    "association_interval",
    "association_revoke_probability",
    "consensus_innovation_check",
)
