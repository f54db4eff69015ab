"""Where the EKF evaluates its Jacobians: the one pluggable piece that separates the filters.

FEJ multi-robot EKF paper, §3: the standard, first-estimate and ideal filters differ only in
the points at which ``Φ`` (eq. 5) and ``H`` (eqs. 10–11) are evaluated, which a :class:`Policy`
picks from the :class:`LinearizationPoints` of a step. With first estimates or the truth the
observability matrix keeps rank ``dim − 3``; the standard choice reaches ``dim − 2``. Table of
the choices and derivation: the concept page *Linearisation* (``docs/concepts/linearization.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.errors import InputError

__all__ = [
    "POLICIES",
    "FirstEstimate",
    "Ideal",
    "LinearizationPoints",
    "Policy",
    "Standard",
    "policy",
]


@dataclass
class LinearizationPoints:
    """What the filter knows at a step, from which a policy picks its linearisation points.

    Attributes
    ----------
    posterior_poses
        ``x̂_{k|k}`` of every robot, ``(N, 3)`` (before propagating to ``k + 1``).
    prior_poses
        ``x̂_{k|k-1}``: the propagated (pre-update) poses of step ``k``.
    propagated_poses
        ``x̂_{k+1|k}`` after propagation.
    true_poses_from, true_poses_to
        Ground-truth poses at ``k`` and ``k + 1`` (``None`` without ground truth).
    """

    posterior_poses: np.ndarray
    prior_poses: np.ndarray
    propagated_poses: np.ndarray
    true_poses_from: np.ndarray | None = None
    true_poses_to: np.ndarray | None = None


class Policy:
    """Base class of a linearisation policy."""

    name: str = "base"
    needs_truth: bool = False

    def propagation_positions(self, points: LinearizationPoints) -> tuple[np.ndarray, np.ndarray]:
        """Positions ``(from, to)`` ``(N, 2)`` for the heading column of ``Φ``."""
        raise NotImplementedError

    def propagation_heading(self, points: LinearizationPoints) -> np.ndarray:
        """Headings ``(N,)`` that rotate the odometry noise in ``G``."""
        return points.posterior_poses[:, 2]

    def update_poses(self, propagated: np.ndarray, truth: np.ndarray | None) -> np.ndarray:
        """Robot poses ``(N, 3)`` at which ``H`` is evaluated."""
        return propagated

    def update_features(
        self, current: np.ndarray, first: np.ndarray, truth: np.ndarray | None
    ) -> np.ndarray:
        """Positions ``(m, 2)`` at which ``H`` is evaluated for the ``m`` observed features.

        ``current``, ``first`` and ``truth`` (``None`` without ground truth) are those features'
        current estimates, first estimates and true positions, row for row.
        """
        raise NotImplementedError


class Standard(Policy):
    """Std-EKF: every Jacobian at the current estimate."""

    name = "std"

    def propagation_positions(self, points):
        return points.posterior_poses[:, :2], points.propagated_poses[:, :2]

    def update_features(self, current, first, truth):
        return current


class FirstEstimate(Policy):
    """FEJ-EKF: propagated robot positions and each feature's first estimate (eqs. 23–24)."""

    name = "fej"

    def propagation_positions(self, points):
        return points.prior_poses[:, :2], points.propagated_poses[:, :2]

    def update_features(self, current, first, truth):
        return first


class Ideal(Policy):
    """Ideal-EKF: every Jacobian at the ground truth (simulation only)."""

    name = "ideal"
    needs_truth = True

    def propagation_positions(self, points):
        return points.true_poses_from[:, :2], points.true_poses_to[:, :2]

    def propagation_heading(self, points):
        return points.true_poses_from[:, 2]

    def update_poses(self, propagated, truth):
        return truth

    def update_features(self, current, first, truth):
        return truth


POLICIES: dict[str, type[Policy]] = {"std": Standard, "fej": FirstEstimate, "ideal": Ideal}


def policy(name: str) -> Policy:
    """Policy by name: ``std``, ``fej`` or ``ideal``."""
    try:
        return POLICIES[name]()
    except KeyError:
        raise InputError(f"unknown linearisation {name!r}; choose std, fej or ideal") from None
