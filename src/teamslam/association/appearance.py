"""How alike two objects look, as a likelihood ratio learned from the data itself.

Descriptors (any dimension, any scale) are compared by their cosine distance
``d = 1 − cos θ ∈ [0, 2]``. :class:`AppearanceModel` keeps two histograms of ``d`` (binned by
the chord ``√(2d)``, finer where descriptors agree): *same object* and *different objects*. With
a uniform Dirichlet prior on both, ``log_ratio(d) = log p_same(d) − log p_different(d)`` is
exactly 0 before any sample and tends to 0 wherever the two agree (appearance that says
nothing). :attr:`~AppearanceModel.informative` says whether the samples separate the two beyond
chance (a one-sided rank test at ``1 − probability``).

Between two robots' maps (:func:`link_model`): *different* are the pairs of objects within
either map (a map holds each object once), *same* the pairs the link already holds and the
samples each summary carries (:attr:`~teamslam.association.ObjectSummary.same_counts`); both ends
of a link build the same model. :func:`chance_tail` is the probability that ``k`` chance
look-alikes — each object paired with the best-looking of ``m`` unrelated objects — reach a summed
log ratio: the bound an answer from fewer than ``min_inliers`` pairs must beat. Before a link
knows what the same object looks like (no *same* sample yet: its first answer), :func:`rarity`
scores a resemblance by how rarely different objects resemble each other as closely —
``−log P(d' ≤ d | different)``, the *different* histogram alone — and :func:`chance_tail` bounds
a set of such pairs alike. The derivation: the association concept page, *Appearance*.
"""

from __future__ import annotations

import functools
import weakref

import numpy as np
from scipy.stats import norm

from teamslam.errors import InputError

__all__ = [
    "BINS",
    "AppearanceModel",
    "beyond_chance",
    "chance_tail",
    "cosine_distances",
    "link_model",
    "rare_triples",
    "rarity",
    "unit_rows",
]

#: Histogram bins over the chord length ``√(2d) ∈ [0, 2]``.
BINS = 40

#: Weight in samples of the uniform prior of a link's histograms (:func:`link_model`): one
#: sample's, so that a few dozen *same* samples let a distance they never show veto a pair.
LINK_PRIOR_WEIGHT = 1.0

#: Grid steps over the range of the log ratio in :func:`chance_tail` (the null's values are
#: rounded up onto it: the tail is over-estimated, never under).
TAIL_GRID = 2048


def unit_rows(a: np.ndarray) -> np.ndarray:
    """Rows scaled to unit norm (a zero row stays zero)."""
    a = np.asarray(a, dtype=np.float64)
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    return np.divide(a, n, out=np.zeros_like(a), where=n > 0)


def cosine_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(A, B)`` cosine distances ``1 − cos θ`` between the rows of ``a`` and of ``b``; NaN
    where either row is zero (a descriptor without content compares with nothing)."""
    ua, ub = unit_rows(a), unit_rows(b)
    d = np.clip(1.0 - ua @ ub.T, 0.0, 2.0)
    d[~ua.any(axis=1)[:, None] | ~ub.any(axis=1)[None, :]] = np.nan
    return d


def distance_bins(d: np.ndarray) -> np.ndarray:
    """The histogram bin of each cosine distance (by its chord ``√(2d)``)."""
    chord = np.sqrt(2.0 * np.asarray(d, dtype=np.float64))
    return np.minimum((chord * (BINS / 2.0)).astype(np.int64), BINS - 1)


def distance_counts(d: np.ndarray) -> np.ndarray:
    """``(BINS,)`` int64 histogram of cosine distances (NaN ones left out)."""
    d = np.ravel(d)
    return np.bincount(distance_bins(d[np.isfinite(d)]), minlength=BINS).astype(np.int64)


class AppearanceModel:
    """The learned likelihood ratio of *same object* against *different objects*.

    Parameters
    ----------
    probability
        The confidence of :attr:`informative`'s test.
    prior_weight
        The weight, in samples, of each histogram's uniform Dirichlet prior (``BINS``: one
        pseudo-sample per bin). The prior bounds the evidence a distance can give against
        *same*: a bin without a *same* sample keeps ``p_same ≥ (prior_weight / BINS) /
        (n_same + prior_weight)``. With one pseudo-sample per bin and a few dozen *same*
        samples, a descriptor distance common among *different* objects and never seen among
        *same* ones gets a likelihood ratio of about 1 : 10 — short of the 1 : 99 of a veto at
        0.99 until some 700 *same* samples are in. A link's model (:func:`link_model`) gives
        the prior the weight of one sample.
    """

    def __init__(self, probability: float, prior_weight: float = BINS) -> None:
        if not prior_weight > 0:
            raise InputError(f"appearance model: prior_weight must be > 0, got {prior_weight}")
        self.probability = float(probability)
        self.prior_weight = float(prior_weight)
        self.same = np.zeros(BINS)
        self.different = np.zeros(BINS)
        self._table = np.zeros(BINS)
        self._informative = False

    @staticmethod
    def _bins(d: np.ndarray) -> np.ndarray:
        return distance_bins(d)

    def add(self, same: np.ndarray, different: np.ndarray) -> None:
        """Count samples of the distance between the same object's and different objects'
        descriptors; the ratio and the test are recomputed."""
        self.add_counts(distance_counts(same), distance_counts(different))

    def add_counts(self, same: np.ndarray, different: np.ndarray) -> None:
        """Count samples already binned (``(BINS,)`` histograms, as :func:`distance_counts`)."""
        self.same += np.asarray(same, dtype=float)
        self.different += np.asarray(different, dtype=float)
        self._table = np.log(self.p_same()) - np.log(self.p_different())
        self._informative = self.separation() > _z(self.probability)

    def p_same(self) -> np.ndarray:
        """``(BINS,)`` the *same* distribution with its prior (uniform before samples)."""
        w = self.prior_weight
        return (self.same + w / BINS) / (self.same.sum() + w)

    def p_different(self) -> np.ndarray:
        """``(BINS,)`` the *different* distribution with its prior (uniform before samples)."""
        w = self.prior_weight
        return (self.different + w / BINS) / (self.different.sum() + w)

    def log_ratio(self, d: np.ndarray) -> np.ndarray:
        """``log p(d | same) − log p(d | different)`` at cosine distances ``d`` (0 at NaN)."""
        d = np.asarray(d, dtype=np.float64)
        known = np.isfinite(d)
        return np.where(known, self._table[self._bins(np.where(known, d, 0.0))], 0.0)

    def auc(self) -> float:
        """Probability that a *same* sample lies nearer than a *different* one (ties half):
        the area under the ROC curve of the distance as a classifier (0.5 before samples)."""
        n_s, n_d = self.same.sum(), self.different.sum()
        if n_s == 0 or n_d == 0:
            return 0.5
        below = np.concatenate([[0.0], np.cumsum(self.different)[:-1]])
        wins = (self.same * (n_d - below - self.different)).sum()
        ties = (self.same * self.different).sum()
        return float((wins + 0.5 * ties) / (n_s * n_d))

    def separation(self) -> float:
        """The rank statistic's z-score for *same nearer than different* (0 without samples)."""
        n_s, n_d = self.same.sum(), self.different.sum()
        if n_s == 0 or n_d == 0:
            return 0.0
        se = np.sqrt((n_s + n_d + 1.0) / (12.0 * n_s * n_d))
        return float((self.auc() - 0.5) / se)

    @property
    def informative(self) -> bool:
        """Whether *same* is nearer than *different* beyond chance at ``probability``."""
        return self._informative


@functools.lru_cache(maxsize=16)
def _z(probability: float) -> float:
    """The standard normal quantile of ``probability`` (:attr:`AppearanceModel.informative`'s
    test; a handful of probabilities, computed once each)."""
    return float(norm.ppf(probability))


def _within(appearance: np.ndarray) -> np.ndarray:
    """Cosine distances of every pair of distinct objects of one map with a descriptor."""
    known = appearance[np.any(appearance != 0, axis=1)]
    i, j = np.triu_indices(known.shape[0], 1)
    u = unit_rows(known)
    return np.clip(1.0 - np.einsum("pd,pd->p", u[i], u[j]), 0.0, 2.0)


def _across(old: np.ndarray, new: np.ndarray) -> np.ndarray:
    """Cosine distances of every object of ``old`` with a descriptor to every one of ``new``
    (as :func:`_within` computes each pair)."""
    a = unit_rows(old[np.any(old != 0, axis=1)])
    b = unit_rows(new[np.any(new != 0, axis=1)])
    i, j = np.divmod(np.arange(a.shape[0] * b.shape[0]), max(b.shape[0], 1))
    return np.clip(1.0 - np.einsum("pd,pd->p", a[i], b[j]), 0.0, 2.0)


#: per robot, its last summary whose within-map histogram was counted (a weak reference: a
#: memo, used only when a later summary holds every one of its objects with the same
#: descriptor)
_COUNTED: weakref.WeakValueDictionary = weakref.WeakValueDictionary()


def within_counts(summary) -> np.ndarray:
    """``(BINS,)`` histogram of the distances between the distinct objects of ``summary``'s
    map (:func:`_within`), kept with the summary: a map a link holds is the same object at
    many exchanges, and one grown by a partial summary
    (:meth:`~teamslam.association.ObjectSummary.updated`) — or a whole summary that holds
    every object of the robot's last one counted with the same descriptor — adds the new
    objects' pairs to its predecessor's counts instead of counting every pair again."""
    cached = summary.__dict__.get("_within_counts")
    if cached is not None:
        return cached
    grown = summary.__dict__.pop("_grown_from", None)
    if grown is None:
        grown = _grown_from_counted(summary)
    if grown is None:
        counts = distance_counts(_within(summary.appearance))
    else:
        before, old, new = grown
        counts = before + distance_counts(_within(new)) + distance_counts(_across(old, new))
    summary.__dict__["_within_counts"] = counts
    _COUNTED[summary.robot] = summary
    return counts


def _grown_from_counted(summary) -> tuple | None:
    """``(counts, old, new)`` when ``summary`` holds every object of its robot's last counted
    summary with the same descriptor (ids increasing in both): that summary's within-map
    counts, its descriptors and those of the objects it lacks; else ``None``."""
    last = _COUNTED.get(summary.robot)
    if last is None or last is summary or last.appearance is None or len(last) > len(summary):
        return None
    if last.appearance.shape[1] != summary.appearance.shape[1] or len(last) == 0:
        return None
    ids, old = summary.ids, last.ids
    if np.any(ids[1:] <= ids[:-1]) or np.any(old[1:] <= old[:-1]):
        return None
    at = np.minimum(np.searchsorted(ids, old), len(ids) - 1)
    if not np.array_equal(ids[at], old) or not np.array_equal(
        summary.appearance[at], last.appearance
    ):
        return None
    added = np.ones(len(ids), dtype=bool)
    added[at] = False
    return last.__dict__["_within_counts"], last.appearance, summary.appearance[added]


def link_model(first, second, held: np.ndarray | None, probability: float):
    """The appearance model of a link, or ``None`` when the two summaries' descriptors cannot
    be compared (one has none, or their dimensions differ).

    Parameters
    ----------
    first, second
        The two :class:`~teamslam.association.ObjectSummary` s.
    held
        ``(h, 2)`` pairs ``(first's id, second's id)`` the link holds (*same* samples), or
        ``None``.
    probability
        The confidence of the model's rank test.
    """
    a, b = first.appearance, second.appearance
    if a is None or b is None or a.shape[1] != b.shape[1]:
        return None
    model = AppearanceModel(probability, prior_weight=LINK_PRIOR_WEIGHT)
    same = np.zeros(BINS, dtype=np.int64)
    for counts in (first.same_counts, second.same_counts):
        if counts is not None:
            same += counts
    if held is not None and len(held):
        held = np.asarray(held, dtype=np.int64).reshape(-1, 2)
        ia, ib = np.searchsorted(first.ids, held[:, 0]), np.searchsorted(second.ids, held[:, 1])
        ia, ib = np.minimum(ia, len(first) - 1), np.minimum(ib, len(second) - 1)
        ok = (first.ids[ia] == held[:, 0]) & (second.ids[ib] == held[:, 1])
        ia, ib = ia[ok], ib[ok]
        ok = np.any(a[ia] != 0, axis=1) & np.any(b[ib] != 0, axis=1)
        ua, ub = unit_rows(a[ia[ok]]), unit_rows(b[ib[ok]])
        same += distance_counts(np.clip(1.0 - np.einsum("pd,pd->p", ua, ub), 0.0, 2.0))
    different = within_counts(first) + within_counts(second)
    model.add_counts(same, different)
    return model


def chance_tail(model: AppearanceModel, observed: float, k: int, m: int) -> float:
    """Probability that ``k`` chance look-alikes reach a summed log ratio of ``observed``.

    A chance look-alike is an object paired with the best-looking (highest log ratio) of ``m``
    objects that are not it, each drawn from the *different* distribution: its log ratio ``L``
    has ``P(L < x) = (1 − q(x))^m`` with ``q(x)`` the *different* distribution's mass at or
    above ``x``. The ``k`` pairs are independent; their sum's distribution is the ``k``-fold
    convolution on a grid of :data:`TAIL_GRID` steps, each value rounded up (the tail is
    over-estimated).
    """
    if k <= 0:
        return 1.0
    low, high, step, pmf = _best_of(model, m)
    if step is None:
        return 1.0 if observed <= k * high else 0.0
    total = np.array([1.0])
    for _ in range(k):
        total = np.convolve(total, pmf)
    return _tail(total, observed, k, low, step)


def _best_of(model: AppearanceModel, m: int):
    """``(low, high, step, pmf)``: the law of the best log ratio of ``m`` different objects on
    :func:`chance_tail`'s grid (``step`` and ``pmf`` ``None`` when the ratio is constant)."""
    values = model._table
    p = model.p_different()
    order = np.argsort(values, kind="stable")
    v, p = values[order], p[order]
    at_least = np.cumsum(p[::-1])[::-1]  # q at each value (mass at or above it)
    above = np.concatenate([at_least[1:], [0.0]])  # mass strictly above
    # best of m: P(L ≥ v_i) − P(L > v_i)
    best = (1.0 - above) ** m - (1.0 - at_least) ** m
    best = np.clip(best, 0.0, None)
    low, high = float(v[0]), float(v[-1])
    if high <= low:
        return low, high, None, None
    step = (high - low) / TAIL_GRID
    cells = np.ceil((v - low) / step - 1e-9).astype(np.int64)
    return low, high, step, np.bincount(cells, weights=best, minlength=TAIL_GRID + 1)


def _tail(total: np.ndarray, observed: float, k: int, low: float, step: float) -> float:
    """The mass of ``total`` (the sum of ``k`` best-of laws on the grid) at or above
    ``observed``."""
    # the sum's value at cell c is k·low + c·step
    first = int(np.ceil((observed - k * low) / step - 1e-9))
    if first <= 0:
        return 1.0
    return float(min(1.0, total[first:].sum()))


def beyond_chance(model: AppearanceModel, log_ratio: np.ndarray, m: int, probability: float):
    """Which single pairs look alike beyond what the best chance look-alike of ``m`` objects
    gives at ``probability`` (:func:`chance_tail` of one pair), elementwise."""
    log_ratio = np.asarray(log_ratio, dtype=float)
    values, inverse = np.unique(log_ratio, return_inverse=True)
    low, high, step, pmf = _best_of(model, m)  # one pair: the law itself, computed once
    if step is None:
        tails = [1.0 if float(v) <= high else 0.0 for v in values]
    else:
        tails = [_tail(pmf, float(v), 1, low, step) for v in values]
    ok = np.array([t <= 1.0 - probability for t in tails])
    return ok[inverse].reshape(log_ratio.shape) if values.size else np.zeros(log_ratio.shape, bool)


def rarity(model: AppearanceModel) -> AppearanceModel:
    """The evidence of a resemblance without a *same* distribution: ``model`` with its log ratio
    replaced by ``r(d) = −log P(d' ≤ d | different)``, how rarely two different objects look at
    least as alike (from the *different* histogram with its prior, per bin).

    ``r`` is 0 where every different pair is as close or closer, grows as close resemblances
    get rarer, and never speaks against a pair. It is no likelihood ratio — nothing says how
    the same object looks yet — but a significance: :func:`chance_tail` and
    :func:`beyond_chance` of the returned model bound ``k`` chance look-alikes by it, each the
    best-looking of ``m`` objects drawn from the *different* distribution, exactly as for the
    learned ratio. The model's other parts (histograms, :attr:`~AppearanceModel.informative`)
    are ``model``'s.
    """
    out = AppearanceModel(model.probability, model.prior_weight)
    out.add_counts(model.same, model.different)
    mass_at_or_below = np.cumsum(out.p_different())
    out._table = -np.log(np.minimum(mass_at_or_below, 1.0))
    return out


def rare_triples(model: AppearanceModel, m: int, probability: float) -> bool:
    """Whether three pairs alike at the closest distance ``model`` knows can lie beyond what
    three chance look-alikes among ``m`` objects reach at ``probability`` (:func:`chance_tail`):
    whether its evidence could ever answer from fewer pairs than position alone needs. Never
    for descriptors that are all alike (every distance in the closest bin: its rarity is 0)."""
    best = float(model._table.max(initial=0.0))
    return best > 0.0 and chance_tail(model, 3.0 * best, 3, m) <= 1.0 - probability
