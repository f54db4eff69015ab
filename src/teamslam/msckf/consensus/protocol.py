"""The consensus protocol of one robot (distributed MSCKF paper, §V-B, Alg. 1 step 1).

:class:`ConsensusProtocol` decides what a robot sends, how it answers and how it averages; the
drivers (:func:`teamslam.msckf.team.run_team`, :func:`teamslam.runtime.agent_process.run_agent`)
only schedule it and move its messages through a
:class:`~teamslam.msckf.consensus.transport.Transport`. One step is::

    transport.send(*protocol.requests(t, neighbours))          # round 1: my map ids
    for reply in protocol.answer(t, <ids messages heard>):     # round 2: our common marginal
        transport.send(reply)
    protocol.average(t, <marginals heard>)                      # eq. 19 + Prop. 2

Weights are Metropolis–Hastings, ``A_ij = 1 / (1 + max(d_i, d_j))``, and always sum to one; a
pair averages the common objects that moved by more than ``kl_threshold`` on either side since
it last exchanged them; every received message is checked once
(:func:`~teamslam.msckf.consensus.checks.check_message`) and a rejected one never reaches the
state; with global ids the consensus innovation check (``consensus.innovation_check``, on by
default) leaves out whole a neighbour's marginal in which most objects fail their χ²₃ test.
The counters ``objects_averaged``, ``hybrid_fallbacks`` and ``links_lost`` count per
exchange, ``objects_inactive`` per step; each neighbour not averaged with in an exchange is
named with why (:attr:`ConsensusProtocol.not_averaged`, :data:`NOT_AVERAGED`). Derivations
(weights, moved flags, hybrid consensus, increments, iterations, association between maps): the
concept page *Consensus* (``docs/concepts/consensus.md``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace
from typing import Protocol

import numpy as np

from teamslam.association import (
    CorrespondenceTable,
    ObjectSummary,
    associate,
    pair_innovation_consistent,
)
from teamslam.association.appearance import BINS, cosine_distances, distance_counts
from teamslam.errors import EstimationError, InputError, InternalError
from teamslam.gaussian import NotPositiveDefiniteError, kl_divergence, spd_inverse
from teamslam.graph import metropolis_weight
from teamslam.msckf.consensus.average import SharedPrior, persistent_average
from teamslam.msckf.consensus.checks import ReceivedMarginal, check_message
from teamslam.msckf.consensus.directions import at_first_estimates
from teamslam.msckf.consensus.kernels import merged_record
from teamslam.msckf.consensus.marginals import common_marginal_message, object_marginals
from teamslam.msckf.consensus.messages import (
    CommonMarginalMessage,
    MapIdsMessage,
    Message,
    MessageAge,
    MessageLags,
    summary_wire_bytes,
)
from teamslam.msckf.consensus.rules import consensus_rule
from teamslam.msckf.consensus.selection import active_objects, settling_thresholds
from teamslam.msckf.filter.linearization import keeps_first_estimates
from teamslam.msckf.filter.state import MsckfState
from teamslam.msckf.filter.views import ObjectViews
from teamslam.msckf.settings.values import MsckfConfig

__all__ = ["NOT_AVERAGED", "ConsensusProtocol"]


class ConsensusMember(Protocol):
    """What consensus needs of a robot's filter (:class:`~teamslam.msckf.agent.MsckfAgent` is
    one): its state, settings, index and views, and where rejections and times are counted."""

    robot: int
    state: MsckfState
    config: MsckfConfig
    views: ObjectViews
    counters: dict[str, int]
    timings: dict[str, float]

    def reject(self, what: str, count: int = 1, reason: str = "") -> None: ...


class ConsensusProtocol:
    """One robot's side of consensus.

    Parameters
    ----------
    agent
        The robot's filter (its state is averaged in place; rejections, counts and the
        consensus time are recorded on it).
    neighbours
        The robots it may hear from (its neighbours in the communication graph).
    max_age
        Oldest step accepted, as ``step − max_age`` (0: lock-step, only the current step).
    kl_threshold
        Average a common object only when it moved by more than this since the last exchange
        (default: the agent's ``config.consensus.kl_threshold``; 0 averages everything).
    """

    def __init__(
        self,
        agent: ConsensusMember,
        neighbours: Iterable[int],
        max_age: int = 0,
        kl_threshold: float | None = None,
    ) -> None:
        self.agent = agent
        self.robot = agent.robot
        self.neighbours = frozenset(int(j) for j in neighbours)
        if self.robot in self.neighbours:
            raise InputError(f"robot {self.robot} cannot be its own neighbour")
        self.max_age = int(max_age)
        settings = agent.config.consensus
        threshold = settings.kl_threshold if kl_threshold is None else kl_threshold
        # asynchronous exchanges mix steps: there every common object is averaged
        self.kl_threshold = float(threshold) if self.max_age == 0 else 0.0
        # a bounded consensus set (lock-step only): inactive objects are flagged only when they
        # moved by more than their own threshold (:mod:`teamslam.msckf.consensus.selection`)
        self.bounded = settings.set == "active" and self.max_age == 0
        self._thresholds: np.ndarray | None = None
        # per neighbour: our own per-object marginals as they were at the last exchange, and
        # the number of that exchange
        self._agreed: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
        self._moved: dict[int, np.ndarray] = {}
        self._pending: dict[int, np.ndarray] = {}
        # our own information of each object set we sent this step (ids bytes → Σ⁻¹), which
        # completes the neighbour's marginal of the same set in the average (eq. 42)
        self._own_information: dict[bytes, np.ndarray] = {}
        self._own: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        # the averaging rule (lock-step only; asynchronous robots average) and the prior it
        # keeps: our joint marginal of the objects after the last exchange
        self.rule = consensus_rule(settings.rule if self.max_age == 0 else "average")
        # a first-estimates filter: the average adds nothing along our rigid motions at our
        # first estimates
        first_estimates = keeps_first_estimates(agent.config.filter.linearization)
        self.directions = bool(settings.rigid_directions) and first_estimates
        # and marginals travel with their rigid-motion directions at their means and are
        # averaged with them at our first estimates (joint marginals only)
        self.moved = (
            bool(settings.at_first_estimates) and first_estimates and not settings.per_object
        )
        self._prior: SharedPrior | None = self.rule.initial_prior(agent.state)
        self.step = -1
        # the exchange's frame stamp and, for robots whose steps are not comparable (they drop
        # frames), the oldest stamp accepted as ``stamp_ns − max_age_ns`` (None: by step)
        self.stamp_ns: int | None = None
        self.max_age_ns: int | None = None
        # with it, the age limits learned from each neighbour's lags (MessageLags)
        self.lags: MessageLags | None = None
        # L exchanges per step (lock-step only; asynchronous robots exchange once a step)
        self.iterations = int(settings.iterations) if self.max_age == 0 else 1
        self.iteration = 0
        self.round = -1
        self.heard: set[int] = set()
        self.expected: set[int] = set()
        self.averaged_with: list[int] = []
        #: the last exchange's neighbours not averaged with, each with why
        #: (:data:`NOT_AVERAGED`)
        self.not_averaged: dict[int, str] = {}
        self.spent = 0.0
        # association by the robots themselves: one correspondence table per link
        association = agent.config.association
        self.association = association.mode
        self.association_interval = int(association.interval)
        # summaries before the interval of the objects new to a link (lock-step only: both
        # ends then hold the same maps of each other, the last whole summaries with the
        # partial ones since)
        self.sooner = int(association.sooner) if self.max_age == 0 else 0
        #: per link: our map as the neighbour holds it / its map as we hold it
        self._given: dict[int, ObjectSummary] = {}
        self._held: dict[int, ObjectSummary] = {}
        self.tables: dict[int, CorrespondenceTable] = {}
        if self.association == "own":
            matching = association.matching()
            self.tables = {
                j: CorrespondenceTable(self.robot, j, matching) for j in sorted(self.neighbours)
            }
        # the persistent map in consensus (consensus.persistent_map): its objects are asked for
        # and averaged object by object with the neighbours' in-state marginals, never sent —
        # with the plain average, lock-step, moved flags (kl_threshold > 0), the paper's set
        # and global ids
        self.persistent = (
            settings.persistent_map
            and self.rule.name == "average"
            and self.max_age == 0
            and self.kl_threshold > 0
            and not self.bounded
            and self.association != "own"
        )
        check = self.association == "own" or settings.innovation_check
        self.innovation_probability = association.revoke_probability if check else None
        self._summary: ObjectSummary | None = None
        #: per link: the histogram of appearance distances of the pairs it holds (the *same*
        #: samples this robot's summaries carry to its other neighbours)
        self._same: dict[int, np.ndarray] = {}
        self._sent: dict[int, ObjectSummary | None] = {}  # this step's summary, per neighbour
        self._associated: dict[int, int] = {}  # aged by stamp: the last summary step associated
        #: per link: summaries sent and their bytes, full associations, extensions, seconds
        #: spent associating, objects left out of an average by the innovation test
        self.link_stats: dict[int, dict[str, float]] = {
            j: {
                "summaries_sent": 0,
                "summary_bytes": 0,
                "full_associations": 0,
                "extensions": 0,
                "association_seconds": 0.0,
                "excluded": 0,
            }
            for j in sorted(self.neighbours)
        }

    # ------------------------------------------------------------------ checks
    @contextmanager
    def _named(self) -> Iterator[None]:
        """Errors of a consensus round name this robot and the frame (the step)."""
        try:
            yield
        except (EstimationError, InternalError, InputError) as exc:
            where = f"robot {self.robot}, frame {self.step}"
            if str(exc).startswith(where):
                raise
            try:  # the same kind of error, now naming robot and frame
                named = type(exc)(f"{where}: consensus: {exc}")
            except TypeError:  # a subclass with another signature: its base kind
                base = next(
                    k for k in (EstimationError, InternalError, InputError) if isinstance(exc, k)
                )
                named = base(f"{where}: consensus: {exc}")
            raise named from exc

    def _stale(self, sender: int, kind: type) -> bool:
        """Whether ``sender``'s newest ``kind`` message arrived but is too old for this exchange
        (known with :attr:`lags` only: asynchronous robots)."""
        if self.lags is None:
            return False
        age = MessageAge(self.round, self.max_age, self.stamp_ns, self.max_age_ns, self.lags)
        return self.lags.stale(sender, kind, age)

    def _check(self, message: object, kind: type, taken: dict, heard: set | None = None):
        """The message's usable content (:func:`~teamslam.msckf.consensus.checks.check_message`),
        or ``None``: ignored (a second message of a sender in ``taken``) or rejected (counted on
        the agent with its reason)."""
        problem, usable = check_message(
            message,
            kind,
            self.round,
            self.max_age,
            self.robot,
            self.neighbours,
            self.agent.state,
            self.agent.config.consensus.per_object,
            taken.keys(),
            heard,
            self.stamp_ns,
            self.max_age_ns,
            self.persistent,
            self.lags,
        )
        if problem is not None:
            self.agent.reject("messages", reason=problem)
        return usable

    # ------------------------------------------------------------------ rounds
    def exchange(self, step: int, iteration: int = 0) -> int:
        """The number the messages of exchange ``iteration`` of ``step`` carry (and the links
        and mailboxes go by): ``step · L + iteration`` with ``L`` exchanges per step — the step
        itself when ``L = 1``."""
        if not 0 <= iteration < self.iterations:
            raise InternalError(
                f"exchange {iteration} of a step with {self.iterations} consensus iterations"
            )
        return int(step) * self.iterations + int(iteration)

    def requests(
        self,
        step: int,
        to: Iterable[int] | None = None,
        iteration: int = 0,
        stamp_ns: int | None = None,
        max_age_ns: int | None = None,
        lags: MessageLags | None = None,
    ) -> list[MapIdsMessage]:
        """Round 1 of exchange ``iteration`` of ``step``: our map ids (and which moved) for
        each neighbour in ``to``.

        ``stamp_ns`` is the stamp of the frame the exchange is at; every message of the
        exchange carries it. With ``max_age_ns`` (asynchronous robots that drop frames, whose
        steps are not comparable) the neighbours' messages are aged by their stamps, not their
        steps (:class:`~teamslam.msckf.consensus.messages.MessageAge`), up to the limits
        ``lags`` learned per neighbour when given
        (:class:`~teamslam.msckf.consensus.messages.MessageLags`).

        Raises
        ------
        EstimationError
            A marginal of ours that is not positive definite; robot and frame are named.
        """
        if max_age_ns is not None and stamp_ns is None:
            raise InternalError("ageing messages by stamp needs the frame's stamp")
        self.step = int(step)
        self.iteration = int(iteration)
        self.round = self.exchange(step, iteration)
        self.stamp_ns = None if stamp_ns is None else int(stamp_ns)
        self.max_age_ns = None if max_age_ns is None else int(max_age_ns)
        self.lags = lags
        with self._named():
            return self._requests(to)

    def _requests(self, to: Iterable[int] | None) -> list[MapIdsMessage]:
        begin = time.perf_counter()
        self.heard = set()
        self.expected = set()
        self.averaged_with = []
        self.not_averaged = {}
        self._moved = {}
        self._pending = {}
        self._own_information = {}
        order = np.argsort(self.agent.state.object_ids)
        ids = self.agent.state.object_ids[order]  # increasing, as messages carry them
        exchange = (
            self.association == "own"
            and self.iteration == 0
            and self.step % self.association_interval == 0
        )
        sooner = (
            self.association == "own" and self.iteration == 0 and not exchange and self._partial()
        )
        if self.kl_threshold > 0 or exchange or sooner or self.bounded:
            means, covs = object_marginals(self.agent.state)
        if self.kl_threshold > 0 or self.bounded:
            self._own = (ids, means[order], covs[order])
        else:
            self._own = None
        if self.bounded:
            self._thresholds = self._object_thresholds(covs)[order]
        if self._with_persistent_map():
            ids = self._own[0]
        targets = sorted(self.neighbours if to is None else set(to) & self.neighbours)
        new = self._new_to(targets, ids) if sooner else {}
        self._summary = None
        if exchange or new:
            wanted = np.unique(np.concatenate(list(new.values()))) if new else ids
            keep = np.isin(ids, wanted)
            self._summary = self._object_summary(ids[keep], means[order][keep], covs[order][keep])
        out = []
        self._sent = {}
        for j in targets:
            moved = self._moved_for(j)
            summary = self._summary_for(j)
            if sooner:
                summary = summary.select(new[j]) if j in new else None
            self._sent[j] = summary
            out.append(MapIdsMessage(self.robot, j, self.round, ids, moved, summary, self.stamp_ns))
            if summary is not None:
                self.link_stats[j]["summaries_sent"] += 1
                self.link_stats[j]["summary_bytes"] += summary_wire_bytes(summary, ids.size)
                if self._partial():
                    self._given[j] = self._joined(self._given.get(j), summary, ids.size)
        self.spent = time.perf_counter() - begin
        return out

    def _partial(self) -> bool:
        """Whether summaries go out before the interval (:attr:`sooner`; robots in lock-step,
        not aged by stamp)."""
        return self.sooner > 0 and self.max_age_ns is None

    def _new_to(self, targets: list[int], ids: np.ndarray) -> dict[int, np.ndarray]:
        """Per neighbour of ``targets`` to send a summary before the interval: our ``ids`` its
        link does not hold yet (not in our summaries since the last whole one), when at least
        :attr:`sooner` of them."""
        new = {}
        for j in targets:
            given = self._given.get(j)
            fresh = ids if given is None else ids[~np.isin(ids, given.ids)]
            if fresh.size >= self.sooner:
                new[j] = fresh
        return new

    @staticmethod
    def _joined(held: ObjectSummary | None, summary: ObjectSummary, n_ids: int) -> ObjectSummary:
        """A map as a link holds it after ``summary`` (of a message of ``n_ids`` ids): a whole
        summary replaces it, a partial one adds its objects."""
        if held is None or len(summary) == n_ids:
            return summary
        return held.updated(summary)

    def _object_summary(
        self, ids: np.ndarray, means: np.ndarray, covs: np.ndarray
    ) -> ObjectSummary:
        """Our object summary of ``ids`` (increasing) with their marginals ``means``, ``covs``."""
        return ObjectSummary(
            self.robot,
            ids,
            means,
            covs,
            classes=self._classes(ids),
            views=self.agent.views.of(ids),
            appearance=self._appearance(ids),
        )

    def _classes(self, ids: np.ndarray) -> np.ndarray | None:
        """``(n,)`` the class of each of our objects ``ids`` — the label its detections voted
        for (``-1``: none yet) — where the robot tracks detections that carry classes, else
        ``None`` (the association then matches without classes)."""
        tracker = self.agent.tracker
        detections = self.agent.sequence.detections
        if tracker is None or detections is None or detections.classes is None:
            return None
        return tracker.labels_of(ids)

    def _summary_now(self, j: int) -> ObjectSummary:
        """Our summary of this step for link ``j``, made now: robots aged by stamp drop frames,
        so a neighbour's summary step is not ours — we answer its summary with our own."""
        if self._summary is None:
            state = self.agent.state
            order = np.argsort(state.object_ids)
            means, covs = object_marginals(state)
            self._summary = self._object_summary(state.object_ids[order], means[order], covs[order])
        summary = self._sent[j] = self._summary_for(j)
        return summary

    def _with_persistent_map(self) -> bool:
        """With the persistent map in consensus and objects in it: add them to our marginals
        of this exchange (``_own``, ids increasing); whether there were any."""
        retired = self.agent.state.retired
        if not self.persistent or len(retired) == 0:
            return False
        stored = retired.arrays()
        ids, means, covs = self._own
        ids = np.concatenate([ids, stored["ids"]])
        order = np.argsort(ids, kind="stable")
        self._own = (
            ids[order],
            np.concatenate([means, stored["means"]])[order],
            np.concatenate([covs, stored["covs"]])[order],
        )
        return True

    def _appearance(self, ids: np.ndarray) -> np.ndarray | None:
        """``(n, D)`` the appearance descriptors of our objects ``ids`` (zero rows: none), or
        ``None``: the tracker's summaries where the robot tracks its detections, else the
        dataset's per-object descriptors."""
        tracker = self.agent.tracker
        if tracker is not None:
            if tracker.memory is None:
                return None
            return tracker.memory.summaries(ids)
        return self.agent.sequence.appearance_of_objects(ids)

    def _summary_for(self, j: int) -> ObjectSummary | None:
        """Our summary of this step as sent to ``j``: with appearance, the *same* samples of
        our other links and of our tracker (``j``'s own link adds its held pairs itself)."""
        summary = self._summary
        if summary is None or summary.appearance is None:
            return summary
        counts = np.zeros(BINS, np.int64)
        for k, same in self._same.items():
            if k != j:
                counts += same
        tracker = self.agent.tracker
        if tracker is not None and tracker.appearance is not None:
            counts += tracker.appearance.same.astype(np.int64)
        return replace(summary, same_counts=counts)

    def _held_counts(self, j: int, own: ObjectSummary, theirs: ObjectSummary) -> None:
        """Record the appearance distances of the pairs link ``j`` holds."""
        if own.appearance is None or theirs.appearance is None:
            return
        if own.appearance.shape[1] != theirs.appearance.shape[1]:
            return
        pairs = self.tables[j].pairs()
        index_own = {int(i): k for k, i in enumerate(own.ids)}
        index_their = {int(i): k for k, i in enumerate(theirs.ids)}
        both = [
            (index_own[int(a)], index_their[int(b)])
            for a, b in pairs
            if int(a) in index_own and int(b) in index_their
        ]
        if not both:
            self._same[j] = np.zeros(BINS, np.int64)
            return
        ia, ib = (np.array(v) for v in zip(*both, strict=True))
        ok = np.any(own.appearance[ia] != 0, axis=1) & np.any(theirs.appearance[ib] != 0, axis=1)
        d = cosine_distances(own.appearance[ia[ok]], theirs.appearance[ib[ok]])
        self._same[j] = distance_counts(np.diagonal(d))

    def _moved_for(self, j: int) -> np.ndarray | None:
        """Which of our objects moved since we last exchanged them with ``j`` (``None``: all).

        The first call of a step computes the flags for every neighbour, in one batched
        Kullback–Leibler evaluation.
        """
        if self._own is None:
            return None
        if j not in self._moved:
            self._moved.update(self._moved_all())
        return self._moved.get(j, np.ones(self._own[0].size, dtype=bool))

    def _moved_all(self) -> dict[int, np.ndarray]:
        """:meth:`_moved_for` of every neighbour (all flags set where nothing is on record)."""
        ids, means, covs = self._own
        out = {j: np.ones(ids.size, dtype=bool) for j in self.neighbours | set(self._agreed)}
        if ids.size == 0:
            return out
        order = np.argsort(ids)
        sorted_ids = ids[order]
        pairs = []  # per neighbour: our slots, its record's slots
        for j, (a_ids, *_) in self._agreed.items():
            if a_ids.size == 0:
                continue
            # a_ids is sorted: where each of our ids sits in j's record
            pos = np.minimum(np.searchsorted(a_ids, sorted_ids), a_ids.size - 1)
            known = a_ids[pos] == sorted_ids
            if known.any():
                pairs.append((j, order[known], pos[known]))
        if not pairs:
            return out
        kl = kl_divergence(
            means[np.concatenate([mine for _, mine, _ in pairs])],
            covs[np.concatenate([mine for _, mine, _ in pairs])],
            np.concatenate([self._agreed[j][1][theirs] for j, _, theirs in pairs]),
            np.concatenate([self._agreed[j][2][theirs] for j, _, theirs in pairs]),
        )
        split = np.cumsum([mine.size for _, mine, _ in pairs])[:-1]
        for (j, mine, theirs), kl_j in zip(pairs, np.split(kl, split), strict=True):
            if self._thresholds is None:
                limit = self.kl_threshold
            else:  # an average once started runs to agreement (consensus.set)
                limit = settling_thresholds(
                    self._thresholds[mine],
                    self._agreed[j][3][theirs],
                    self.round,
                    self.kl_threshold,
                )
            out[j][mine] = kl_j > limit
        return out

    def _object_thresholds(self, covs: np.ndarray) -> np.ndarray:
        """Per object (state slot order): how far its marginal must move (KL, nats) to be
        averaged again — ``consensus.kl_threshold`` when active (``-inf`` for 0: always),
        ``consensus.inactive_kl_threshold`` otherwise."""
        settings = self.agent.config.consensus
        active = active_objects(self.agent.state, covs, settings.active_information)
        if self.iteration == 0:  # the set of a step, counted once however many exchanges
            self.agent.counters["objects_inactive"] += int(active.size - active.sum())
        active_threshold = self.kl_threshold if self.kl_threshold > 0 else -np.inf
        inactive = max(float(settings.inactive_kl_threshold), self.kl_threshold)
        return np.where(active, active_threshold, inactive)

    def answer(self, received: Sequence[Message]) -> list[CommonMarginalMessage]:
        """Round 2: our marginal of the common objects to average with each requester.

        Those are the objects we share that moved on either side (all we share with a
        threshold of 0). Records who was heard (our degree this step) and whose marginal to
        expect back.

        Raises
        ------
        EstimationError
            A marginal of ours that is not positive definite; robot and frame are named.
        """
        with self._named():
            return self._answer(received)

    def _answer(self, received: Sequence[Message]) -> list[CommonMarginalMessage]:
        begin = time.perf_counter()
        requests = {}
        for m in received:
            if self._check(m, MapIdsMessage, requests) is not None:
                requests[m.sender] = m
        self.heard = set(requests)
        replies = []
        own = np.sort(self.agent.state.object_ids)  # a retired object is asked for, not sent
        for j in sorted(requests):
            their_ids = np.asarray(requests[j].ids, dtype=np.int64)
            if self.tables:
                exchanged = requests[j].summary is not None or (
                    self._partial() and self._sent.get(j) is not None
                )
                if exchanged and not self._associate(j, requests[j]):
                    continue
                # their ids in ours: the pairs of the link's table (-1: not matched)
                ours = self.tables[j].ours(their_ids)
                matched = ours >= 0
                matched[matched] = _members(ours[matched], own)
            else:
                ours, matched = their_ids, _members(their_ids, own)
            # ours ∩ theirs, flagged by either side: masks over their (increasing) ids
            shared = matched
            mine_moved = self._moved_for(j)
            theirs_moved = requests[j].moved
            if mine_moved is not None and theirs_moved is not None:
                # the flags refer to our map as it was in round 1
                shared &= np.asarray(theirs_moved, dtype=bool) | (
                    matched & _members(ours, self._own[0][mine_moved])
                )
            share = np.sort(ours[shared]) if self.tables else their_ids[shared]
            if share.size == 0:
                continue
            self._pending[j] = share
            self.expected.add(j)
        source = None
        if self._pending:
            source = self.rule.sent_marginal(
                self.agent.state,
                np.unique(np.concatenate(list(self._pending.values()))),
                len(self.heard),
                self._prior,
                self.agent.counters,
            )
        settings = self.agent.config.consensus
        self._own_information = {}
        for j, share in self._pending.items():
            reply = common_marginal_message(
                self.agent.state,
                self.robot,
                j,
                self.round,
                share,
                len(self.heard),
                per_object=settings.per_object,
                float32=settings.float32,
                source=source,
                information=not settings.per_object,
                keep=self._own_information if source is None else None,
                prior=self.rule.message_prior(self._prior),
                directions=self.moved,
            )
            if reply is not None and self.stamp_ns is not None:
                reply = replace(reply, stamp_ns=self.stamp_ns)
            replies.append(reply)
        self.spent += time.perf_counter() - begin
        return replies

    def _associate(self, j: int, request: MapIdsMessage) -> bool:
        """Update the table of link ``j`` with both summaries of this step (``False``: the
        neighbour's summary was rejected)."""
        theirs = request.summary
        request_ids = np.asarray(request.ids, dtype=np.int64)
        if theirs is not None:
            if not isinstance(theirs, ObjectSummary) or theirs.robot != j:
                self.agent.reject(
                    "messages", reason=f"object summary of robot {j} names another robot"
                )
                return False
            whole = np.array_equal(theirs.ids, request_ids)
            some = (
                self._partial()
                and np.all(theirs.ids[1:] > theirs.ids[:-1])
                and bool(np.isin(theirs.ids, request_ids).all())
            )
            if not (whole or some):
                self.agent.reject(
                    "messages", reason=f"object summary of robot {j} disagrees with its ids"
                )
                return False
        if self._partial():
            # both ends associate the maps as the link holds them: the last whole summaries
            # with the partial ones since (the same two on both ends when none was lost)
            if theirs is not None:
                self._held[j] = self._joined(self._held.get(j), theirs, request_ids.size)
            if j not in self._given or j not in self._held:
                return True
            # a full association only on the whole summaries of the interval's steps: in
            # between, the objects new to the link extend its table
            tick = self.step % self.association_interval == 0
            return self._associated_maps(j, self._given[j], self._held[j], full=tick)
        own = self._sent[j] if j in self._sent else self._summary_for(j)
        if self.max_age_ns is not None:
            # aged by stamp: the same newest request may come back in later steps, and its
            # summary step is the neighbour's own — associate each summary once, with ours now
            if self._associated.get(j) == request.step:
                return True
            self._associated[j] = request.step
            if own is None:
                own = self._summary_now(j)
        if own is None:  # we did not exchange summaries this step (a neighbour out of phase)
            return True
        return self._associated_maps(j, own, theirs)

    def _associated_maps(
        self, j: int, own: ObjectSummary, theirs: ObjectSummary, full: bool = True
    ) -> bool:
        """Run link ``j``'s association on the two maps' summaries ``own``, ``theirs``: a
        full one when its table is due (and ``full``), else an extension."""
        begin = time.perf_counter()
        table = self.tables[j]
        stats = self.link_stats[j]
        table.revoke_other_classes(own, theirs, self.step)
        if full and table.due(len(own), len(theirs)):
            held = table.pairs() if own.appearance is not None else None
            result = associate(own, theirs, table.current_settings(), held, table.history)
            if table.learn_frame(result, own, theirs):
                # the answer showed the maps further apart than their covariances say: once
                # more with the shared frame's scale learned from it
                result = associate(own, theirs, table.current_settings(), held, table.history)
                stats["full_associations"] += 1
            table.merge(result, own, theirs, self.step)
            stats["full_associations"] += 1
        else:
            table.extend(own, theirs, self.step)
            stats["extensions"] += 1
        self._held_counts(j, own, theirs)
        stats["association_seconds"] += time.perf_counter() - begin
        return True

    def _translate(self, message: CommonMarginalMessage) -> CommonMarginalMessage | None:
        """A neighbour's marginal in our own ids: blocks reordered to increasing own ids, the
        objects of pairs we do not hold marginalised out (``None``: rejected, or no object of
        ours in it)."""
        table = self.tables.get(message.sender)
        if table is None or message.receiver != self.robot:
            return message  # the one check rejects it, naming why
        ids = np.asarray(message.ids)
        k = ids.size
        per_object = message.info is None and np.ndim(message.cov) == 3
        shape = (k, 3, 3) if per_object else (3 * k, 3 * k)
        if (
            ids.ndim != 1
            or k == 0
            or ids.dtype.kind not in "iu"
            or np.any(ids[1:] <= ids[:-1])
            or np.shape(message.mean) != (3 * k,)
            or np.shape(message.matrix) != shape
        ):
            self.agent.reject("messages", reason="marginal ids or sizes malformed")
            return None
        ours = table.ours(ids)
        keep = np.flatnonzero(ours >= 0)
        if keep.size == 0:
            self.agent.reject(
                "messages", reason=f"no object of robot {message.sender}'s marginal is matched"
            )
            return None
        keep = keep[np.argsort(ours[keep], kind="stable")]
        coords = (3 * keep[:, None] + np.arange(3)).ravel()
        mean = np.asarray(message.mean)[coords]
        matrix = np.asarray(message.matrix)
        if per_object:
            return replace(message, ids=ours[keep], mean=mean, cov=matrix[keep])
        if keep.size == k or message.info is None:
            sub = matrix[np.ix_(coords, coords)]
            if message.info is None:
                return replace(message, ids=ours[keep], mean=mean, cov=sub)
            return replace(
                message, ids=ours[keep], mean=mean, info=sub, **_reordered_prior(message, keep)
            )
        # marginalise in moment form; a prior (consensus on increments) is left out: the
        # marginal then counts as a prior only
        message = replace(message, prior_held=None, prior_mean=None, prior_info=None)
        try:
            cov = spd_inverse(matrix, "information matrix")
        except (NotPositiveDefiniteError, np.linalg.LinAlgError, ValueError):
            self.agent.reject("messages", reason="information matrix is not positive definite")
            return None
        return replace(
            message, ids=ours[keep], mean=mean, cov=cov[np.ix_(coords, coords)], info=None
        )

    def _innovation_check(self, marginal: ReceivedMarginal) -> ReceivedMarginal | None:
        """The marginal checked by the ``χ²₃`` test of each object's consensus innovation.

        With own association: the quantile times the link's learned frame scale
        (:attr:`~teamslam.association.CorrespondenceTable.frame_scale`: the maps' disagreement
        against their covariances, which the link's association gate already allows; on noisy
        odometry the plain test revoked right pairs by the tens), and without the objects that
        fail (revoked from the link's table);
        with oracle ids: whole, unless most of its objects fail (then ``None``: the sender is
        not averaged this step). ``None`` also when no object is left."""
        ids = marginal.ids
        k = ids.size
        if k == 0:  # only objects of our persistent map
            return marginal
        try:
            cov = spd_inverse(marginal.info, "information matrix")
        except (NotPositiveDefiniteError, np.linalg.LinAlgError):
            self.agent.reject("messages", reason="information matrix is not positive definite")
            return None
        mean = cov @ marginal.info_vector
        index = 3 * np.arange(k)[:, None] + np.arange(3)
        blocks = cov[index[:, :, None], index[:, None, :]]
        state = self.agent.state
        slots = state.object_slots(ids)
        own_covs = state.covariance(state.object(slots))[index[:, :, None], index[:, None, :]]
        j = marginal.sender
        table = self.tables.get(j)
        ok = pair_innovation_consistent(
            state.objects[slots],
            own_covs,
            mean.reshape(k, 3),
            blocks,
            probability=self.innovation_probability,
            scale=1.0 if table is None else table.frame_scale,
        )
        if ok.all():
            return marginal
        failed = ids[~ok]
        self.agent.counters["consensus_innovation_failures"] += int(failed.size)
        if table is None:  # oracle ids: judge the sender by the majority of its objects
            if 2 * int(failed.size) <= k:
                return marginal
            self.link_stats[j]["excluded"] += k
            self.agent.counters["consensus_marginals_left_out"] += 1
            return None
        self.link_stats[j]["excluded"] += int(failed.size)
        if table is not None:
            for own_id, their_id in zip(failed, table.theirs(failed), strict=True):
                table.revoke(int(own_id), int(their_id), self.step)
        if not ok.any():
            return None
        coords = index[ok].ravel()
        sub = cov[np.ix_(coords, coords)]
        info = spd_inverse(sub, "marginal covariance")
        return ReceivedMarginal(
            j, ids[ok], info, info @ mean[coords], marginal.per_object, retired=marginal.retired
        )

    def association_summary(self) -> dict:
        """Per link (neighbour id as a string): the table's pairs and counts and the exchange
        statistics (empty with oracle ids: the innovation check's marginals left out are the
        agent's ``consensus_marginals_left_out`` counter)."""
        if not self.tables:
            return {}
        out = {}
        for j, stats in self.link_stats.items():
            entry = {
                k: (float(v) if k == "association_seconds" else int(v)) for k, v in stats.items()
            }
            table = self.tables.get(j)
            if table is not None:
                entry.update(table.counts())
                entry["pairs"] = table.pairs().tolist()
            out[str(j)] = entry
        return out

    def weights(self, degrees: dict[int, int]) -> tuple[float, dict[int, float]]:
        """``(A_ii, {j: A_ij})`` for the neighbours heard, given each one's degree."""
        mine = len(self.heard)
        out = {j: metropolis_weight(mine, degrees.get(j, mine)) for j in sorted(self.heard)}
        return 1.0 - sum(out.values()), out

    def average(self, received: Sequence[Message]) -> int:
        """Validate the neighbours' marginals and average the common objects (eq. 19, Prop. 2).

        Returns the number of objects averaged; adds it to the agent's ``objects_averaged``
        counter and the time spent this step to its ``consensus`` timing.

        Raises
        ------
        EstimationError
            The average or the rebuilt joint is not positive definite (or not finite); robot
            and frame are named and the state is left as it was.
        InternalError
            A broken invariant of the average (weights, mixed message kinds); robot and frame
            are named.
        """
        with self._named():
            return self._average(received)

    def _average(self, received: Sequence[Message]) -> int:
        begin = time.perf_counter()
        marginals: dict[int, ReceivedMarginal] = {}
        degrees: dict[int, int] = {}
        refused: set[int] = set()
        inconsistent: set[int] = set()
        for m in received:
            sender = getattr(m, "sender", None)
            if self.tables and isinstance(m, CommonMarginalMessage):
                m = self._translate(m)
                if m is None:
                    refused.add(sender)
                    continue
            # asynchronous mode: a marginal from a neighbour whose ids we did not hear this
            # step still counts as heard (the link works)
            marginal = self._check(m, CommonMarginalMessage, marginals, self.heard)
            if marginal is None:
                refused.add(sender)
                continue
            if self.innovation_probability is not None:
                marginal = self._innovation_check(marginal)
                if marginal is None:
                    inconsistent.add(sender)
                    continue
            if self.moved:
                marginal = at_first_estimates(self.agent.state, marginal)
            marginals[m.sender] = marginal
            degrees[m.sender] = int(m.degree)
        self_weight, weights = self.weights(degrees)
        self.averaged_with = sorted(marginals)
        self.not_averaged = {
            j: _why_not_averaged(j, refused, inconsistent, self.heard, self.expected, self._stale)
            for j in sorted(self.neighbours - set(marginals))
        }
        used = [(weights[j], marginals[j]) for j in sorted(marginals) if marginals[j].ids.size]
        averaged = self.rule.average(
            self.agent.state,
            self_weight,
            used,
            self._prior,
            self.agent.counters,
            self._own_information,
            self.directions,
        )
        self._own_information = {}  # the state has moved
        if self.persistent:
            stored = persistent_average(
                self.agent.state, [(weights[j], marginals[j].retired) for j in marginals]
            )
            if stored:
                self.agent.counters["retired_averaged"] += stored
        self._prior = self.rule.next_prior(
            self.agent.state, self._prior, bool(self.expected or averaged)
        )
        if self._own is not None:
            for j in marginals:
                exchanged = self._pending.get(j)
                retired = marginals[j].retired if self.persistent else None
                if retired is not None and retired[0].size:
                    # retired objects the neighbour sent: on record too, so that they are asked
                    # for again only once they moved on either side, as the state's objects
                    exchanged = (
                        retired[0]
                        if exchanged is None
                        else np.union1d(exchanged, retired[0]).astype(np.int64)
                    )
                if exchanged is not None:
                    self._record_exchange(j, exchanged)
        self.agent.counters["objects_averaged"] += averaged
        self.spent += time.perf_counter() - begin
        self.agent.timings["consensus"] += self.spent
        return averaged

    def _record_exchange(self, j: int, exchanged: np.ndarray) -> None:
        """Remember our pre-average marginals of the objects just exchanged with ``j`` (our ids,
        ``exchanged`` and the record are increasing; one compiled merge)."""
        ids, means, covs = self._own
        old = self._agreed.get(j)
        if old is None:
            old = (ids[:0], means[:0], covs[:0], np.zeros(0, dtype=np.int64))
        self._agreed[j] = merged_record(
            *old, ids, means, covs, np.asarray(exchanged, dtype=np.int64), self.round
        )


#: why a neighbour was not averaged with in an exchange: ``not_heard`` (no map ids of it
#: of an accepted age), ``too_old`` (asynchronous: its newest map ids, or its newest marginal
#: when its ids were heard, arrived but are older than accepted), ``nothing_common`` (heard,
#: but no object to average with it: none in common, or none that moved), ``no_marginal``
#: (objects to average, but no marginal of it of an accepted age arrived), ``refused`` (its
#: marginal failed the checks: counted in ``rejected_messages``), ``inconsistent`` (its
#: marginal failed the consensus innovation check)
NOT_AVERAGED = (
    "not_heard",
    "too_old",
    "nothing_common",
    "no_marginal",
    "refused",
    "inconsistent",
)


def _why_not_averaged(
    j: int,
    refused: set[int],
    inconsistent: set[int],
    heard: set[int],
    expected: set[int],
    stale: Callable[[int, type], bool],
) -> str:
    """The :data:`NOT_AVERAGED` reason of neighbour ``j`` in an exchange (``stale(j, kind)``:
    whether its newest ``kind`` message arrived but is too old)."""
    if j in refused:
        return "refused"
    if j in inconsistent:
        return "inconsistent"
    if j not in heard:
        return "too_old" if stale(j, MapIdsMessage) else "not_heard"
    if j not in expected:
        return "nothing_common"
    return "too_old" if stale(j, CommonMarginalMessage) else "no_marginal"


def _reordered_prior(message: CommonMarginalMessage, order: np.ndarray) -> dict:
    """The prior fields of a marginal message whose objects are taken in ``order`` (a
    permutation of its objects); empty without a prior."""
    if not message.has_prior:
        return {}
    held = np.asarray(message.prior_held, dtype=bool)
    if held.shape != order.shape:
        return {"prior_held": held[:0]}  # the one check rejects it, naming why
    rank = np.cumsum(held) - 1  # an object's place among the held ones
    taken = order[held[order]]
    coords = (3 * rank[taken][:, None] + np.arange(3)).ravel()
    return {
        "prior_held": held[order],
        "prior_mean": np.asarray(message.prior_mean)[coords],
        "prior_info": np.asarray(message.prior_info)[np.ix_(coords, coords)],
    }


def _members(values: np.ndarray, sorted_set: np.ndarray) -> np.ndarray:
    """``np.isin(values, sorted_set)`` for a sorted ``sorted_set`` without repeats."""
    if sorted_set.size == 0:
        return np.zeros(values.shape, dtype=bool)
    pos = np.minimum(np.searchsorted(sorted_set, values), sorted_set.size - 1)
    return sorted_set[pos] == values
