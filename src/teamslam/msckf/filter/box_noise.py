"""Measurement noise of an object's box centre from a detector: a share of the box's size.

A detection with a box size travels as a *box row* of :data:`BOX_COLUMNS` numbers
``(u_l, v_l, u_r, v_r, w, h, c_ul, c_vl, c_ur, c_vr)``: the stereo box centre, the box's width
and height (units of ``K``) and per centre coordinate ``1`` where the box touches the image
border along that coordinate's axis (clipped: the centre of the visible part lies inward of the
object's by half the hidden extent, unknown). A plain row holds the centre only.

Per coordinate the variance is ``σ₀² + (α·s)² + c·s²`` (:func:`box_variances`): ``σ₀`` is
``filter.object_std``, ``α`` ``filter.object_size_share``, ``s`` the box's size along the
coordinate's axis (``w`` for ``u``, ``h`` for ``v``) and ``c`` the clipped flag (a hidden part
up to twice the visible one, at one σ; for ``u`` plus half the disparity, squared). Plain rows
keep ``σ₀²``. Derivation: the concept page *Boxes* (``docs/concepts/boxes.md``).

A box centre's error persists from frame to frame (perspective, occlusion and the detector's
habits shift it by a share of the box that changes slowly with the viewpoint), which a filter
taking each box's error as new cannot see: its objects come out overconfident.
:class:`Overconfidence` learns by how much from evidence beyond the window — two robots'
estimates of one object, paired by the association — and :func:`box_variances` multiplies the
box's own part ``σ₀² + (α·s)²`` of new boxes by the factor ``κ`` it gives.

A box an occluder cut short shows part of its object: :class:`ObjectExtents` keeps each
object's size over its disparity, and :func:`occlusion_shift` takes a box short of it at the
edge the occluder left (the tracker's gates and the filter's update alike).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy import stats

from teamslam.gaussian import chi2_quantile, log_chi2_std

__all__ = [
    "BOX_COLUMNS",
    "OVERCONFIDENCE_PROBABILITY",
    "FormedUnder",
    "ObjectExtents",
    "Overconfidence",
    "box_rows",
    "box_size2",
    "box_variances",
    "is_box",
    "occlusion_shift",
    "occlusion_sigmas",
]

#: Width of a box row: the centre (4), the size (2), the clipped flags (4).
BOX_COLUMNS = 10
#: How many edge σ from the border an edge may lie and still count as the border's.
CLIP_EDGE_SIGMAS = 2.0


def is_box(rows: np.ndarray) -> bool:
    """Whether ``rows`` (``(..., 4)`` or ``(..., BOX_COLUMNS)``) are box rows."""
    return np.shape(rows)[-1] == BOX_COLUMNS


def box_size2(rows: np.ndarray) -> np.ndarray:
    """``(..., 4)`` squared box size along each centre coordinate's axis (``w², h², w², h²``)."""
    size = rows[..., 4:6]
    return np.concatenate([size, size], axis=-1) ** 2


def box_variances(
    rows: np.ndarray, std: float, share: float, kappa: float | None = None
) -> np.ndarray:
    """``(..., 4)`` variance of each centre coordinate of box rows (module docstring).

    ``kappa``: the factor by which the box's own part ``σ₀² + (α·s)²`` is multiplied
    (:class:`Overconfidence`; the clipped part is not); ``None``: 1.
    """
    size2 = box_size2(rows)
    if kappa is None:
        out = std**2 + (share**2 + rows[..., 6:10]) * size2
    else:
        out = kappa * (std**2 + share**2 * size2) + rows[..., 6:10] * size2
    # the hidden extents of the two images differ by the disparity: so may their centres' bias
    half_disparity2 = 0.25 * (rows[..., 0] - rows[..., 2]) ** 2
    out[..., 0] += rows[..., 6] * half_disparity2
    out[..., 2] += rows[..., 8] * half_disparity2
    return out


def box_rows(
    z: np.ndarray,
    sizes: np.ndarray,
    image_size: tuple[int, int] | None,
    std: float,
    share: float,
) -> np.ndarray:
    """Box rows of detections ``z`` (``(D, 4)``) with box sizes ``sizes`` (``(D, 2)``).

    A coordinate is clipped when an edge of its box lies within :data:`CLIP_EDGE_SIGMAS` edge
    σ (``√2`` times the centre's unclipped σ, one pixel at least) of the image's border
    ``[-0.5, W - 0.5] × [-0.5, H - 0.5]``: the border cut the box there, or the detector's
    noise moved its edge just inside. The right image's box is taken as wide as the left one's,
    and ``u_r`` counts as clipped wherever the left box is clipped at the right border: the
    right centre was found for the visible part (its patch, or a right box cut as well), so it
    lies as far inward of the object's as the left one, though the right image — a point at
    ``u_l`` is seen at ``u_l − d`` — shows that box clear of its border. Without ``image_size``
    no box counts as clipped.
    """
    z = np.asarray(z, dtype=float)
    sizes = np.asarray(sizes, dtype=float)
    rows = np.zeros((z.shape[0], BOX_COLUMNS))
    rows[:, :4] = z
    rows[:, 4:6] = sizes
    if image_size is None or not z.shape[0]:
        return rows
    width, height = image_size
    sigma = np.sqrt(std**2 + (share * sizes) ** 2)  # (D, 2): u, v
    margin = -0.5 + np.maximum(CLIP_EDGE_SIGMAS * np.sqrt(2.0) * sigma, 1.0)
    axis = [0, 1, 0, 1]  # u_l, v_l, u_r, v_r: each coordinate's box side and image extent
    half, margin = 0.5 * sizes[:, axis], margin[:, axis]
    extent = np.array([width, height, width, height], float)
    low = z - half <= margin
    high = z + half >= extent - 1.0 - margin
    rows[:, 6:10] = low | high
    # a box the left image's right border cut: its right centre is that of the visible part
    # (the part's patch, or a right box cut as well), inward of the object's as the left one,
    # though the right image, which sees further right, shows it clear of its border
    rows[:, 8] = np.maximum(rows[:, 8], high[:, 0] & np.isfinite(z[:, 2]))
    # a box cut at the top or bottom is cut in both images (the same rows after rectification)
    v_cut = np.maximum(rows[:, 7], rows[:, 9])
    rows[:, 7] = rows[:, 9] = v_cut
    return rows


#: Probability of the one-sided, distribution-free test (the binomial test of the median) that
#: the pairs' squared Mahalanobis distances exceed χ²(3)'s: only then is ``κ`` above 1.
OVERCONFIDENCE_PROBABILITY = 0.99
#: Median of χ²(3)
_CHI2_3_MEDIAN = chi2_quantile(0.5, 3)


class Overconfidence:
    """How overconfident a robot's objects are, learned from two estimates of one object.

    Each sample is the squared Mahalanobis distance ``d² = rᵀ D⁻¹ r`` of two estimates of one
    object made from different views, ``χ²(3)`` when their covariances are right. A box error
    that persists beyond the filter's window is taken for the object's position, two estimates
    from elsewhere carry different offsets, and ``d²`` grows by the factor the covariances miss.
    Two sources, each chosen by evidence other than ``d²`` itself:

    * *the links* (source: the neighbour's id): a pair of objects the inter-robot association
      identified as one by the transform of the pairs its link already holds, taken before the
      pair was held (so before consensus averaged the two estimates): the two robots'
      estimates in the shared world frame, ``D = Σₐ + Σ_b``;
    * *the robot's own re-identifications* (source ``-1``): a long-unseen object that the
      appearance and class of a new object's boxes alone identify, before the position gate
      (:meth:`~teamslam.msckf.objects.tracking.ObjectTracker.reidentify`), ``D`` from the joint
      state.

    An offset the two estimates share (robots driving the same way see an object from the same
    side) cancels in ``r``: each source measures the overconfidence at most, and ``κ`` is the
    larger of the two.

    Each sample is kept with the ``κ`` its two estimates were formed under: with the box part
    dominating an object's covariance, covariances formed under ``κ`` are ``κ`` times those
    under 1, so ``κ_i · d²_i ~ κ · χ²(3)`` whatever ``κ_i``. For a re-identification the old
    object's last boxes may be older than the factor now in force: ``κ_i`` is the mean of the
    factors in force at each object's last update (taking the one now for both would count
    the old object's covariance ``κ_i`` times too large and let ``κ`` run away).

    The links' estimate is robust, as the association's frame scale:
    ``κ = median(κ_i · d²_i) / median(χ²(3))`` (a minority of wrong pairs moves it little),
    taken only when the median of ``κ_i · d²_i`` exceeds χ²(3)'s by the one-sided
    binomial (sign) test at :data:`OVERCONFIDENCE_PROBABILITY` — no assumption of the samples'
    distribution, and with few samples no departure from ``κ = 1`` — and never below 1.

    Appearance alone may name a look-alike, and among a robot's own re-identifications such
    pairs can be the majority, which no median survives. Each of those samples comes with
    the ``d²`` of the other old objects of its call (of every class; appearance may name any
    of them): what a sample's ``d²`` looks like when the named object is another one. Their
    estimate is a mixture's (:func:`mixture_factor`): each sample right (``κ χ²(3)``) or a
    pair of two objects (distributed as the calls' other candidates, pooled), ``κ`` and the
    share of right pairs by maximum likelihood, taken when it beats ``κ = 1`` by the
    likelihood-ratio test at :data:`OVERCONFIDENCE_PROBABILITY`.

    The links' samples pass the association's gate under its transform, whose drift allowance
    grows with the distance from the pairs it was fitted on: a pair far from them is admitted at
    any ``d²`` of the identity; near them the gate cuts the upper tail, so the median is, if
    anything, low (``κ`` errs towards the calibrated noise). The re-identifications' are not
    gated by position at all (a pair merged, which passed the ``χ²(3)`` gate, would be cut).
    """

    def __init__(self) -> None:
        #: (source, id, other id) → ``κ_i · d²_i`` of the pair's first sample
        self.samples: dict[tuple[int, int, int], float] = {}
        #: (-1, id, other id) → ``κ_i · d²`` of the other old objects of the
        #: re-identification call the pair's first sample came from
        self.alternatives: dict[tuple[int, int, int], np.ndarray] = {}
        # per own sample, its kernel sum over every positive alternative pooled so far, and the
        # pooled alternatives' logarithms (one array per sample that had any): kept as samples
        # come (each new sample adds its alternatives to every earlier sum), so a sample costs
        # what its own alternatives and the pool cost, not every sample times the pool
        # (:func:`mixture_factor`)
        self._kernel: dict[tuple[int, int, int], float] = {}
        self._pooled: list[np.ndarray] = []
        self._kappa = 1.0

    def __len__(self) -> int:
        return len(self.samples)

    @property
    def kappa(self) -> float:
        """The factor ``κ ≥ 1`` (class docstring)."""
        return self._kappa

    def add(
        self,
        neighbour: int,
        pairs: Mapping[tuple[int, int], float],
        kappa: float | Mapping[tuple[int, int], float],
        alternatives: Mapping[tuple[int, int], np.ndarray] | None = None,
    ) -> int:
        """Record source ``neighbour``'s ``pairs`` (two ids) → ``d²`` taken under ``kappa``
        (``-1``: the robot's own re-identifications); a pair already recorded keeps its first
        sample. ``kappa``: one factor for all, or each pair's. ``alternatives``: per pair of the
        robot's own, the ``d²`` of its call's other old objects (class docstring). Returns how
        many were new."""
        new = 0
        for (own, theirs), d2 in pairs.items():
            key = (int(neighbour), int(own), int(theirs))
            if key not in self.samples and np.isfinite(d2) and d2 >= 0:
                factor = kappa[(own, theirs)] if isinstance(kappa, Mapping) else kappa
                self.samples[key] = float(factor) * float(d2)
                others = None if alternatives is None else alternatives.get((own, theirs))
                if others is not None and neighbour < 0:
                    others = np.asarray(others, float).ravel()
                    others = others[np.isfinite(others) & (others >= 0)]
                    self.alternatives[key] = float(factor) * others
                if neighbour < 0:
                    self._count_own(key)
                new += 1
        if new:
            self._kappa = self._factor()
        return new

    def _count_own(self, key: tuple[int, int, int]) -> None:
        """Add own sample ``key``'s alternatives to the kernel sums of the earlier own samples,
        and its own sum over the whole pool (:attr:`_kernel`)."""
        part = self.alternatives.get(key, np.zeros(0))
        part = np.log(part[part > 0])
        if part.size and self._kernel:
            earlier = list(self._kernel)
            log_s = np.log(np.maximum([self.samples[k] for k in earlier], 1e-12))
            for k, extra in zip(earlier, _kernel_sums(log_s, part), strict=True):
                self._kernel[k] += float(extra)
        if part.size:
            self._pooled.append(part)
        pool = np.concatenate([np.zeros(0), *self._pooled])
        log_key = np.log(np.array([max(self.samples[key], 1e-12)]))
        self._kernel[key] = float(_kernel_sums(log_key, pool)[0])

    def _factor(self) -> float:
        """The larger of the two sources' factors: the pairs of the links (pooled) and the
        robot's own re-identifications (source ``-1``, :func:`mixture_factor` from the kernel
        sums kept as samples came)."""
        own = np.array([k[0] < 0 for k in self.samples], dtype=bool)
        values = np.fromiter(self.samples.values(), float, count=own.size)
        links = overconfidence_factor(values[~own])
        count = sum(p.size for p in self._pooled)
        if not self.alternatives or count == 0:
            return max(links, overconfidence_factor(values[own]))
        s = np.maximum(values[own], 1e-12)
        sums = np.array([self._kernel[k] for k in self.samples if k[0] < 0])
        return max(links, _mixture_kappa(s, _wrong_density(s, sums, count)))

    def arrays(self) -> dict[str, np.ndarray]:
        """What it learned, as arrays (for a snapshot; :meth:`from_arrays`)."""
        keys = np.array(list(self.samples), dtype=np.int64).reshape(-1, 3)
        others = [self.alternatives.get(tuple(k), np.zeros(0)) for k in keys.tolist()]
        return {
            "keys": keys,
            "values": np.fromiter(self.samples.values(), float),
            "alternative_counts": np.array([o.size for o in others], np.int64),
            "alternatives": np.concatenate([np.zeros(0), *others]),
        }

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> Overconfidence:
        """The learner of :meth:`arrays`."""
        out = cls()
        keys = np.asarray(arrays["keys"], dtype=np.int64).reshape(-1, 3)
        values = np.asarray(arrays["values"], dtype=float).ravel()
        if keys.shape[0] != values.size:
            raise ValueError(f"overconfidence: {keys.shape[0]} pairs, {values.size} values")
        out.samples = {tuple(k): float(v) for k, v in zip(keys.tolist(), values, strict=True)}
        counts = np.asarray(arrays.get("alternative_counts", np.zeros(0)), np.int64).ravel()
        flat = np.asarray(arrays.get("alternatives", np.zeros(0)), float).ravel()
        if counts.size:  # a snapshot from before has none
            if counts.size != keys.shape[0] or counts.sum() != flat.size or (counts < 0).any():
                raise ValueError(
                    f"overconfidence: {counts.size} alternative counts summing to "
                    f"{counts.sum()} for {keys.shape[0]} pairs and {flat.size} alternatives"
                )
            for k, part in zip(keys.tolist(), np.split(flat, np.cumsum(counts)[:-1]), strict=True):
                if k[0] < 0 and part.size:
                    out.alternatives[tuple(k)] = part.copy()
        own = [k for k in out.samples if k[0] < 0]
        out._pooled = [np.log(a[a > 0]) for a in out.alternatives.values() if (a > 0).any()]
        pool = np.concatenate([np.zeros(0), *out._pooled])
        log_s = np.log(np.maximum([out.samples[k] for k in own], 1e-12))
        out._kernel = dict(zip(own, _kernel_sums(log_s, pool).tolist(), strict=True))
        if values.size:
            out._kappa = out._factor()
        return out


def overconfidence_factor(scaled: np.ndarray) -> float:
    """``κ`` of samples ``κ_i · d²_i`` (:class:`Overconfidence`): ``median / median(χ²(3))`` when
    more of them exceed χ²(3)'s median than chance allows (the one-sided sign test at
    :data:`OVERCONFIDENCE_PROBABILITY`), else 1."""
    scaled = np.asarray(scaled, dtype=float)
    n = scaled.size
    if n == 0:
        return 1.0
    above = int(np.count_nonzero(scaled > _CHI2_3_MEDIAN))
    # P(at least `above` of n above the median | the covariances are right) = sf(above − 1)
    if stats.binom.sf(above - 1, n, 0.5) > 1.0 - OVERCONFIDENCE_PROBABILITY:
        return 1.0
    return max(1.0, float(np.median(scaled)) / _CHI2_3_MEDIAN)


#: Most kernel evaluations :func:`mixture_factor` holds at once (samples × alternatives)
_MIXTURE_CHUNK = 1 << 20


def mixture_factor(scaled: np.ndarray, alternatives: list[np.ndarray]) -> float:
    """``κ`` of samples ``s_i = κ_i · d²_i``, some of which pair two objects (a robot's own
    re-identifications, :class:`Overconfidence`).

    Each sample is right with probability ``w``, density ``χ²₃(s / κ) / κ``, or pairs two
    objects, with the density of the ``d²`` of the old objects appearance did not name
    (``alternatives``: one array per call, scaled alike, pooled): a kernel density in
    ``log d²`` of bandwidth the spread of ``log χ²(3)``. ``κ`` and ``w`` maximise the likelihood
    (over a grid, ``κ`` from 1 to beyond the largest sample); ``κ > 1`` only when it beats
    ``κ = 1`` (its own best ``w``) by the likelihood-ratio test (χ²(1)) at
    :data:`OVERCONFIDENCE_PROBABILITY`. Without any alternative, :func:`overconfidence_factor`.
    """
    scaled = np.asarray(scaled, dtype=float).ravel()
    others = np.concatenate([np.zeros(0), *(np.asarray(a, float).ravel() for a in alternatives)])
    others = np.log(others[others > 0])
    if scaled.size == 0 or others.size == 0:
        return overconfidence_factor(scaled)
    s = np.maximum(scaled, 1e-12)
    return _mixture_kappa(s, _wrong_density(s, _kernel_sums(np.log(s), others), others.size))


def _kernel_sums(log_s: np.ndarray, log_others: np.ndarray) -> np.ndarray:
    """``(len(log_s),)`` sums over ``log_others`` of the unnormalised kernel of
    :func:`mixture_factor` at each ``log_s`` (in chunks: memory bounded)."""
    h = log_chi2_std(3)  # how far one pair's d² lies from another's of its kind
    out = np.zeros(log_s.size)
    if not log_others.size:
        return out
    rows = max(1, _MIXTURE_CHUNK // log_others.size)
    for start in range(0, log_s.size, rows):
        z = (log_s[start : start + rows, None] - log_others[None, :]) / h
        out[start : start + rows] = np.exp(-0.5 * z * z).sum(axis=1)
    return out


def _wrong_density(s: np.ndarray, sums: np.ndarray, count: int) -> np.ndarray:
    """The density in ``d²`` at each sample ``s`` of the pairs of two objects, from its kernel
    sums over ``count`` alternatives (:func:`_kernel_sums`)."""
    return sums / (count * log_chi2_std(3) * np.sqrt(2.0 * np.pi) * s)


def _mixture_kappa(s: np.ndarray, wrong: np.ndarray) -> float:
    """:func:`mixture_factor`'s ``κ`` of samples ``s`` given each one's density as a pair of two
    objects."""
    kappas = np.geomspace(1.0, max(10.0, 100.0 * float(s.max())), 400)
    shares = np.linspace(0.01, 1.0, 100)
    loglik = np.empty(kappas.size)  # each κ at its best share w
    for k, kappa in enumerate(kappas):
        right = stats.chi2.pdf(s / kappa, 3) / kappa
        mixed = shares[:, None] * right[None, :] + (1.0 - shares)[:, None] * wrong
        loglik[k] = np.log(np.maximum(mixed, 1e-300)).sum(axis=1).max()
    best = int(np.argmax(loglik))
    if 2.0 * (loglik[best] - loglik[0]) <= chi2_quantile(OVERCONFIDENCE_PROBABILITY, 1):
        return 1.0
    return float(kappas[best])


class FormedUnder:
    """Under which factor ``κ`` each object's covariance was formed, to widen it when ``κ`` grows.

    New boxes get ``κ (σ₀² + (α s)²)`` (:func:`box_variances`), but an object whose boxes came
    before ``κ`` was learned (or grew) keeps the covariance those boxes gave: too small by the
    factor the learner now finds. With the box part dominating an object's information,
    ``P⁻¹ ∝ Σ_k 1 / κ_k`` over its boxes (``κ_k`` the factor in force at box ``k``), against
    ``n / κ`` had every box been taken under the factor now in force; so the object's
    covariance is too small by

        ``r = κ · mean_k(1 / κ_k)``  (``≥ 1`` while ``κ`` only grows; never taken below 1),

    which is 1 for an object formed under ``κ`` and ``κ`` for one formed before it
    (:meth:`widening`). The tracker's re-identification widens the joint covariance of a new
    and an old object by these factors before its gate, as a congruence ``D P D`` (``√r`` on
    each object's coordinates: each block times its ``r``, the cross term times ``√(r_n r_o)``;
    it stays a covariance and every correlation stays).
    """

    def __init__(self) -> None:
        #: object id → ``[boxes, Σ 1/κ_k]``
        self.boxes: dict[int, list[float]] = {}

    def __len__(self) -> int:
        return len(self.boxes)

    def add(self, ids: np.ndarray, kappa: float, boxes: float = 1.0) -> None:
        """Count ``boxes`` boxes of each object of ``ids`` taken under ``kappa``."""
        inverse = boxes / float(kappa)
        for i in np.asarray(ids, np.int64).ravel().tolist():
            entry = self.boxes.setdefault(i, [0.0, 0.0])
            entry[0] += boxes
            entry[1] += inverse

    def merge(self, new: int, old: int) -> None:
        """Object ``new`` is ``old`` seen again: its boxes are ``old``'s."""
        entry = self.boxes.pop(int(new), None)
        if entry is not None:
            target = self.boxes.setdefault(int(old), [0.0, 0.0])
            target[0] += entry[0]
            target[1] += entry[1]

    def widening(self, ids: np.ndarray, kappa: float) -> np.ndarray:
        """``(len(ids),)`` factor ``r ≥ 1`` by which each object's covariance is too small under
        ``kappa`` (class docstring); 1 for an object without boxes counted."""
        ids = np.asarray(ids, np.int64).ravel()
        out = np.ones(ids.size)
        for k, i in enumerate(ids.tolist()):
            entry = self.boxes.get(i)
            if entry is not None and entry[0] > 0:
                out[k] = kappa * entry[1] / entry[0]
        return np.maximum(out, 1.0)

    def arrays(self) -> dict[str, np.ndarray]:
        """What it counted, as arrays (for a snapshot; :meth:`from_arrays`)."""
        ids = np.fromiter(self.boxes, np.int64, count=len(self.boxes))
        values = np.array(list(self.boxes.values()), float).reshape(-1, 2)
        return {"ids": ids, "values": values}

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> FormedUnder:
        """The counts of :meth:`arrays`."""
        out = cls()
        ids = np.asarray(arrays["ids"], np.int64).ravel()
        values = np.asarray(arrays["values"], float).reshape(-1, 2)
        if ids.size != values.shape[0]:
            raise ValueError(f"formed-under: {ids.size} objects, {values.shape[0]} counts")
        out.boxes = {i: list(v) for i, v in zip(ids.tolist(), values.tolist(), strict=True)}
        return out


class ObjectExtents:
    """Each object's size over its disparity, whatever its depth (the occlusion model of
    :func:`occlusion_shift`).

    A box ``w × h`` pixels of an object at disparity ``d`` gives ``(w, h) / d``: the object's
    width over the stereo baseline and its height over it (times ``f_y / f_x``), the same at
    every depth. An object's is the median of its uncut stereo boxes' — an occluder hides part
    of a few, the detector moves each edge a little.
    """

    def __init__(self) -> None:
        #: object id → ``[(w / d, h / d), …]`` of its boxes
        self.sizes: dict[int, list[tuple[float, float]]] = {}
        self._median: dict[int, np.ndarray] = {}  # of the objects whose sizes did not change

    def __len__(self) -> int:
        return len(self.sizes)

    def add(self, ids: np.ndarray, disparity: np.ndarray, rows: np.ndarray) -> None:
        """Count box rows ``rows`` of objects ``ids`` seen at ``disparity`` (a prediction's,
        less noisy than a box's own); cut boxes and non-positive disparities are left out."""
        ok = (disparity > 0) & ~rows[:, 6:10].any(axis=1)
        per = rows[ok, 4:6] / disparity[ok, None]
        for i, (w, h) in zip(ids[ok].tolist(), per.tolist(), strict=True):
            self.sizes.setdefault(i, []).append((w, h))
            self._median.pop(i, None)

    def of(self, ids: np.ndarray) -> np.ndarray:
        """``(len(ids), 2)`` each object's size over its disparity (NaN: no box yet)."""
        out = np.full((np.size(ids), 2), np.nan)
        for k, i in enumerate(np.asarray(ids).tolist()):
            median = self._median.get(i)
            if median is None and self.sizes.get(i):
                median = self._median[i] = np.median(np.asarray(self.sizes[i]), axis=0)
            if median is not None:
                out[k] = median
        return out

    def expected(
        self, ids: np.ndarray, pred: np.ndarray, cov: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(len(ids), 2)`` the box size of each object at its predicted stereo centre
        ``pred`` ``(…, 4)`` (NaN: no size yet, or no positive disparity), and its variance from
        the prediction's covariance ``cov`` ``(…, 4, 4)`` (the disparity's, scaled)."""
        disparity = pred[:, 0] - pred[:, 2]
        per = self.of(ids)
        size = per * np.where(disparity > 0, disparity, np.nan)[:, None]
        var_d = cov[:, 0, 0] + cov[:, 2, 2] - 2.0 * cov[:, 0, 2]
        return size, per**2 * var_d[:, None]

    def merge(self, new: int, old: int) -> None:
        """The sizes of ``new``, merged into ``old`` (one object)."""
        sizes = self.sizes.pop(new, None)
        self._median.pop(new, None)
        if sizes:
            self.sizes.setdefault(old, []).extend(sizes)
            self._median.pop(old, None)

    def arrays(self) -> np.ndarray:
        """``(n, 3)`` rows ``(id, w / d, h / d)`` (for a snapshot; :meth:`from_arrays`)."""
        rows = [(i, *size) for i, sizes in self.sizes.items() for size in sizes]
        return np.array(rows, float).reshape(-1, 3)

    @classmethod
    def from_arrays(cls, rows: np.ndarray) -> ObjectExtents:
        """The sizes of :meth:`arrays`."""
        out = cls()
        for i, w, h in np.asarray(rows, float).reshape(-1, 3).tolist():
            out.sizes.setdefault(int(i), []).append((w, h))
        return out


def occlusion_sigmas(probability: float) -> float:
    """How many σ of its own noise a box must fall short of its object's size by to count as
    cut short (:func:`occlusion_shift`): the one-sided normal quantile of ``probability``."""
    return float(stats.norm.ppf(probability))


def occlusion_shift(
    expected: tuple[np.ndarray, np.ndarray],
    rows: np.ndarray,
    r: np.ndarray,
    variances: np.ndarray,
    own: np.ndarray,
    sigmas: float,
) -> tuple[np.ndarray, np.ndarray]:
    """A box as a measurement of an object it falls short of: an occluder (or the detector)
    hid part of the object on one side, so the box's other edge is the object's, and the
    object's centre lies half the missing extent ``m`` beyond the box's, on a side not known.

    A box falls short along an axis (``u`` by the width, ``v`` by the height) when its size
    lies more than ``sigmas`` σ below the object's at its predicted disparity, σ that of the
    difference: the size's own noise (two edges: twice the centre's σ of ``own``, the box's
    noise without the overconfidence factor) and the predicted size's (an uncertain disparity
    predicts an uncertain size). Its centre is then taken as the box's, or shifted by ``± m / 2``
    towards the prediction, whichever lies nearer it (the side decided by the mean residual of
    the axis' coordinates: one occluder hides the same side in both images); a shifted centre
    is an edge plus half a size, with twice the centre's variance (an edge's). A box inside a
    larger object that reaches neither of its edges stays as far from it as it is. Not for a
    coordinate the image border cut (censored or widened already), nor for an object of no
    size yet (``expected`` NaN).

    Broadcasting arrays: ``expected`` the object's box size at its predicted disparity and
    its variance, ``(…, 2)`` each (:meth:`ObjectExtents.expected`); ``rows``
    ``(…, BOX_COLUMNS)`` the boxes; ``r`` ``(…, k)`` the residuals box − prediction of their
    first ``k`` centre coordinates (``k = 4``; ``k = 2``: the left image's only) and
    ``variances`` ``(…, k)`` theirs in the measurement; ``own`` ``(…, ≥ 2)`` the box's own
    noise of ``(u, v)``. Returns the shifts to add to the residuals and the variances, both of
    ``r``'s broadcast shape.
    """
    k = r.shape[-1]
    size, size_var = expected
    short = size - rows[..., 4:6]
    noise = np.sqrt(4.0 * own[..., :2] + size_var)  # the box's size's (two edges), the object's
    short = np.where(np.isfinite(short) & (short > sigmas * noise), short, 0.0)
    half = 0.5 * short
    if k == 4:
        mean = 0.5 * (r[..., [0, 1]] + r[..., [2, 3]])
        half, mean = half[..., [0, 1, 0, 1]], mean[..., [0, 1, 0, 1]]
    else:
        mean = r
    half = half * (1.0 - rows[..., 6 : 6 + k])
    shifted = (half > 0) & (half < 2.0 * np.abs(mean))  # nearer than the box's own centre
    shift = np.where(shifted, -np.sign(mean) * half, 0.0)
    return shift, np.where(shifted, 2.0 * variances, variances)
