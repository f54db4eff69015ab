"""Which objects two robots share, when each robot names its own objects.

Neighbours exchange :class:`ObjectSummary` s (id, mean, marginal covariance, optional class and
appearance descriptor of each object); :func:`associate` finds the correspondences between two
summaries with no shared id — drift-invariant candidates, pairwise consistency of distances, the
maximum consistent set (PCM, Mangelson et al. ICRA 2018), the relative transform it implies and
a Mahalanobis gate under it — and gives none rather than guess; appearance, when its learned
model separates objects (:mod:`~teamslam.association.appearance`), adds candidates and vetoes
and lets three pairs beyond chance answer (before any sample of the same object, by the rarity
of their resemblance among different objects) — and, between maps in one world frame, single
pairs whose resemblance is beyond chance among all the frame allows. A
:class:`CorrespondenceTable` per link keeps the
pairs across steps, grows them, revokes a pair whose consensus innovation fails its ``χ²`` test
(:func:`pair_innovation_consistent`). :func:`score_correspondences` measures precision and recall
against ground truth.
"""

from teamslam.association.answer import AssociationResult, associate
from teamslam.association.clique import maximum_clique
from teamslam.association.consistency import consistency_graph
from teamslam.association.evaluate import CorrespondenceScore, score_correspondences
from teamslam.association.gate import gate_pairs
from teamslam.association.mirror import flipped
from teamslam.association.settings import AssociationSettings
from teamslam.association.summary import ObjectSummary
from teamslam.association.table import (
    CorrespondenceTable,
    pair_innovation_consistent,
    pair_innovation_nis,
)
from teamslam.association.transform import fit_transform

__all__ = [
    "AssociationResult",
    "AssociationSettings",
    "CorrespondenceScore",
    "CorrespondenceTable",
    "ObjectSummary",
    "associate",
    "consistency_graph",
    "fit_transform",
    "flipped",
    "gate_pairs",
    "maximum_clique",
    "pair_innovation_consistent",
    "pair_innovation_nis",
    "score_correspondences",
]
