"""Settings of one robot's distributed MSCKF, in groups.

:class:`MsckfConfig` holds one frozen dataclass per group — ``filter``, ``objects``,
``tracking``, ``consensus``, ``association`` — and each group validates its own fields. A setting
is named ``group.name`` (``filter.window``); every field documents its meaning in its class's
``Attributes`` section and its unit in the field's metadata (``unit``; empty: unit-free). Where a
run's settings come from (defaults, dataset, calibration, file, flags) is decided in
:mod:`teamslam.msckf.settings.sources`; this module only holds and validates them.
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, is_dataclass, replace
from typing import Any

import numpy as np

from teamslam.association import AssociationSettings
from teamslam.errors import InputError
from teamslam.gaussian import chi2_quantile

__all__ = [
    "CONSENSUS_RULES",
    "LINEARIZATIONS",
    "ConsensusSettings",
    "FilterSettings",
    "MsckfConfig",
    "ObjectSettings",
    "TeamAssociationSettings",
    "TrackingSettings",
]

#: The consensus rules (:mod:`teamslam.msckf.consensus.rules`).
CONSENSUS_RULES = ("average", "hybrid", "increments", "ci", "ici")
#: The linearisation policies (:mod:`teamslam.msckf.filter.linearization`).
LINEARIZATIONS = ("std", "fej", "ideal", "oc")


def _unit(unit: str) -> dict[str, str]:
    """A field's metadata: its unit (empty: unit-free)."""
    return {"unit": unit}


def _is_count(value, least: int) -> bool:
    """Whether ``value`` is an integer (not a bool) of at least ``least``."""
    return isinstance(value, int | np.integer) and not isinstance(value, bool) and value >= least


def _is_number(value) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)


def _positive(value) -> bool:
    return _is_number(value) and bool(np.isfinite(value) and value > 0)


def _probability(value) -> bool:
    return _is_number(value) and 0.0 < value < 1.0


def _flag(value) -> bool:
    return isinstance(value, bool | np.bool_)


def _check_flags(group, prefix: str, names: tuple[str, ...]) -> None:
    for name in names:
        if not _flag(getattr(group, name)):
            raise InputError(f"{prefix}.{name} must be true or false, got {getattr(group, name)!r}")


@dataclass(frozen=True)
class FilterSettings:
    """The MSCKF itself: window, noise levels, gate, linearisation.

    Attributes
    ----------
    window
        Window size ``c``: the number of body poses kept.
    odometry_std
        Six per-axis std of the odometry noise per step, translation ``(x, y, z)`` in metres then
        rotation ``(x, y, z)`` in radians (body frame, right perturbation):
        ``W = diag(odometry_std)²``.
    feature_std
        Std of each stereo coordinate of a geometric feature, in the units of the camera
        intrinsics (pixels; normalised coordinates when ``K = I``).
    object_std
        Std of each stereo coordinate of an object's box centre, in the units of the camera
        intrinsics; for detections with a box size, the part of that std that does not
        grow with the box.
    object_size_share
        How a box centre's std grows with the box (detections with a box size only): per
        coordinate ``σ² = object_std² + (object_size_share · s)²``, ``s`` the box's width (for
        ``u``) or height (for ``v``); ``0``: the same σ for every box
        (:mod:`teamslam.msckf.filter.box_noise`).
    object_overconfidence
        Detections with a box size, objects paired by the robots' own association: learn from
        the pairs by how much the objects' covariances are too small, and multiply the box part
        of new boxes' variance by it
        (:class:`~teamslam.msckf.filter.box_noise.Overconfidence`).
    min_track_length
        Fewest observations of a geometric feature used in an MSCKF update.
    gate_probability
        Chi-square gate: a feature or object whose normalised innovation exceeds this quantile
        of χ²(dof) — dof = its residual length — is rejected.
    use_geometric_features
        Use the geometric features.
    use_objects
        Use the objects.
    initial_pose_std
        Std of the first pose, every axis (tiny: robots start from a known pose in the common
        frame).
    linearization
        Where Jacobians are evaluated: ``std`` (current estimate), ``fej`` (first estimates),
        ``ideal`` (ground truth, simulation only) or ``oc`` (observability-constrained);
        :mod:`teamslam.msckf.filter.linearization`.
    debug
        Check the covariance after every edit.
    """

    window: int = field(default=20, metadata=_unit("poses"))
    odometry_std: tuple[float, ...] = field(
        default=(0.02, 0.02, 0.02, 0.004, 0.004, 0.004), metadata=_unit("m, m, m, rad, rad, rad")
    )
    feature_std: float = field(default=1.0, metadata=_unit("camera units"))
    object_std: float = field(default=2.0, metadata=_unit("camera units"))
    object_size_share: float = field(default=0.0, metadata=_unit(""))
    object_overconfidence: bool = field(default=True, metadata=_unit(""))
    min_track_length: int = field(default=3, metadata=_unit("observations"))
    gate_probability: float = field(default=0.95, metadata=_unit(""))
    use_geometric_features: bool = field(default=True, metadata=_unit(""))
    use_objects: bool = field(default=True, metadata=_unit(""))
    initial_pose_std: float = field(default=1e-4, metadata=_unit("m, rad"))
    linearization: str = field(default="std", metadata=_unit(""))
    debug: bool = field(default=False, metadata=_unit(""))

    def __post_init__(self) -> None:
        if not _is_count(self.window, 2):
            raise InputError("filter.window must be an integer of at least 2 poses")
        odometry = self.odometry_std
        if isinstance(odometry, str) or not hasattr(odometry, "__len__"):
            raise InputError(
                "filter.odometry_std must be six numbers (x, y, z in m; rx, ry, rz in rad)"
            )
        if len(odometry) != 6 or not all(_positive(v) for v in odometry):
            raise InputError("filter.odometry_std must be six positive numbers")
        object.__setattr__(self, "odometry_std", tuple(float(v) for v in odometry))
        for name in ("feature_std", "object_std", "initial_pose_std"):
            if not _positive(getattr(self, name)):
                raise InputError(f"filter.{name} must be a positive number")
        if not (_is_number(self.object_size_share) and 0 <= self.object_size_share < np.inf):
            raise InputError("filter.object_size_share must be a number ≥ 0")
        if not _is_count(self.min_track_length, 2):
            raise InputError(
                "filter.min_track_length must be an integer of at least 2 observations"
            )
        if not _probability(self.gate_probability):
            raise InputError("filter.gate_probability must lie in (0, 1)")
        if self.linearization not in LINEARIZATIONS:
            raise InputError(
                f"filter.linearization must be std, fej, ideal or oc, not {self.linearization!r}"
            )
        _check_flags(
            self,
            "filter",
            ("use_geometric_features", "use_objects", "object_overconfidence", "debug"),
        )

    def odometry_cov(self) -> np.ndarray:
        """``W`` (6×6)."""
        return np.diag(np.square(self.odometry_std))

    def gate(self, dof: int | np.ndarray) -> float | np.ndarray:
        """Chi-square threshold for residuals of ``dof`` entries (each quantile computed once)."""
        dof = np.asarray(dof, dtype=np.int64)
        if dof.ndim == 0:
            return chi2_quantile(self.gate_probability, int(dof))
        values, index = np.unique(dof, return_inverse=True)
        table = np.array([chi2_quantile(self.gate_probability, int(d)) for d in values])
        return table[index].reshape(dof.shape)


@dataclass(frozen=True)
class ObjectSettings:
    """Objects in the filter: when one enters the state, how it is updated, when it retires.

    Attributes
    ----------
    init_observations
        Observations of an object (inside the window) needed to initialise it.
    min_depth
        Nearest accepted distance of a new object from the current pose.
    max_depth
        Farthest accepted distance of a new object from the current pose.
    init_max_relative_std
        An object enters the state only once its initial position is certain relative to its
        distance: the largest standard deviation of its initial covariance (eq. 30, the largest
        axis) at most this fraction of its distance from the current pose; a less certain
        object waits for more observations inside the window. Far objects seen by stereo from a
        few frames are strongly nonlinear in depth, and their linearised initial covariance is
        then overconfident. 0 initialises as soon as ``init_observations`` are in the window.
    init_linearity_probability
        An object enters the state — and fixes its first estimate, the point at which ``fej``
        takes its rows' unobservable directions for good — only once its rows are close enough
        to linear over what its data still allow: at the edge of its confidence region of this
        probability (its covariance given the window poses, the measurement part of eq. 30; the
        poses' own uncertainty moves it with them), the linearisation error of its stereo rows,
        whitened by their noise, moves the least-squares point of those rows by at most one of
        its own standard deviations (:func:`~teamslam.msckf.filter.models.linearisation_reach`).
        A far object seen by stereo from a few nearby frames fails, and waits for more
        observations inside the window (each one re-triangulated and tested again); one still
        waiting when its oldest observation leaves the window enters then if it is still
        observed (from the longest track the window gives), and otherwise updates the poses as
        a geometric feature. For the policies that fix first estimates (``fej``, ``oc``); 0.95
        is the probability it was measured with. 0: off (the default while the results pages
        measured without it stand).
    reanchor_probability
        For the policies that fix an object's first estimate (``fej``, ``oc``): an object
        observed this frame whose first estimate lies outside its confidence region of this
        probability — ``(p̂ − p̄)ᵀ Σ_pp⁻¹ (p̂ − p̄)`` above the χ²(3) quantile, ``Σ_pp`` its
        marginal covariance — is re-anchored: its rows still annihilate the rigid motions at
        ``p̄``, a point its own data now rule out, and the error of those directions, the same
        at every row, adds up along the route. It is marginalised out of the state (what it
        gave the poses stays) and enters again as a new object from its next observations, at
        a fresh first estimate: no observation is used twice, and every row keeps annihilating
        the rigid motions at one point per object. It discards what the object knew, which
        costs accuracy where objects are seen again and again. 0.99 (the default) is the
        probability it was measured with (0.95 and 0.999 gave the same within the runs'
        spread). 0: off. A robot that averages with neighbours re-anchors only with
        ``reanchor_with_consensus``.
    reanchor_with_consensus
        Whether a robot running with consensus (at least one neighbour) re-anchors too. Off by
        default: dropping an object drops what the team's averages gave it, which costs a team
        far more accuracy than a lone robot (the consistency results page). On long routes,
        with ``consensus.set=active``, it keeps a ``fej`` team inside its NEES bands (same page).
    loss
        Robust object updates for heavy-tailed detections: ``none`` (Gaussian), ``huber`` or
        ``cauchy``. An accepted object whose innovation has Mahalanobis distance ``d`` (in
        standard deviations of its predicted innovation) is updated with its measurement
        variance divided by the weight ``w(d)`` — Huber ``min(1, c/d)``, Cauchy
        ``1/(1 + (d/c)²)`` with ``c = loss_scale`` — one reweighting step of the M-estimator.
    loss_scale
        The scale ``c`` of the robust loss, in standard deviations of the predicted innovation.
    update_iterations
        Linearisations of the object rows per frame: 1 is the EKF update of the paper (objects
        and geometric features in one stacked update, every Jacobian at the prior); ``k > 1``
        updates with the features first, then with the objects by an iterated EKF (Gauss–Newton
        on the prior and the object measurements, :meth:`MsckfState.iterated_update`): the
        object rows are linearised again at the updated estimate up to ``k − 1`` times, until
        no predicted measurement moves by more than a hundredth of its noise std. Every row
        keeps the linearisation policy's pose Jacobians (first estimates for ``fej``).
    retire_after
        Frames an object may go unobserved before it leaves the filter's active state for the
        robot's persistent map, as a consider state (its mean and every covariance it has with
        the state kept and updated, never corrected; it re-enters with them, exactly, when
        observed again): this bounds the active state — the cost of an update is then
        quadratic in it and linear in the persistent map — over a long mission. 0 never
        retires an object. Policy, exactness and what it means for consensus:
        :mod:`teamslam.msckf.filter.persistent_map`.
    max_active
        The most objects the filter state may hold: beyond it the least recently observed
        objects not observed this frame retire into the persistent map as with
        ``retire_after`` (and re-enter when observed again), which bounds the cost per frame
        by size rather than by time. 0: no bound.
    active_windows
        A budget learned from the data instead of picked per scene: the state may hold ``k``
        times the most objects the robot observed within one window (``filter.window``
        frames) so far; beyond it objects retire as with ``max_active`` (with both set, the
        smaller bound holds). 0: off.
    max_consider
        The most retired objects kept as consider states (correlated with the state, so that
        they re-enter exactly): an update costs ``O(active × consider)`` more and the map holds
        their ``(3c)²`` joint covariance. Beyond it the earliest retired lose their
        correlations — their means and marginals stay — and re-enter as independent priors,
        which counts their place in the world twice. For long missions through new ground,
        whose persistent map grows without end. 0: no bound (every retired object is a
        consider state: consistent).
    """

    init_observations: int = field(default=3, metadata=_unit("observations"))
    min_depth: float = field(default=1.0, metadata=_unit("m"))
    max_depth: float = field(default=40.0, metadata=_unit("m"))
    init_max_relative_std: float = field(default=0.0, metadata=_unit("fraction of distance"))
    init_linearity_probability: float = field(default=0.0, metadata=_unit("probability"))
    reanchor_probability: float = field(default=0.99, metadata=_unit("probability"))
    reanchor_with_consensus: bool = field(default=False, metadata=_unit(""))
    loss: str = field(default="none", metadata=_unit(""))
    loss_scale: float = field(default=2.0, metadata=_unit("std"))
    update_iterations: int = field(default=1, metadata=_unit("linearisations"))
    retire_after: int = field(default=0, metadata=_unit("frames"))
    max_active: int = field(default=0, metadata=_unit("objects"))
    active_windows: int = field(default=0, metadata=_unit("windows"))
    max_consider: int = field(default=0, metadata=_unit("objects"))

    def __post_init__(self) -> None:
        if not _is_count(self.init_observations, 2):
            raise InputError("objects.init_observations must be an integer of at least 2")
        if not _positive(self.min_depth):
            raise InputError("objects.min_depth must be a positive number")
        if not (_is_number(self.max_depth) and self.max_depth > self.min_depth):
            raise InputError("objects.max_depth must exceed objects.min_depth")
        relative = self.init_max_relative_std
        if not (_is_number(relative) and np.isfinite(relative) and relative >= 0):
            raise InputError(
                "objects.init_max_relative_std must be a number ≥ 0 (a fraction of the "
                "distance; 0: no wait)"
            )
        for name in ("init_linearity_probability", "reanchor_probability"):
            value = getattr(self, name)
            if not (_is_number(value) and (value == 0 or _probability(value))):
                raise InputError(f"objects.{name} must lie in (0, 1), or be 0 (off)")
        _check_flags(self, "objects", ("reanchor_with_consensus",))
        if self.loss not in ("none", "huber", "cauchy"):
            raise InputError(f"objects.loss must be none, huber or cauchy, not {self.loss!r}")
        if not _positive(self.loss_scale):
            raise InputError("objects.loss_scale must be a positive number (standard deviations)")
        if not _is_count(self.update_iterations, 1):
            raise InputError(
                "objects.update_iterations must be an integer of at least 1 (1: the EKF update)"
            )
        if not _is_count(self.retire_after, 0):
            raise InputError(
                "objects.retire_after must be an integer number of frames ≥ 0 (0: never retire)"
            )
        if not _is_count(self.max_active, 0):
            raise InputError(
                "objects.max_active must be an integer number of objects ≥ 0 (0: no bound)"
            )
        if not _is_count(self.max_consider, 0):
            raise InputError(
                "objects.max_consider must be an integer number of objects ≥ 0 (0: no bound)"
            )
        if not _is_count(self.active_windows, 0):
            raise InputError(
                "objects.active_windows must be an integer number of windows ≥ 0 (0: off)"
            )

    def robust_weight(self, mahalanobis: np.ndarray) -> np.ndarray:
        """The object update's weight ``w(d)`` for Mahalanobis distances ``d`` (1: Gaussian)."""
        d = np.asarray(mahalanobis, dtype=float)
        c = self.loss_scale
        if self.loss == "huber":
            return np.minimum(1.0, c / np.maximum(d, 1e-300))
        if self.loss == "cauchy":
            return 1.0 / (1.0 + (d / c) ** 2)
        return np.ones_like(d)


@dataclass(frozen=True)
class TrackingSettings:
    """Object tracking, for a robot whose detections carry no ids
    (:mod:`teamslam.msckf.objects.tracking`).

    Attributes
    ----------
    gate_probability
        A detection may be assigned to a predicted object or track only when its squared
        Mahalanobis distance under the filter's innovation covariance is at most this quantile
        of χ²(4).
    birth_probability
        The outer gate, a wider quantile of χ²(4) than ``gate_probability``: an object of the
        state seen within the last ``N`` frames (``confirm_frames``), or a track, that took no
        detection this frame takes one left outside every gate but inside its outer gate when
        the pair is alone there (a detector's heavy-tailed error keeps its object); such a
        detection, when not alone, starts no track (one object, one id). A detection near an
        object that took another one starts a track (a detector boxes an object once per
        frame); objects unseen for longer block nothing. Equal to ``gate_probability``: no outer
        gate.
    confirm_hits
        A tentative track is confirmed after ``M = confirm_hits`` detections within its first
        ``N = confirm_frames`` frames, and dropped otherwise. 0 takes the default
        ``M = objects.init_observations``.
    confirm_frames
        ``N`` of ``confirm_hits``; a confirmed track not yet in the state is also dropped after
        ``N`` frames without a detection. 0 takes the default ``N = M + 2``.
    loop_closure
        Loop closure in each tracking robot's own map
        (:mod:`teamslam.msckf.objects.loop_closure`): the objects it created last are matched
        by the shape of the group against its objects unseen for longer than the window (the
        own association's rules), and each accepted pair is merged in the filter (an EKF update
        with ``x_new − x_old = 0``, then the new object leaves the state).
    appearance
        Use the detections' appearance descriptors where the data has them
        (:mod:`teamslam.msckf.objects.appearance`): once appearance separates objects beyond
        chance (at ``gate_probability``), the assignment cost adds ``−2 log`` of the likelihood
        ratio learned in the run, a pair whose ratio falls below
        ``(1 − gate_probability) / gate_probability`` is refused (a long-unseen object's
        too). Box sizes are used alike: each box's shape (width to height) against that of a
        target seen within the last ``N`` (``confirm_frames``) frames, its ratio learned on its
        own. Without descriptors and box sizes nothing changes.
    revisit_probability
        Re-identification of a long-unseen object by the boxes of a new one
        (:meth:`~teamslam.msckf.objects.tracking.ObjectTracker.reidentify`): a new object of the
        tracker is merged into an object last seen before its first box when the posterior
        probability that it is that object (its position difference inside the
        ``gate_probability`` gate of χ²(3) and its likelihood ratio, appearance and class of all
        its boxes, against a new object and every other candidate) reaches this. Boxes with
        sizes and appearance only (otherwise nothing changes).
    """

    gate_probability: float = field(default=0.99, metadata=_unit(""))
    birth_probability: float = field(default=0.999999, metadata=_unit(""))
    confirm_hits: int = field(default=0, metadata=_unit("detections"))
    confirm_frames: int = field(default=0, metadata=_unit("frames"))
    loop_closure: bool = field(default=False, metadata=_unit(""))
    appearance: bool = field(default=True, metadata=_unit(""))
    revisit_probability: float = field(default=0.99, metadata=_unit(""))

    def __post_init__(self) -> None:
        _check_flags(self, "tracking", ("loop_closure", "appearance"))
        for name in ("gate_probability", "birth_probability", "revisit_probability"):
            if not _probability(getattr(self, name)):
                raise InputError(f"tracking.{name} must lie in (0, 1)")
        for name in ("confirm_hits", "confirm_frames"):
            if not _is_count(getattr(self, name), 0):
                raise InputError(f"tracking.{name} must be an integer ≥ 0 (0: the default)")


@dataclass(frozen=True)
class ConsensusSettings:
    """Consensus on the common objects with the neighbours (:mod:`teamslam.msckf.consensus`).

    Attributes
    ----------
    rule
        How the neighbours' marginals are averaged (:mod:`teamslam.msckf.consensus.rules`):
        ``average`` — the paper's Metropolis-weighted geometric average (eq. 19, Prop. 2),
        conservative by about the number of robots averaging; ``hybrid`` — the new
        information each robot gathered since its last exchange enters the neighbours' averages
        at full weight (after HCMCI, Battistelli et al. 2015), with gains that never count one
        robot's new information twice; ``increments`` — hybrid consensus in which the robot's
        own new information enters its average exactly once on every object (each neighbour's
        marginal is completed against our prior rather than our current marginal), so partial
        maps and partial exchanges no longer dilute it. ``hybrid`` and ``increments`` need joint
        marginals and lock-step exchanges (asynchronous robots average). ``ci`` and ``ici`` —
        each neighbour's marginal is fused with the robot's by covariance intersection or
        inverse covariance intersection, the weight minimising the fused covariance's
        determinant (:mod:`teamslam.msckf.consensus.intersection`): consistent whatever the
        robots share (``ci``) or when what they share is common information (``ici``), without
        the fixed weights' dilution; joint marginals and lock-step exchanges. Options: their
        NEES is closer to 1 on the teams measured, their position error larger (concept page
        *Consensus*, section *Intersection*).
    kl_threshold
        Consensus averages a common object with a neighbour only when its marginal has moved,
        on either robot, since the two last exchanged it, by more than this Kullback–Leibler
        divergence (unit-free, so the same for any camera or scale). 0 averages every common
        object at every step, as the paper does.
    set
        Which common objects consensus averages jointly: ``all`` (the paper: every common
        object that moved) or ``active`` (a bounded set: the objects the window can still
        change — observed within the window, or with mutual information above
        ``active_information`` with the window poses — and the others only when they moved by
        more than ``inactive_kl_threshold``); lock-step exchanges only;
        :mod:`teamslam.msckf.consensus.selection`.
    active_information
        With ``set = active``: an object not observed within the window is active while its
        mutual information with the window poses exceeds this (``inf``: only the objects
        observed within the window are active).
    inactive_kl_threshold
        With ``set = active``: an inactive object is averaged with a neighbour when its marginal
        moved by more than this Kullback–Leibler divergence since the pair last exchanged it
        (active objects, and objects the pair averaged in the previous exchange, use
        ``kl_threshold``).
    per_object
        Send each common object's own 3×3 marginal instead of the joint marginal of all of
        them (the cross-object covariances are dropped from the message, not from the filter):
        the message grows linearly instead of quadratically with the objects shared.
    float32
        Send means and covariances in single precision where rounding is harmless: a message
        goes in float32 only when the rounded marginal is within
        :data:`~teamslam.msckf.consensus.FLOAT32_MAX_KL` of the exact one, else in float64.
    iterations
        Consensus exchanges per step ``L``: both rounds and the average are run ``L`` times
        before each frame, every exchange with its own messages and link losses. With the
        ``hybrid`` and ``increments`` rules each robot's new information is sent at its gain in
        the first exchange only, so no increment is counted twice for any ``L``. Lock-step only;
        every robot of a team must use the same ``L``.
    persistent_map
        Objects retired to the persistent map (``objects.retire_after``,
        ``objects.max_active``) listen to consensus: a robot asks for them with its map ids and
        averages each with the neighbours' marginals of it (eq. 19 per object, the rest of the
        joint a consider state of that average), flagged at ``kl_threshold`` as the objects of
        its state;
        it never sends them (a stale copy would pull the neighbours' working estimates back).
        With the plain average, lock-step exchanges, ``kl_threshold > 0``, ``set = all`` and
        oracle ids. Off by default: it does not lower a budget's object error over a long
        mission (``docs/results/speed.md``); off, retired objects wait for re-entry.
    innovation_check
        With oracle association: the ``χ²₃`` test of each common object's consensus innovation
        (at ``association.revoke_probability``); a neighbour's marginal in which most objects
        fail (a member that sends marginals far off with a tiny covariance) is left out of the
        step's average whole. On by default: a check that protects the estimate must not need
        switching on. Own association always tests.
    rigid_directions
        With a linearisation that keeps first estimates (``fej``, ``oc``): the consensus average
        leaves the robot's information along the rigid motions of the world, taken at its
        first estimates of the averaged objects, as it was, and averages the robots' marginals
        of the map's shape (:mod:`teamslam.msckf.consensus.directions`; the hybrid and
        increments rules and ``per_object`` take their finished average's marginal of it).
        On by default. It also throws away what the team knows of a robot's drift relative to
        its neighbours (a rigid motion of its map that the common objects show): off, ``fej``
        with consensus is more accurate on every team measured (KITTI 00: 5.9 m against
        10.2 m), but robots that first estimated a common object apart hand each other
        information along their unobservable directions, and the team becomes overconfident
        along a long route whichever objects it averages (``docs/concepts/linearization.md``).
        No effect with ``std`` or ``ideal``.
    at_first_estimates
        With a linearisation that keeps first estimates (``fej``, ``oc``) and joint marginals:
        a robot sends its marginal with its rigid-motion directions moved from its first
        estimates to its means, and the receiver moves them to its own first estimates before
        it averages (:func:`~teamslam.msckf.consensus.directions.reexpressed_information`), so
        that a neighbour's marginal says along the receiver's rigid motions what it said along
        its own — what it knows of where the map sits, not of its shape read through the
        disagreement of first estimates. No effect with ``std`` or ``ideal``.
    """

    rule: str = field(default="average", metadata=_unit(""))
    kl_threshold: float = field(default=1e-3, metadata=_unit("nats"))
    set: str = field(default="all", metadata=_unit(""))
    active_information: float = field(default=float("inf"), metadata=_unit("nats"))
    inactive_kl_threshold: float = field(default=0.3, metadata=_unit("nats"))
    per_object: bool = field(default=False, metadata=_unit(""))
    float32: bool = field(default=True, metadata=_unit(""))
    iterations: int = field(default=1, metadata=_unit("exchanges per step"))
    persistent_map: bool = field(default=False, metadata=_unit(""))
    innovation_check: bool = field(default=True, metadata=_unit(""))
    rigid_directions: bool = field(default=True, metadata=_unit(""))
    at_first_estimates: bool = field(default=False, metadata=_unit(""))

    def __post_init__(self) -> None:
        if self.rule not in CONSENSUS_RULES:
            raise InputError(
                f"consensus.rule must be one of {', '.join(CONSENSUS_RULES)}, not {self.rule!r}"
            )
        threshold = self.kl_threshold
        if not (_is_number(threshold) and np.isfinite(threshold) and threshold >= 0):
            raise InputError("consensus.kl_threshold must be a number ≥ 0 (nats)")
        if self.set not in ("all", "active"):
            raise InputError(f"consensus.set must be all or active, not {self.set!r}")
        for name in ("active_information", "inactive_kl_threshold"):
            value = getattr(self, name)
            if not (_is_number(value) and value >= 0):  # inf: never by this test
                raise InputError(f"consensus.{name} must be a number ≥ 0 (nats; inf allowed)")
        _check_flags(
            self,
            "consensus",
            (
                "per_object",
                "float32",
                "persistent_map",
                "innovation_check",
                "rigid_directions",
                "at_first_estimates",
            ),
        )
        if self.rule != "average" and self.per_object:
            raise InputError(
                f"consensus.rule {self.rule} needs joint marginals: it cannot be used with "
                "consensus.per_object"
            )
        if not _is_count(self.iterations, 1):
            raise InputError("consensus.iterations must be an integer of at least 1 (exchanges)")


def _attributes(doc: str | None) -> str:
    """The entries of a numpy docstring's ``Attributes`` section, as written."""
    match = re.search(r"Attributes\n\s*-+\n(.*)", doc or "", flags=re.S)
    return match.group(1).rstrip() if match else ""


@dataclass(frozen=True)
class TeamAssociationSettings(AssociationSettings):
    """Which objects of two neighbours are the same: the mode and, with ``own``, when the links
    associate and the matcher's thresholds (:class:`~teamslam.association.AssociationSettings`).

    Attributes
    ----------
    mode
        ``oracle`` (equal ids — the dataset's ids are team-wide) or ``own`` (each robot names
        its own objects; each link finds its correspondences from exchanged object summaries,
        :mod:`teamslam.association`, and consensus averages the matched pairs).
    interval
        With ``own``: steps between two exchanges of object summaries on a link (each exchange
        runs a full association when the link's table is due, else grows it): the longest a
        link goes without a whole summary.
    sooner
        With ``own``, lock-step: a robot that holds at least this many objects its last
        summaries to a neighbour did not carry sends it, before the interval, a summary of
        those objects alone; the link then associates at once (both ends on the two maps as
        they hold them: the last whole summaries with the partial ones since). 0: summaries
        only every ``interval`` steps.
    revoke_probability
        With ``own`` (and with ``consensus.innovation_check``): probability of the ``χ²₃`` test
        of each matched pair's consensus innovation; a pair that fails is left out of the
        average and revoked for good. Close to 1, the test tolerates a somewhat overconfident
        filter and still catches a neighbour far off with a tiny covariance. With ``own`` the
        test's ``χ²₃`` quantile is multiplied by the link's learned frame scale (how far the two
        maps' estimates of one object lie apart against their covariances, learned from pairs
        a transform identified): the hypothesis its association gate admitted the pair under.
    """

    mode: str = field(default="oracle", metadata=_unit(""))
    interval: int = field(default=5, metadata=_unit("steps"))
    sooner: int = field(default=1, metadata=_unit("objects"))
    revoke_probability: float = field(default=0.99999, metadata=_unit(""))
    # a team's maps are estimates in the one world frame every robot starts in (at its known
    # first pose): the matcher tests a pair under the identity as consensus does
    frame_probability: float | None = field(default=0.99999, metadata=_unit(""))

    def __post_init__(self) -> None:
        try:
            super().__post_init__()
        except InputError as exc:  # name the key as it is set
            raise InputError(str(exc).replace("association setting ", "association.", 1)) from None
        if self.mode not in ("oracle", "own"):
            raise InputError(f"association.mode must be oracle or own, not {self.mode!r}")
        if not _is_count(self.interval, 1):
            raise InputError("association.interval must be an integer number of steps ≥ 1")
        if not _is_count(self.sooner, 0):
            raise InputError("association.sooner must be an integer number of objects ≥ 0")
        if not _probability(self.revoke_probability):
            raise InputError("association.revoke_probability must lie in (0, 1)")

    def matching(self) -> AssociationSettings:
        """The matcher's thresholds alone (what :func:`~teamslam.association.associate`
        takes)."""
        return AssociationSettings(
            **{f.name: getattr(self, f.name) for f in fields(AssociationSettings)}
        )


# the matcher's fields are documented where they are defined: their entries follow ours
TeamAssociationSettings.__doc__ = (
    f"{TeamAssociationSettings.__doc__.rstrip()}\n{_attributes(AssociationSettings.__doc__)}\n    "
)


def _fields(kind: type) -> tuple:
    """A group's fields, its own before those it inherits (the association mode before the
    matcher's thresholds)."""
    own = inspect.get_annotations(kind)
    every = fields(kind)
    return tuple(f for f in every if f.name in own) + tuple(f for f in every if f.name not in own)


#: The groups of :class:`MsckfConfig`, in order: name → class.
GROUPS: dict[str, type] = {
    "filter": FilterSettings,
    "objects": ObjectSettings,
    "tracking": TrackingSettings,
    "consensus": ConsensusSettings,
    "association": TeamAssociationSettings,
}


@dataclass(frozen=True)
class MsckfConfig:
    """Every setting of one robot's filter, in groups; a setting is named ``group.name``.

    Attributes
    ----------
    filter
        The MSCKF: window, noise levels, gate, linearisation (:class:`FilterSettings`).
    objects
        Objects in the filter: initialisation, robust update, retirement
        (:class:`ObjectSettings`).
    tracking
        Object tracking for detections without ids (:class:`TrackingSettings`).
    consensus
        Consensus with the neighbours: the rule and what is exchanged
        (:class:`ConsensusSettings`).
    association
        Which objects of two neighbours are the same (:class:`TeamAssociationSettings`).
    """

    filter: FilterSettings = field(default_factory=FilterSettings)
    objects: ObjectSettings = field(default_factory=ObjectSettings)
    tracking: TrackingSettings = field(default_factory=TrackingSettings)
    consensus: ConsensusSettings = field(default_factory=ConsensusSettings)
    association: TeamAssociationSettings = field(default_factory=TeamAssociationSettings)

    def __post_init__(self) -> None:
        for name, kind in GROUPS.items():
            if not isinstance(getattr(self, name), kind):
                raise InputError(f"{name} must be a {kind.__name__}")
        hits = self.tracking.confirm_hits or self.objects.init_observations
        frames = self.tracking.confirm_frames or hits + 2
        if frames < hits:
            raise InputError(
                f"tracking.confirm_frames ({frames}) must be at least tracking.confirm_hits "
                f"({hits})"
            )

    # ------------------------------------------------------------------ names
    @classmethod
    def keys(cls) -> tuple[str, ...]:
        """Every setting's name, ``group.name``."""
        return tuple(f"{g}.{f.name}" for g, kind in GROUPS.items() for f in _fields(kind))

    @classmethod
    def field_of(cls, key: str):
        """The dataclass field of setting ``key`` (``None``: no such setting)."""
        group, _, name = key.partition(".")
        kind = GROUPS.get(group)
        if kind is None:
            return None
        return next((f for f in _fields(kind) if f.name == name), None)

    @classmethod
    def unit(cls, key: str) -> str:
        """The unit of setting ``key`` (empty: unit-free)."""
        found = cls.field_of(key)
        return "" if found is None else found.metadata.get("unit", "")

    # ------------------------------------------------------------------ values
    def settings(self) -> dict[str, Any]:
        """Every setting as ``{"group.name": value}``, in order."""
        return {
            f"{g}.{f.name}": getattr(getattr(self, g), f.name)
            for g, kind in GROUPS.items()
            for f in _fields(kind)
        }

    @classmethod
    def from_settings(cls, values: Mapping[str, Any]) -> MsckfConfig:
        """The defaults with ``{"group.name": value}`` on top (names checked by the caller:
        :func:`~teamslam.msckf.settings.sources.coerce_settings`)."""
        return cls().with_(values)

    def with_(self, changes: Mapping[str, Any] | None = None, /, **groups: Any) -> MsckfConfig:
        """A copy with some settings changed: ``{"group.name": value}`` and/or, per group, a
        mapping of its fields or a whole group (``filter={"window": 8}``).

        Raises
        ------
        InputError
            A name that is no setting, or a value the setting cannot take.
        """
        grouped: dict[str, dict[str, Any]] = {}
        for key, value in (changes or {}).items():
            group, _, name = key.partition(".")
            if self.field_of(key) is None:
                raise InputError(f"unknown setting {key!r}")
            grouped.setdefault(group, {})[name] = value
        new = {}
        for group, value in groups.items():
            if group not in GROUPS:
                raise InputError(f"unknown group of settings {group!r}")
            if is_dataclass(value):
                new[group] = value
            else:
                grouped.setdefault(group, {}).update(value)
        for group, names in grouped.items():
            base = new.get(group, getattr(self, group))
            try:
                new[group] = replace(base, **names)
            except TypeError as exc:
                raise InputError(f"{group}: {exc}") from None
        return replace(self, **new) if new else self

    def to_json(self) -> dict:
        """Every setting as plain JSON, one mapping per group."""
        return {
            g: {
                f.name: list(v) if isinstance(v := getattr(getattr(self, g), f.name), tuple) else v
                for f in _fields(kind)
            }
            for g, kind in GROUPS.items()
        }
