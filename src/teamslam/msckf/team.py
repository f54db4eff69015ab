"""The team driver: one robot's frame loop, the lock-step schedule of a team, one result.

Every way of running the filter goes through :class:`RobotDriver`: per frame, consensus
(``consensus.iterations`` exchanges: requests, answers, average) over a
:class:`~teamslam.msckf.consensus.transport.Transport`, then the filter step and the record of
the filtered pose. Waiting follows :class:`LockStep` or :class:`Asynchronous`; a neighbour
silent for ``lost_after`` frames is reported lost. :func:`run_lockstep` runs a team in one
process phase by phase (all requests before any answer, all answers before any average, every
step before any record); :func:`run_team` runs it over a memory network with link losses.
:func:`assemble_result` builds the one :class:`TeamResult`; :func:`save_result`,
:func:`load_result` and :func:`merge_results` write, read and join results.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections import defaultdict
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from teamslam.datasets.model import TeamDataset
from teamslam.errors import EstimationError, InputError, InternalError, OutputError
from teamslam.graph import CommunicationGraph, EdgeLoss, complete
from teamslam.msckf.agent import MsckfAgent, grown
from teamslam.msckf.consensus.messages import CommonMarginalMessage, MapIdsMessage, MessageLags
from teamslam.msckf.consensus.protocol import NOT_AVERAGED, ConsensusProtocol
from teamslam.msckf.consensus.transport import MemoryNetwork, Transport
from teamslam.msckf.filter.linearization import GroundTruth
from teamslam.msckf.settings.health import SensorHealth
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.textio import read_npz

__all__ = [
    "Asynchronous",
    "LockStep",
    "PartialRunError",
    "RobotDriver",
    "TeamResult",
    "assemble_result",
    "compilations",
    "exchanges_per_frame",
    "load_result",
    "merge_results",
    "run_drivers",
    "run_lockstep",
    "run_team",
    "save_result",
    "write_atomic",
]

#: Per-robot arrays of a :class:`TeamResult` as :func:`save_result` names them.
ARRAYS = ("poses", "pose_covs", "object_ids", "objects", "object_covs", "frame_times")
#: The other fields of a :class:`TeamResult`, in ``result.json``.
FIELDS = (
    "robots",
    "counters",
    "timings",
    "consensus",
    "graph",
    "loss",
    "wall_seconds",
    "extra",
    "health",
    "sensor_health",
    "complete",
)


@dataclass
class TeamResult:
    """Per-robot estimates and what it cost.

    Attributes
    ----------
    poses
        Per robot ``(N_i + 1, 4, 4)`` filtered ``T_world_body`` of every frame (of the frames
        done, when the run stopped early).
    pose_covs
        Per robot ``(N_i + 1, 6, 6)`` covariance of that pose (right perturbation).
    object_ids, objects
        Per robot the final map: ids and ``(m, 3)`` positions.
    object_covs
        Per robot ``(m, 3, 3)`` marginal covariances of those positions (empty when unknown).
    counters
        Per robot counts (updates, rejected measurements, objects initialised, links lost, …)
        plus ``messages`` and ``bytes`` sent.
    timings
        Per robot seconds per stage (``consensus``, ``propagation``, ``update``,
        ``initialisation``).
    frame_times
        Per robot ``(N_i + 1, 4)`` seconds of each frame in those four stages.
    consensus
        Whether consensus ran.
    health
        Sensor health (:meth:`~teamslam.msckf.settings.health.SensorHealth.summary`): ``team`` over
        every robot, ``robots`` per robot.
    sensor_health
        Per robot :meth:`~teamslam.msckf.settings.health.SensorHealth.to_json`, to combine results
        computed apart (:func:`merge_results`).
    robots
        The robots' ids (default: ``0 … n − 1``).
    complete
        ``False`` when the run stopped early (the arrays hold the frames done).
    """

    poses: list[np.ndarray]
    pose_covs: list[np.ndarray]
    object_ids: list[np.ndarray]
    objects: list[np.ndarray]
    counters: list[dict[str, int]]
    timings: list[dict[str, float]]
    frame_times: list[np.ndarray]
    consensus: bool
    graph: str
    loss: float
    wall_seconds: float = 0.0
    extra: dict = field(default_factory=dict)
    health: dict = field(default_factory=dict)
    object_covs: list[np.ndarray] = field(default_factory=list)
    sensor_health: list[dict] = field(default_factory=list)
    robots: list[int] = field(default_factory=list)
    complete: bool = True


class PartialRunError(EstimationError):
    """The estimate failed mid-run; ``result`` holds what every robot computed before."""

    def __init__(self, cause: EstimationError, result: TeamResult) -> None:
        super().__init__(str(cause))
        self.result = result


@dataclass(frozen=True)
class LockStep:
    """Wait for this step's messages from every neighbour still awaited, up to ``timeout`` s."""

    timeout: float = 5.0
    max_age = 0  # only this step's messages are accepted


@dataclass(frozen=True)
class Asynchronous:
    """Never wait: use each neighbour's newest message no older than ``max_age`` steps.

    ``by_stamp``: for robots that drop frames (live), whose steps count the frames each
    processed and are not comparable between them, messages are aged by the stamp of the frame
    they were sent at instead — accepted back to ``max_age_s`` seconds before the current
    frame's stamp when it is given; by default each neighbour's messages up to the age learned
    from how late they arrive (the ``lag_quantile`` of their lags plus the neighbour's interval
    between messages, :class:`~teamslam.msckf.consensus.messages.MessageLags`), never less than
    ``max_age`` of the robot's steps (the sequence's ``step_interval_ns``: the mean stamp
    interval between the frames it processed — longer than the input's frame period when it
    drops frames, as ``max_age`` steps are). ``lag_quantile`` ``None``: that floor alone.
    """

    max_age: int = 3
    by_stamp: bool = False
    max_age_s: float | None = None
    lag_quantile: float | None = 0.95

    def __post_init__(self) -> None:
        if self.max_age_s is not None and not (np.isfinite(self.max_age_s) and self.max_age_s >= 0):
            raise InputError(f"max_age_s must be seconds ≥ 0, got {self.max_age_s}")
        if self.lag_quantile is not None and not 0.0 < self.lag_quantile < 1.0:
            raise InputError(f"the lag quantile must be in (0, 1), got {self.lag_quantile}")


class RobotDriver:
    """One robot's frame loop: consensus over a transport, the filter step, the record.

    Parameters
    ----------
    agent
        The robot's filter.
    transport
        Its endpoint (``None``: a robot that talks to nobody).
    neighbours
        The robots it may hear from; consensus runs when there is a transport and
        ``consensus`` is true.
    wait
        :class:`LockStep` or :class:`Asynchronous`.
    lost_after
        Silent frames in a row after which a neighbour is reported lost.
    consensus
        ``False``: the filter runs alone even with neighbours.
    """

    def __init__(
        self,
        agent: MsckfAgent,
        transport: Transport | None = None,
        neighbours: Sequence[int] = (),
        wait: LockStep | Asynchronous = LockStep(),
        lost_after: int = 3,
        consensus: bool = True,
    ) -> None:
        self.agent = agent
        self.transport = transport
        self.neighbours = {int(j) for j in neighbours}
        self.wait = wait
        self.lost_after = lost_after
        self.protocol = (
            ConsensusProtocol(agent, self.neighbours, max_age=wait.max_age)
            if consensus and transport is not None
            else None
        )
        agent.with_consensus = self.protocol is not None and bool(self.neighbours)
        self.by_stamp = isinstance(wait, Asynchronous) and wait.by_stamp
        #: asynchronous: the neighbours' messages seen, their lags and the age limits learned
        #: from them (aged by stamp without a fixed ``max_age_s``), those found too old
        self.lags: MessageLags | None = None
        if isinstance(wait, Asynchronous) and self.protocol is not None:
            learn = self.by_stamp and wait.max_age_s is None
            self.lags = MessageLags(wait.lag_quantile if learn else None)
        self._too_old = 0  # messages found too old so far, counted in messages_too_old
        if self.by_stamp and not hasattr(agent.sequence, "step_interval_ns"):
            raise InternalError("ageing messages by stamp needs a sequence with frame stamps")
        frames = agent.sequence.frames
        self.poses = np.zeros((frames, 4, 4))
        self.covs = np.zeros((frames, 6, 6))
        self.consensus_times = np.zeros(frames)
        self.done = 0  # frames recorded
        self.silent = dict.fromkeys(self.neighbours, 0)
        self._heard_first: set[int] = set(self.neighbours)
        self.lost_reported: set[int] = set()
        self.lost_steps: list[int] = []
        self.averaged_with: dict[int, list[int]] = defaultdict(list)
        #: (frame, neighbour) pairs of the exchanges not averaged, by reason
        #: (:data:`~teamslam.msckf.consensus.protocol.NOT_AVERAGED`)
        self.not_averaged: dict[str, int] = dict.fromkeys(NOT_AVERAGED, 0)

    @property
    def frames(self) -> int:
        """Frames in the robot's sequence."""
        return self.agent.sequence.frames

    def exchanges(self, t: int) -> bool:
        """Whether the robot takes part in consensus at frame ``t``."""
        return t > 0 and self.protocol is not None

    @property
    def iterations(self) -> int:
        """Consensus exchanges per frame (``consensus.iterations``; 1 without consensus)."""
        return 1 if self.protocol is None else self.protocol.iterations

    @contextmanager
    def _named(self, t: int, stage: str) -> Iterator[None]:
        """A numerical failure of this robot at frame ``t`` (a linear-algebra error, a
        covariance that lost positive definiteness) becomes an :class:`EstimationError` naming
        the robot, the frame and ``stage``."""
        try:
            yield
        except (np.linalg.LinAlgError, FloatingPointError, EstimationError) as exc:
            where = f"robot {self.agent.robot}, frame {t}"
            if isinstance(exc, EstimationError) and str(exc).startswith(where):
                raise
            raise EstimationError(f"{where}: {stage}: {exc}") from exc

    # ------------------------------------------------------------------ consensus rounds
    def requests(self, t: int, iteration: int = 0) -> None:
        """Round 1 of exchange ``iteration``: send our map ids to every neighbour the transport
        can reach."""
        with self._named(t, "consensus"):
            self._requests(t, iteration)

    def answer(self, t: int, iteration: int = 0) -> None:
        """Round 2: take the neighbours' ids, answer each with our common marginal (a
        neighbour's silence is judged on a frame's first exchange)."""
        with self._named(t, "consensus"):
            self._answer(t, iteration)

    def average(self, t: int, iteration: int = 0) -> None:
        """Round 3: take the marginals we expect, average (eq. 19, Prop. 2)."""
        with self._named(t, "consensus"):
            self._average(t, iteration)

    def _requests(self, t: int, iteration: int) -> None:
        reachable = self.transport.reachable(self.protocol.exchange(t, iteration), self.neighbours)
        stamp_ns, max_age_ns = self._age(t)
        requests = self.protocol.requests(t, reachable, iteration, stamp_ns, max_age_ns, self.lags)
        for message in requests:
            self.transport.send(message)

    def _age(self, t: int) -> tuple[int | None, int | None]:
        """``(stamp_ns, max_age_ns)`` of frame ``t``'s exchanges: ``(None, None)`` when
        messages are aged by step."""
        if not self.by_stamp:
            return None, None
        sequence = self.agent.sequence
        if self.wait.max_age_s is not None:
            max_age_ns = round(self.wait.max_age_s * 1e9)
        else:
            max_age_ns = self.wait.max_age * sequence.step_interval_ns(t)
        return int(sequence.stamps_ns[t]), int(max_age_ns)

    def _newest(self, kind: type, t: int) -> list:
        """Asynchronous: each neighbour's newest ``kind`` message of the age accepted (those
        found too old are counted in the agent's ``messages_too_old``)."""
        protocol = self.protocol
        heard = self.transport.newest(
            kind,
            self.neighbours,
            self.wait.max_age,
            t,
            protocol.stamp_ns,
            protocol.max_age_ns,
            self.lags,
        )
        too_old = sum(self.lags.too_old.values())
        if too_old > self._too_old:
            self.agent.counters["messages_too_old"] += too_old - self._too_old
            self._too_old = too_old
        return heard

    def _answer(self, t: int, iteration: int) -> None:
        number = self.protocol.exchange(t, iteration)
        if isinstance(self.wait, LockStep):
            waiting = {j for j in self.neighbours if self.silent[j] < self.lost_after}
            if iteration > 0:  # a neighbour silent in the frame's first exchange is not awaited
                waiting &= self._heard_first
            heard = self.transport.collect(
                number, MapIdsMessage, waiting, self.wait.timeout, also=self.neighbours - waiting
            )
        else:
            heard = self._newest(MapIdsMessage, t)
        for reply in self.protocol.answer(heard):
            self.transport.send(reply)
        if iteration > 0:
            return
        self._heard_first = set(self.protocol.heard)
        for j in self.neighbours:
            self.silent[j] = 0 if j in self.protocol.heard else self.silent[j] + 1
            if self.silent[j] >= self.lost_after and j not in self.lost_reported:
                self.lost_reported.add(j)
                self.agent.counters["neighbours_lost"] += 1

    def _average(self, t: int, iteration: int) -> None:
        if isinstance(self.wait, LockStep):
            heard = self.transport.collect(
                self.protocol.exchange(t, iteration),
                CommonMarginalMessage,
                self.protocol.expected,
                self.wait.timeout,
            )
        else:
            heard = self._newest(CommonMarginalMessage, t)
        silent = self.neighbours - self.protocol.heard
        if silent:
            self.agent.counters["links_lost"] += len(silent)
            if not self.lost_steps or self.lost_steps[-1] != t:
                self.lost_steps.append(t)
        self.protocol.average(heard)
        for j in self.protocol.averaged_with:
            if not self.averaged_with[j] or self.averaged_with[j][-1] != t:
                self.averaged_with[j].append(t)
        for reason in self.protocol.not_averaged.values():
            self.not_averaged[reason] += 1
        self._room(t)
        self.consensus_times[t] += self.protocol.spent

    # ------------------------------------------------------------------ filter
    def step(self, t: int) -> None:
        """Process frame ``t`` (Algorithm 1, steps 2–4), after learning from this frame's
        association how overconfident the objects are
        (:meth:`~teamslam.msckf.agent.MsckfAgent.learn_overconfidence`)."""
        with self._named(t, "filter"):
            if self.protocol is not None and self.protocol.tables:
                self.agent.learn_overconfidence(self.protocol.tables)
            self.agent.step(t)

    def _room(self, t: int) -> None:
        """Room for frame ``t`` in the per-frame records (a sequence that grows while it runs:
        capacity doubled; a finished sequence's records are allocated whole up front)."""
        if t >= self.poses.shape[0]:
            self.poses = grown(self.poses, t + 1)
            self.covs = grown(self.covs, t + 1)
        if t >= self.consensus_times.shape[0]:
            self.consensus_times = grown(self.consensus_times, t + 1)

    def record(self, t: int) -> None:
        """Keep the filtered pose of frame ``t`` and its covariance."""
        self._room(t)
        with self._named(t, "filter"):
            self.poses[t] = self.agent.state.current_pose
            self.covs[t] = self.agent.state.current_pose_cov()
        self.done = t + 1

    def frame(self, t: int) -> None:
        """Everything of frame ``t`` for this robot alone (the robot process's loop body)."""
        if self.exchanges(t):
            for iteration in range(self.iterations):
                self.requests(t, iteration)
                self.answer(t, iteration)
                self.average(t, iteration)
        self.step(t)
        self.record(t)

    def restore(self, poses: np.ndarray, covs: np.ndarray) -> None:
        """Continue after the frames of a checkpoint (the agent restored already)."""
        self.done = poses.shape[0]
        self._room(self.done - 1)
        self.poses[: self.done] = poses
        self.covs[: self.done] = covs

    def summary(self) -> dict:
        """Lost neighbours, steps with lost links and with whom the robot averaged when (and,
        with association by the robots or the innovation check, the per-link association)."""
        out = {
            "lost_neighbours": sorted(self.lost_reported),
            "steps_with_lost_links": list(self.lost_steps),
            "averaged_with": {str(j): s for j, s in sorted(self.averaged_with.items())},
            "not_averaged": dict(self.not_averaged),
        }
        association = self.association()
        if association:
            out["association"] = association
        tracking = self.tracking()
        if tracking is not None:
            out["tracking_hypotheses"] = tracking
            out.update(self.tracking_record())
        return out

    def tracking(self) -> list[int] | None:
        """The id the robot's tracker gave each of its detections (``None`` without one)."""
        tracker = self.agent.tracker
        return None if tracker is None else tracker.hypotheses().tolist()

    def tracking_record(self) -> dict:
        """With a tracker: the ids as first given (``tracking_first_ids``), its merges
        (``tracking_merges``) and the box noise's overconfidence factor
        (``object_overconfidence``), for :func:`~teamslam.eval.tracking.merge_audit`."""
        tracker = self.agent.tracker
        if tracker is None:
            return {}
        return {
            "tracking_first_ids": tracker.first_ids().tolist(),
            "tracking_merges": tracker.merges().tolist(),
            "object_overconfidence": self.agent.overconfidence_factor,
        }

    def association(self) -> dict:
        """:meth:`~teamslam.msckf.consensus.protocol.ConsensusProtocol.association_summary` (empty
        without
        a protocol)."""
        return {} if self.protocol is None else self.protocol.association_summary()


def run_lockstep(
    drivers: Sequence[RobotDriver],
    before: Callable[[int, list[int]], None] | None = None,
    progress: bool | None = None,
) -> float:
    """Run every driver over its frames, phase by phase; the wall seconds it took.

    Parameters
    ----------
    drivers
        One per robot; a robot runs until its sequence ends.
    before
        Called as ``before(t, running)`` at the start of frame ``t`` with the robots still
        running (e.g. to draw this frame's link losses).
    progress
        Show a progress bar (default: when standard error is a terminal).

    Raises
    ------
    PartialRunError
        A robot's filter failed; the error carries the result of the frames done.
    """
    frames = [d.frames for d in drivers]
    show = sys.stderr.isatty() if progress is None else progress
    begin = time.perf_counter()
    with tqdm(total=max(frames), desc="frames", disable=not show, leave=False) as bar:
        for t in range(max(frames)):
            running = [i for i, f in enumerate(frames) if t < f]
            ended = {i for i, f in enumerate(frames) if f == t}
            for i in running:  # a robot whose sequence ended is no neighbour, not a lost link
                drivers[i].neighbours -= ended
            if before is not None:
                before(t, running)
            talking = [drivers[i] for i in running if drivers[i].exchanges(t)]
            for iteration in range(exchanges_per_frame(talking)):
                for phase in (RobotDriver.requests, RobotDriver.answer, RobotDriver.average):
                    for d in talking:
                        phase(d, t, iteration)
            for i in running:
                drivers[i].step(t)
            for i in running:  # after every robot's update of this frame
                drivers[i].record(t)
            bar.update()
    return time.perf_counter() - begin


def exchanges_per_frame(drivers: Sequence[RobotDriver]) -> int:
    """The consensus exchanges per frame of a team (``consensus.iterations``; 1 without
    consensus).

    Raises
    ------
    InputError
        Robots that exchange a different number of times per frame (their messages would
        never meet).
    """
    counts = {d.iterations for d in drivers if d.protocol is not None}
    if len(counts) > 1:
        raise InputError(
            f"every robot of a team needs the same consensus.iterations, not {sorted(counts)}"
        )
    return counts.pop() if counts else 1


def assemble_result(
    drivers: Sequence[RobotDriver],
    graph: str,
    loss: float,
    wall_seconds: float = 0.0,
    robots: Sequence[int] | None = None,
    maps: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
    complete: bool = True,
    consensus: bool | None = None,
) -> TeamResult:
    """The :class:`TeamResult` of a run from its drivers (after their last frame).

    Parameters
    ----------
    maps
        Per robot ``(ids, means, covs)`` of its final map (default: each agent's
        ``state.full_map()`` — in the state and retired, by id).
    complete
        ``False`` for the frames done of a run that stopped early (no odometry health of the
        window is added then).
    consensus
        Whether consensus ran (default: whether any driver has a protocol).
    """
    agents = [d.agent for d in drivers]
    if complete:
        for a in agents:
            a.flush_odometry_health()
    maps = [a.state.full_map() for a in agents] if maps is None else maps
    association = [d.association() for d in drivers]
    extra = {"association": association} if any(association) else {}
    tracking = [d.tracking() for d in drivers]
    if any(t is not None for t in tracking):
        extra["tracking_hypotheses"] = [[] if t is None else t for t in tracking]
        extra["tracking_records"] = [d.tracking_record() for d in drivers]
    counters = []
    for d in drivers:
        c = dict(d.agent.counters)
        c["messages"] = int(d.transport.messages_sent) if d.transport is not None else 0
        c["bytes"] = int(d.transport.bytes_sent) if d.transport is not None else 0
        counters.append(c)
    return TeamResult(
        poses=[d.poses[: d.done] for d in drivers],
        pose_covs=[d.covs[: d.done] for d in drivers],
        object_ids=[m[0] for m in maps],
        objects=[m[1] for m in maps],
        object_covs=[m[2] for m in maps],
        counters=counters,
        timings=[dict(a.timings) for a in agents],
        frame_times=[
            np.column_stack(
                [d.consensus_times[: d.done], np.array(d.agent.frame_times)[: d.done]]
            ).reshape(-1, 4)
            for d in drivers
        ],
        consensus=any(d.protocol is not None for d in drivers) if consensus is None else consensus,
        graph=graph,
        loss=loss,
        wall_seconds=wall_seconds,
        health={
            "team": SensorHealth.combine([a.health for a in agents]).summary(),
            "robots": [a.health.summary() for a in agents],
        },
        sensor_health=[a.health.to_json() for a in agents],
        robots=list(range(len(drivers)) if robots is None else robots),
        complete=complete,
        extra=extra,
    )


def merge_results(parts: Sequence[TeamResult], graph: str, loss: float) -> TeamResult:
    """One :class:`TeamResult` of robots whose results were computed apart (in order)."""
    per_robot = [(p, k) for p in parts for k in range(len(p.poses))]
    health = [SensorHealth.from_json(p.sensor_health[k]) for p, k in per_robot]
    return TeamResult(
        **{name: [getattr(p, name)[k] for p, k in per_robot] for name in ARRAYS},
        counters=[p.counters[k] for p, k in per_robot],
        timings=[p.timings[k] for p, k in per_robot],
        consensus=any(p.consensus for p in parts),
        graph=graph,
        loss=loss,
        wall_seconds=max((p.wall_seconds for p in parts), default=0.0),
        extra={"per_robot": [s for p in parts for s in p.extra.get("per_robot", [])]},
        health={
            "team": SensorHealth.combine(health).summary(),
            "robots": [h.summary() for h in health],
        },
        sensor_health=[p.sensor_health[k] for p, k in per_robot],
        robots=[(p.robots or list(range(len(p.poses))))[k] for p, k in per_robot],
        complete=all(p.complete for p in parts),
    )


RESULT_ARRAYS = "result.npz"
RESULT_JSON = "result.json"


def save_result(result: TeamResult, directory: str | Path) -> Path:
    """Write ``result.npz`` (per robot ``k``: ``robot_<k>_<array>``) and ``result.json``.

    Both are replaced atomically: a partial file never replaces a complete one.

    Raises
    ------
    OutputError
        The directory or a file cannot be written (named).
    """
    directory = Path(directory)
    arrays = {
        f"robot_{k}_{name}": np.asarray(getattr(result, name)[k])
        for name in ARRAYS
        for k in range(len(result.poses))
        if k < len(getattr(result, name))
    }
    payload = {name: getattr(result, name) for name in FIELDS}
    payload["robots"] = result.robots or list(range(len(result.poses)))
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot write {directory}: {exc.strerror or exc}") from exc
    write_atomic(directory / RESULT_ARRAYS, lambda tmp: np.savez_compressed(tmp, **arrays))
    text = json.dumps(payload, indent=1, sort_keys=True)
    write_atomic(directory / RESULT_JSON, lambda tmp: tmp.write_text(text))
    return directory


def write_atomic(path: Path, write: Callable[[Path], None]) -> None:
    """``write(tmp)`` a temporary file beside ``path``, then put it in its place: a partial file
    never replaces a complete one.

    Raises
    ------
    OutputError
        The file cannot be written (named).
    """
    tmp = path.with_name(f"{path.name}.tmp{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from exc


def load_result(directory: str | Path) -> TeamResult:
    """The :class:`TeamResult` :func:`save_result` wrote; a missing or malformed file raises
    :class:`~teamslam.errors.InputError` naming it."""
    directory = Path(directory)
    try:
        payload = json.loads((directory / RESULT_JSON).read_text())
        arrays = read_npz(directory / RESULT_ARRAYS)
    except (OSError, ValueError) as exc:
        raise InputError(f"{directory}: no readable result ({exc})") from None
    n = len(payload["robots"])
    try:
        per_robot = {
            name: [arrays[f"robot_{k}_{name}"] for k in range(n)]
            for name in ARRAYS
            if name != "object_covs"
        }
    except KeyError as exc:
        raise InputError(f"{directory / RESULT_ARRAYS}: lacks {exc.args[0]}") from None
    covs = [arrays.get(f"robot_{k}_object_covs") for k in range(n)]
    return TeamResult(
        **per_robot,
        object_covs=[] if any(c is None for c in covs) else covs,
        **{name: payload[name] for name in FIELDS},
    )


def run_drivers(
    drivers: Sequence[RobotDriver],
    graph: str,
    loss: float,
    before: Callable[[int, list[int]], None] | None = None,
    progress: bool | None = None,
    maps: Callable[[], list] | None = None,
) -> TeamResult:
    """:func:`run_lockstep` then :func:`assemble_result`; a failing filter raises
    :class:`PartialRunError` with the result of the frames every robot finished."""
    begin = time.perf_counter()
    compiled = np.array(compilations())
    try:
        wall = run_lockstep(drivers, before, progress)
    except EstimationError as exc:
        # the frame that failed: robots whose sequence had ended keep every frame
        failed = min(d.done for d in drivers if d.done < d.frames)
        for d in drivers:  # the frames every running robot finished
            d.done = min(d.done, failed)
        partial = assemble_result(
            drivers,
            graph,
            loss,
            time.perf_counter() - begin,
            maps=None if maps is None else maps(),
            complete=False,
        )
        raise PartialRunError(exc, partial) from exc
    result = assemble_result(drivers, graph, loss, wall, maps=None if maps is None else maps())
    # kernels compiled or loaded from the cache while the clock ran: a one-off cost of the
    # process, in the stage times
    result.extra["compilations"], result.extra["kernels_loaded"] = (
        np.array(compilations()) - compiled
    ).tolist()
    return result


def compilations() -> tuple[int, int]:
    """How many of teamslam's compiled kernels numba has, in this process so far, compiled
    (a signature not in its cache) and loaded from its cache (a kernel compiled inside
    another counts with it). Both are one-off costs of a process, paid by the run that
    first calls the kernel: compiling takes seconds, loading milliseconds."""
    compiled = loaded = 0
    seen = set()
    for name, module in list(sys.modules.items()):
        if not name.startswith("teamslam") or module is None:
            continue
        for value in list(vars(module).values()):
            stats = getattr(value, "stats", None)
            misses = getattr(stats, "cache_misses", None)
            if misses is None or not hasattr(value, "signatures") or id(value) in seen:
                continue
            seen.add(id(value))
            compiled += sum(misses.values())
            loaded += sum(stats.cache_hits.values())
    return compiled, loaded


def lockstep_drivers(
    dataset: TeamDataset,
    configs: Sequence[MsckfConfig],
    network,
    graph: CommunicationGraph,
    consensus: bool = True,
) -> list[RobotDriver]:
    """One lock-step driver per robot of ``dataset`` (ground truth for the ``ideal``
    linearisation), each on its endpoint of ``network`` (a
    :class:`~teamslam.msckf.consensus.transport.MemoryNetwork` or one like it), hearing its
    neighbours in ``graph``: what :func:`run_team` runs, for callers that bring their own
    network."""
    return [
        RobotDriver(
            MsckfAgent(i, dataset.calibration, r, c, truth=GroundTruth(r.T_world_body, dataset)),
            network.endpoint(i),
            graph.neighbours(i),
            LockStep(timeout=0.0),
            consensus=consensus,
        )
        for i, (r, c) in enumerate(zip(dataset.robots, configs, strict=True))
    ]


def run_team(
    dataset: TeamDataset,
    config: MsckfConfig | Sequence[MsckfConfig] | None = None,
    graph: CommunicationGraph | None = None,
    consensus: bool = True,
    loss: float = 0.0,
    seed: int = 0,
    progress: bool | None = None,
) -> TeamResult:
    """Run the distributed MSCKF (or separate MSCKFs) over a team dataset.

    Parameters
    ----------
    dataset
        The team's data.
    config
        Filter settings, one for the team or one per robot (default:
        :func:`~teamslam.msckf.configure.build_settings` — the dataset's sensor model, or a
        calibration from the data when it has none).
    graph
        Communication graph (default: complete).
    consensus
        ``False`` runs each robot's filter alone ("separate").
    loss
        Per-frame probability that a link is down.
    seed
        Seed of the link-loss draws.
    progress
        Show a progress bar (default: when standard error is a terminal).

    Raises
    ------
    PartialRunError
        A filter failed (an :class:`~teamslam.errors.EstimationError` naming robot and frame);
        its ``result`` holds the frames done.
    """
    from teamslam.msckf.configure import team_configs  # settings calibrate with a team run

    n = dataset.n_robots
    configs = team_configs(dataset, config)
    graph = graph or complete(n)
    if graph.n != n:
        raise InputError(f"graph has {graph.n} robots, dataset has {n}")
    edge_loss = EdgeLoss(graph, loss, seed)
    links: dict[int, np.ndarray] = {}
    network = MemoryNetwork(n, links=links.__getitem__)
    drivers = lockstep_drivers(dataset, configs, network, graph, consensus)

    exchanges = exchanges_per_frame(drivers)

    def draw_links(t: int, running: list[int]) -> None:
        mask = np.zeros(n, dtype=bool)
        mask[running] = True
        links.clear()
        for iteration in range(exchanges):  # each exchange of the frame draws its own links
            active, _ = edge_loss.step()
            links[t * exchanges + iteration] = active & mask[:, None] & mask[None, :]

    return run_drivers(drivers, graph.name, loss, draw_links, progress)
