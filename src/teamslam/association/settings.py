"""Settings of the association (:class:`AssociationSettings`): probabilities, ratios, counts.

Every setting is unit-free; a value out of its range is refused at construction with a one-line
:class:`~teamslam.errors.InputError` naming it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from teamslam.errors import InputError
from teamslam.gaussian import chi2_quantile

__all__ = ["AssociationSettings"]


@dataclass(frozen=True)
class AssociationSettings:
    """Settings of :func:`~teamslam.association.associate` (all unit-free).

    Attributes
    ----------
    consistency_probability
        Probability of the ``χ²₁`` test of pairwise distance consistency (and of the descriptor
        comparison).
    gate_probability
        Probability of the ``χ²₃`` Mahalanobis gate of a pair under the relative transform.
    drift_ratio
        Standard deviation of a map's deformation per unit of distance: two objects ``d`` apart
        in one map may be ``d ± ρ·d`` apart in the other beyond what their covariances say.
    neighbours
        Nearest neighbours ``k`` of each object compared for candidates.
    descriptor_matches
        Neighbours two objects must have in common (as a consistent set) to be a candidate
        pair.
    candidates_per_object
        Each object keeps at most this many candidates (its best by descriptor agreement).
    min_inliers
        Fewest pairs that give an answer (at least 3, which fix a transform).
    ambiguity_ratio
        A rival consistent set gathering at least this fraction of the answer's pair count in
        pairs that contradict the answer makes it ambiguous (no correspondence).
    clique_budget
        Search nodes of the exact maximum-clique search (beyond it, the best clique found).
    rivals
        Consistent sets examined after the first (each among the candidates the earlier ones'
        transforms reject); the one gathering the most pairs is the answer, the others its
        rivals.
    distinctness
        A matched pair is kept only when no other object fits within this many units of
        squared Mahalanobis distance (a likelihood ratio of ``exp(distinctness / 2)``).
    separation
        A matched pair is kept only when its gate is narrow against the spacing of the objects
        around it: the longest semi-axis of its ``χ²₃`` gate ellipsoid times ``separation``
        must not exceed the distance from either object to its nearest neighbour in its own
        map. A pair whose gate could hold a neighbour of the true partner — a car of the same
        row, when the true partner is not (yet) in the other map, so no rival is there to be
        seen — is a guess. 0 turns the test off.
    frame_probability
        ``None`` (default): the two maps may be in unrelated frames, any rigid transform between
        them is as likely as any other. A probability: both maps are estimates in one world
        frame (the robots started at known poses), so a pair whose two estimates fail the
        ``χ²₃`` test of their difference under the identity, with their own marginal
        covariances (the test consensus revokes a pair by), is no candidate and is never
        gathered. Of two consistent sets related by a shift the layout repeats (a row of
        objects one spacing further), only the one the maps' own frames allow remains. A
        team's own association (``association.frame_probability``) sets it by default, at
        the probability of its revocation test: its robots start at known poses in one frame.
    frame_scale
        The factor (at least 1) by which the two maps' differences are known to exceed their
        marginal covariances: the test of ``frame_probability`` compares the squared
        Mahalanobis distance with ``frame_scale`` times the ``χ²₃`` quantile. 1 (default): the
        covariances are taken as right. A link's table learns it from the pairs its held
        pairs' transform identifies (:meth:`~teamslam.association.CorrespondenceTable.extend`):
        not a setting to give by hand.
    """

    consistency_probability: float = 0.99
    gate_probability: float = 0.99
    drift_ratio: float = 0.05
    neighbours: int = 6
    descriptor_matches: int = 2
    candidates_per_object: int = 3
    min_inliers: int = 6
    ambiguity_ratio: float = 0.5
    clique_budget: int = 2_000
    distinctness: float = 2.0
    rivals: int = 3
    separation: float = 0.5
    frame_probability: float | None = None
    frame_scale: float = 1.0

    def __post_init__(self) -> None:
        for name in ("consistency_probability", "gate_probability"):
            value = getattr(self, name)
            if not 0.0 < value < 1.0:
                raise InputError(f"association setting {name} must be in (0, 1), got {value}")
        if not (np.isfinite(self.drift_ratio) and self.drift_ratio >= 0.0):
            raise InputError(f"association setting drift_ratio must be ≥ 0, got {self.drift_ratio}")
        if not 0.0 < self.ambiguity_ratio <= 1.0:
            raise InputError(
                f"association setting ambiguity_ratio must be in (0, 1], got {self.ambiguity_ratio}"
            )
        for name, low in (
            ("neighbours", 1),
            ("descriptor_matches", 0),
            ("candidates_per_object", 1),
            ("min_inliers", 3),
            ("clique_budget", 1),
            ("rivals", 1),
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
                raise InputError(f"association setting {name} must be an integer ≥ {low}")
        if not (np.isfinite(self.distinctness) and self.distinctness >= 0.0):
            raise InputError(
                f"association setting distinctness must be ≥ 0, got {self.distinctness}"
            )
        if not (np.isfinite(self.separation) and self.separation >= 0.0):
            raise InputError(f"association setting separation must be ≥ 0, got {self.separation}")
        if self.frame_probability is not None and not 0.0 < self.frame_probability < 1.0:
            raise InputError(
                "association setting frame_probability must be in (0, 1) or None, got "
                f"{self.frame_probability}"
            )
        if not (np.isfinite(self.frame_scale) and self.frame_scale >= 1.0):
            raise InputError(f"association setting frame_scale must be ≥ 1, got {self.frame_scale}")
        if self.descriptor_matches > self.neighbours:
            raise InputError("association setting descriptor_matches exceeds neighbours")

    @property
    def consistency_threshold(self) -> float:
        """``χ²₁`` quantile of :attr:`consistency_probability`."""
        return chi2_quantile(self.consistency_probability, 1)

    @property
    def gate_threshold(self) -> float:
        """``χ²₃`` quantile of :attr:`gate_probability`."""
        return chi2_quantile(self.gate_probability, 3)

    @property
    def frame_threshold(self) -> float | None:
        """``χ²₃`` quantile of :attr:`frame_probability` times :attr:`frame_scale` (``None``
        without it)."""
        if self.frame_probability is None:
            return None
        chi2 = chi2_quantile(self.frame_probability, 3)
        return chi2 if self.frame_scale == 1.0 else chi2 * self.frame_scale
