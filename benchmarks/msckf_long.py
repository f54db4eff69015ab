"""Bounded cost over a long mission: the distributed MSCKF with a persistent map.

Run on demand (BLAS pinned to one thread)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_long.py cost [--frames 5000] [--retire 40]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_long.py accuracy [--frames 300] [--retire 40]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_long.py revisit [--frames 1000] [--set k=v ...]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_long.py budget [--frames 300] [--budgets 40 80]
        [--team make-run|long] [--reference-frames N] [--listening 80] [--windows 4]

``cost`` runs a team (3 robots, consensus over a complete graph) along the long route
(:func:`teamslam.sim.long_route_team`, a world of about 1.2 objects per metre) with objects
retiring to the persistent map after ``--retire`` unobserved frames, and prints the median
time per robot-frame over frames 100–200 and over the last 100 frames and their ratio (wall
time of all stages, and CPU time of the filter step, which other work on the machine disturbs
less), the peak state dimension, objects in the state and persistent-map size, and the memory
per robot at frame 200 and at the end: the bytes the filter holds — its state with the open
feature tracks and object observations, and apart the persistent map, which grows with the
objects retired — and the process's resident set size (the whole team and its data set).
``accuracy`` compares
the trajectory RMSE with and without retirement over a shorter run of the same route (without
retirement the cost grows with the map, so the run must stay short), and on the Lissajous team
of ``make run``.
``revisit`` flies the team of ``make run`` (5 robots on a complete graph revisiting the same
objects, window 10, geometric features and objects) for ``--frames`` frames, once with the
paper's consensus set (``consensus.set = all``) and once with the bounded one (``active``, with
the ``--set`` overrides), in one process, and prints per stage the median over frames of the
time per frame (mean over robots) over the first 100 frames, the 100 frames up to the middle of
the run and the last 100, and the ratios of the last to the first and to the middle (wall
time, and the CPU time of the consensus rounds and of the filter step, which other work on the
machine disturbs less), the
consensus bytes per robot-step, the objects averaged per robot-step and the state dimension
(mean over robots) over the same frames, and the accuracy of each run and its ratio to the
paper's set.
``budget`` flies a team — the team of ``make run`` or, ``--team long``, the long route — once
without a bound on the objects in each robot's state and once per ``--budgets`` value of
``objects.max_active``, and prints per run the median time per frame of consensus and of the
whole step (mean over robots) over frames 100–200 and over the last 100 and their ratio, the
trajectory RMSE and object error (final maps: state and persistent map) with their ratio to the
unbounded run, and the objects retired per robot. ``--reference-frames N`` flies the unbounded
run N frames only (its cost grows with the route) and each budget both N frames, for the
ratios, and ``--frames`` frames; ``--listening B…`` adds those budgets with retired objects
averaged with the neighbours' marginals (``consensus.persistent_map = true``); ``--windows K…``
adds runs with the budget learned from the data (``objects.active_windows = K``: ``K`` times the
most objects observed within one window), with the largest budget that rule reached.
``--markdown FILE`` writes that table headed by the commit, date, command and machine.
"""

from __future__ import annotations

import argparse
import resource
import time
from dataclasses import replace

import numpy as np

from _markdown import Markdown, add_option
from teamslam.eval.metrics import team_metrics
from teamslam.msckf import config_for, run_team
from teamslam.msckf.agent import MsckfAgent
from teamslam.sim import lissajous_team, long_route_team


def held_bytes(agent: MsckfAgent) -> tuple[int, int]:
    """Bytes the filter holds: ``(state and open observation histories, persistent map)``.

    Arrays by their size; an open observation as its 4-vector and its ``(frame, z)`` tuple; a
    persistent-map entry as its allocated rows plus about 100 bytes of dict entry.
    """
    state = agent.state
    arrays = (state.cov, state.poses, state.pose_fe, state.objects, state.object_fe)
    observations = sum(len(v) for v in agent.tracks.values())
    observations += sum(len(v) for v in agent.object_history.values())
    working = sum(a.nbytes for a in arrays) + observations * (4 * 8 + 112)
    stored = state.retired
    return working, stored.capacity * 15 * 8 + len(stored) * 100


def rss_mib() -> float:
    """Resident set size of this process now (MiB)."""
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * resource.getpagesize() / 2**20


class Probe:
    """Records, after every step of every robot, the state's size and at given frames memory."""

    def __init__(self, sample_frames: tuple[int, ...]) -> None:
        self.sample_frames = set(sample_frames)
        self.dim = self.objects = self.retired = 0
        self.memory: dict[int, list[int]] = {}
        self.states: dict[int, object] = {}
        self.cpu: dict[int, list[float]] = {}
        self.dims: dict[int, list[int]] = {}
        self.rss: dict[int, float] = {}
        self._step = MsckfAgent.step
        probe = self

        def step(agent: MsckfAgent, t: int) -> None:
            begin = time.thread_time()
            probe._step(agent, t)
            probe.cpu.setdefault(agent.robot, []).append(time.thread_time() - begin)
            state = agent.state
            probe.states[agent.robot] = state
            probe.dims.setdefault(agent.robot, []).append(state.dim)
            probe.dim = max(probe.dim, state.dim)
            probe.objects = max(probe.objects, state.n_objects)
            probe.retired = max(probe.retired, len(state.retired))
            if t in probe.sample_frames:
                probe.memory.setdefault(t, []).append(held_bytes(agent))
                probe.rss[t] = rss_mib()

        MsckfAgent.step = step

    def close(self) -> None:
        MsckfAgent.step = self._step

    def with_full_maps(self, result):
        """``result`` with each robot's final map including its persistent map."""
        maps = [self.states[i].full_map() for i in range(len(result.objects))]
        return replace(
            result,
            object_ids=[m[0] for m in maps],
            objects=[m[1] for m in maps],
            object_covs=[m[2] for m in maps],
        )


def cost(robots: int, frames: int, retire: int, seed: int) -> None:
    begin = time.perf_counter()
    dataset = long_route_team(robots=robots, steps=frames, seed=seed)
    print(
        f"long route: {robots} robots × {frames} frames, {len(dataset.object_positions)} objects "
        f"in the world (simulated in {time.perf_counter() - begin:.0f} s)"
    )
    config = config_for(dataset, {"objects.retire_after": retire})
    probe = Probe((200, frames))
    try:
        result = run_team(dataset, config, progress=False)
    finally:
        probe.close()
    per_frame = np.stack([t.sum(axis=1) for t in result.frame_times])  # (robots, frames + 1)
    early = float(np.median(per_frame[:, 100:200]))
    late = float(np.median(per_frame[:, frames - 100 : frames]))
    metrics = team_metrics(dataset, probe.with_full_maps(result))
    retired = sum(c.get("objects_retired", 0) for c in result.counters) / robots
    back = sum(c.get("objects_reentered", 0) for c in result.counters) / robots
    print(f"window {config.filter.window}, objects.retire_after {retire}, consensus on")
    print(f"wall time {result.wall_seconds:.0f} s")
    print(f"median time per robot-frame, frames 100–200:          {1e3 * early:7.1f} ms")
    print(f"median time per robot-frame, frames {frames - 100}–{frames}:      {1e3 * late:7.1f} ms")
    print(f"ratio:                                                {late / early:7.2f}")
    cpu = np.array([probe.cpu[i] for i in range(robots)])  # CPU seconds of each step
    cpu_early = float(np.median(cpu[:, 100:200]))
    cpu_late = float(np.median(cpu[:, frames - 100 : frames]))
    print(
        f"median CPU time of a robot's step (no consensus), same frames: {1e3 * cpu_early:.1f} "
        f"ms, {1e3 * cpu_late:.1f} ms, ratio {cpu_late / cpu_early:.2f}"
    )
    print(f"peak state dimension {probe.dim}, peak objects in state {probe.objects}")
    print(f"persistent map at the end (per robot, largest): {probe.retired} objects")
    print(f"objects retired / re-entered per robot: {retired:.0f} / {back:.0f}")
    for t in sorted(probe.memory):
        working, stored = (np.array(probe.memory[t]) / 1024).T
        print(
            f"frame {t:>5}: per robot, state + open observations {working.mean():6.0f} KiB "
            f"(max {working.max():.0f}), persistent map {stored.mean():6.0f} KiB "
            f"(max {stored.max():.0f}); process RSS {probe.rss[t]:.0f} MiB"
        )
    print(f"trajectory RMSE (mean over robots): {metrics['trajectory_rmse_avg_m']:.3f} m")
    print(
        f"object error, state + persistent map (mean over robots): "
        f"{metrics['object_error_avg_m']:.3f} m"
    )


def accuracy(robots: int, frames: int, retire: int, seed: int) -> None:
    print(f"{'team':<31} {'retire':>6} {'traj RMSE':>9} {'obj err':>8} {'obj err':>8} {'wall':>6}")
    print(f"{'':<31} {'':>6} {'[m]':>9} {'state':>8} {'+ map':>8} {'[s]':>6}")
    teams = (
        (f"long route {robots}r × {frames}", long_route_team(robots, frames, seed), {}),
        ("lissajous 5r × 150, window 10", lissajous_team(5, 150, seed=0), {"filter.window": 10}),
    )
    for name, dataset, extra in teams:
        for value in (0, retire):
            config = config_for(dataset, {"objects.retire_after": value, **extra})
            probe = Probe(())
            try:
                result = run_team(dataset, config, progress=False)
            finally:
                probe.close()
            m = team_metrics(dataset, result)
            full = team_metrics(dataset, probe.with_full_maps(result))
            print(
                f"{name:<31} {value:>6} {m['trajectory_rmse_avg_m']:9.3f} "
                f"{m['object_error_avg_m']:8.3f} {full['object_error_avg_m']:8.3f} "
                f"{result.wall_seconds:6.0f}"
            )


STAGES = ("consensus", "propagation", "update", "initialisation")


class ConsensusCpu:
    """CPU seconds of each robot's consensus rounds per step (``time.thread_time``: on a loaded
    machine wall time also counts waiting for a core; the team runs in one thread)."""

    def __init__(self) -> None:
        from teamslam.msckf.consensus.protocol import ConsensusProtocol

        self.spent: dict[tuple[int, int], float] = {}
        self.averaged: dict[tuple[int, int], int] = {}
        self._cls = ConsensusProtocol
        self._saved = {name: getattr(ConsensusProtocol, name) for name in ROUNDS}
        probe = self

        def timed(name):
            original = probe._saved[name]

            def call(protocol, *args, **kwargs):
                begin = time.thread_time()
                try:
                    out = original(protocol, *args, **kwargs)
                    if name == "average":
                        key = (protocol.robot, protocol.step)  # every exchange of the step
                        probe.averaged[key] = probe.averaged.get(key, 0) + out
                    return out
                finally:
                    key = (protocol.robot, protocol.step)
                    probe.spent[key] = probe.spent.get(key, 0.0) + time.thread_time() - begin

            return call

        for name in ROUNDS:
            setattr(ConsensusProtocol, name, timed(name))

    def close(self) -> None:
        for name, method in self._saved.items():
            setattr(self._cls, name, method)

    def per_frame(self, robots: int, frames: int) -> np.ndarray:
        """``(frames + 1,)`` consensus CPU seconds per robot at each step (mean over robots)."""
        return per_step_mean(self.spent, robots, frames)


ROUNDS = ("requests", "answer", "average")


def over(values, windows, summary=np.median, shift=0) -> list[float]:
    """``summary`` of ``values`` over each ``(begin, end)`` frame window (``shift``: the index
    of frame ``t`` is ``t − shift``)."""
    return [float(summary(values[a - shift : b - shift])) for a, b in windows]


def per_step_mean(totals: dict[tuple[int, int], float], robots: int, frames: int) -> np.ndarray:
    """``(frames + 1,)`` mean over robots of ``totals[(robot, step)]`` at each step."""
    out = np.zeros(frames + 1)
    for (_, step), amount in totals.items():
        if 0 <= step <= frames:
            out[step] += amount / robots
    return out


class ByteProbe:
    """Records the consensus bytes each robot sends at each step (in-process transport)."""

    def __init__(self) -> None:
        from teamslam.msckf.consensus.transport import MemoryTransport

        self.sent: dict[tuple[int, int], int] = {}
        self._cls = MemoryTransport
        self._send = MemoryTransport.send
        probe = self

        def send(transport, message) -> None:
            key = (int(message.sender), int(message.step))
            probe.sent[key] = probe.sent.get(key, 0) + message.nbytes()
            probe._send(transport, message)

        MemoryTransport.send = send

    def close(self) -> None:
        self._cls.send = self._send

    def per_frame(self, robots: int, frames: int) -> np.ndarray:
        """``(frames + 1,)`` bytes sent per robot at each step (mean over robots)."""
        return per_step_mean(self.sent, robots, frames)


def revisit(frames: int, seed: int, overrides: dict) -> None:
    dataset = lissajous_team(5, frames, seed=seed)
    print(
        f"make-run team: 5 robots × {frames} frames, complete graph, window 10, "
        f"{len(dataset.object_positions)} objects; bounded set: {overrides}"
    )
    rows, metrics = {}, {}
    for name, extra in (("all", {}), ("active", {"consensus.set": "active", **overrides})):
        config = config_for(dataset, {"filter.window": 10, **extra})
        probe, cpu, steps = ByteProbe(), ConsensusCpu(), Probe(())
        try:
            result = run_team(dataset, config, progress=False)
        finally:
            probe.close()
            cpu.close()
            steps.close()
        times = 1e3 * np.stack(result.frame_times).mean(axis=0)  # (frames + 1, 4), robot mean
        times = np.column_stack([times, times.sum(axis=1)])
        sent = probe.per_frame(5, frames)
        # frames 1–100, the 100 frames up to the middle of the run, the last 100
        half = frames // 2
        windows = [(1, 101), (half - 99, half + 1), (frames - 99, frames + 1)]
        consensus_cpu = 1e3 * cpu.per_frame(5, frames)
        # per step 0 … N-1 (frame t's step is at t): shifted to the same frames
        step_cpu = 1e3 * np.mean([steps.cpu[i] for i in range(5)], axis=0)
        dims = np.mean([steps.dims[i] for i in range(5)], axis=0)
        averaged_now = per_step_mean(cpu.averaged, 5, frames)

        rows[name] = (
            [over(times[:, k], windows) for k in range(5)]
            + [over(sent, windows, np.mean)]
            + [over(consensus_cpu, windows)]
            + [over(step_cpu, windows, shift=1)]
            + [over(averaged_now, windows, np.mean)]
            + [over(dims, windows, np.mean, shift=1)]
        )
        metrics[name] = team_metrics(dataset, result)
        inactive = sum(c.get("objects_inactive", 0) for c in result.counters)
        averaged = sum(c.get("objects_averaged", 0) for c in result.counters)
        print(
            f"{name}: wall {result.wall_seconds:.0f} s, objects averaged per robot-step "
            f"{averaged / (5 * frames):.1f}, inactive {inactive / (5 * frames):.1f}",
            flush=True,
        )
    mid = f"{frames // 2 - 99}–{frames // 2}"
    print(
        f"\n{'stage':<16} {'set':<7} {'first 100':>10} {mid:>10} {'last 100':>10} "
        f"{'last/first':>10} {'last/mid':>10}"
    )
    labels = (
        *STAGES,
        "total",
        "bytes/robot-step",
        "consensus CPU",
        "filter step CPU",
        "objects averaged",
        "state dimension",
    )
    for k, stage in enumerate(labels):
        for name in rows:
            a, m, b = rows[name][k]
            unit = "" if k in (5, 8, 9) else " ms"
            print(
                f"{stage:<16} {name:<7} {a:10.2f} {m:10.2f} {b:10.2f} {b / a:10.2f} "
                f"{b / m:10.2f}{unit}"
            )
    # consensus against the filter's own step: both rebuild or update the same dense covariance
    consensus_k, step_k = labels.index("consensus CPU"), labels.index("filter step CPU")
    for name in rows:
        ratio = [c / f for c, f in zip(rows[name][consensus_k], rows[name][step_k], strict=True)]
        print(
            f"consensus CPU / filter step CPU, {name}: "
            + " → ".join(f"{r:.2f}" for r in ratio)
            + " (first 100, middle, last 100)"
        )
    print(f"\n{'set':<7} {'traj RMSE':>10} {'obj err':>10} {'disagree':>10}")
    keys = ("trajectory_rmse_avg_m", "object_error_avg_m", "object_disagreement_avg_m")
    for name in rows:
        print(f"{name:<7} " + " ".join(f"{metrics[name][k]:10.5f}" for k in keys))
    print("ratio   " + " ".join(f"{metrics['active'][k] / metrics['all'][k]:10.3f}" for k in keys))


TEAMS = {
    "make-run": "the make-run team (5 robots on Lissajous curves over 210 objects, complete "
    "graph, window 10)",
    "long": "the long route (3 robots, complete graph, about 1.2 objects per metre, never "
    "revisited)",
}


def _team(team: str, frames: int, seed: int):
    """``(dataset, settings)`` of a budget run of ``team`` for ``frames`` frames."""
    if team == "long":
        return long_route_team(robots=3, steps=frames, seed=seed), {}
    return lissajous_team(5, frames, seed=seed), {"filter.window": 10}


def _budget_row(team: str, frames: int, seed: int, bound: int, settings: dict) -> dict:
    """One budget run: consensus and step times over frames 100–200 and the last 100, accuracy."""
    dataset, base = _team(team, frames, seed)
    config = config_for(dataset, {**base, "objects.max_active": bound, **settings})
    reached: dict[int, int] = {}
    active_budget = MsckfAgent.active_budget

    def recorded(agent: MsckfAgent, t: int) -> int:
        value = active_budget(agent, t)
        reached[agent.robot] = max(reached.get(agent.robot, 0), value)
        return value

    MsckfAgent.active_budget = recorded
    begin = time.perf_counter()
    try:
        result = run_team(dataset, config, progress=False)
    finally:
        MsckfAgent.active_budget = active_budget
    wall = time.perf_counter() - begin
    times = 1e3 * np.stack(result.frame_times).mean(axis=0)  # (frames + 1, 4)
    windows = [(100, 201), (frames - 99, frames + 1)]
    metrics = team_metrics(dataset, result)  # the final maps: state and persistent map
    robots = len(result.counters)
    return {
        "consensus": over(times[:, 0], windows),
        "step": over(times.sum(axis=1), windows),
        "rmse": metrics["trajectory_rmse_avg_m"],
        "objects": metrics["object_error_avg_m"],
        "retired": sum(c.get("objects_retired", 0) for c in result.counters) / robots,
        "budget": max(reached.values(), default=0),
        "wall": wall,
    }


def budget(
    team: str,
    frames: int,
    seed: int,
    budgets: list[int],
    md: Markdown,
    reference_frames: int | None = None,
    listening: list[int] = (),
    windows: list[int] = (),
) -> None:
    """Cost growth and accuracy of ``team`` under each ``objects.max_active``, against the
    run without a bound (over ``reference_frames`` frames when that is shorter: then each
    budget is also flown that long for the ratios)."""
    reference_frames = frames if reference_frames is None else min(reference_frames, frames)
    header = [
        "frames",
        "objects.max_active",
        "consensus ms, frames 100–200",
        "consensus ms, last 100",
        "growth",
        "step ms, frames 100–200",
        "step ms, last 100",
        "growth",
        "trajectory RMSE [m]",
        "× unbounded",
        "object error [m]",
        "× unbounded",
        "retired per robot",
    ]
    note = (
        "Times: median over the frames of the window of the wall time per frame, mean over "
        "robots; growth: last 100 frames over frames 100–200. Object error: each robot's "
        "final map, its state and its persistent map. × unbounded: against the run without a "
        "bound over as many frames."
    )
    if listening:
        note += (
            " *listening*: retired objects averaged with the neighbours' marginals of them "
            "(`consensus.persistent_map = true`); otherwise out of consensus until they re-enter."
        )
    if windows:
        note += (
            " *K windows*: the budget learned from the data (`objects.active_windows = K`): K "
            "times the most objects a robot observed within one window, the largest budget "
            "reached in brackets."
        )
    md.table(
        f"A budget on the objects in each robot's state: {TEAMS[team]} flown for {frames} "
        "frames, consensus",
        header,
        note,
    )
    print(" | ".join(header), flush=True)
    runs = [(reference_frames, 0, {})]
    runs += [(reference_frames, b, {}) for b in budgets]
    runs += [(reference_frames, b, {"consensus.persistent_map": True}) for b in listening]
    learned = [(0, {"objects.active_windows": k}) for k in windows]
    runs += [(reference_frames, b, extra) for b, extra in learned]
    if reference_frames < frames:
        runs += [(frames, b, {}) for b in budgets]
        runs += [(frames, b, extra) for b, extra in learned]
    reference = None
    for length, bound, settings in runs:
        row = _budget_row(team, length, seed, bound, settings)
        if bound == 0 and not settings:
            reference = (row["rmse"], row["objects"])
        ratios = (
            (f"{row['rmse'] / reference[0]:.2f}", f"{row['objects'] / reference[1]:.2f}")
            if length == reference_frames
            else ("—", "—")
        )
        name = "none" if bound == 0 else str(bound)
        if "objects.active_windows" in settings:
            name = f"{settings['objects.active_windows']} windows ({row['budget']})"
        elif settings:
            name += ", listening"
        c, st = row["consensus"], row["step"]
        cells = [
            str(length),
            name,
            f"{c[0]:.2f}",
            f"{c[1]:.2f}",
            f"{c[1] / c[0]:.2f}",
            f"{st[0]:.2f}",
            f"{st[1]:.2f}",
            f"{st[1] / st[0]:.2f}",
            f"{row['rmse']:.4f}",
            ratios[0],
            f"{row['objects']:.4f}",
            ratios[1],
            f"{row['retired']:.0f}",
        ]
        md.row(*cells)
        print(" | ".join(cells), f"(wall {row['wall']:.0f} s)", flush=True)
    md.end()


def _overrides(pairs: list[str]) -> dict:
    from teamslam.msckf.settings.sources import parse_assignments

    return dict(parse_assignments(pairs))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("what", choices=("cost", "accuracy", "revisit", "budget"))
    parser.add_argument(
        "--budgets", type=int, nargs="*", default=[40, 80, 160], help="budget: objects.max_active"
    )
    parser.add_argument(
        "--team", choices=tuple(TEAMS), default="make-run", help="budget: the team flown"
    )
    parser.add_argument(
        "--reference-frames",
        type=int,
        default=None,
        help="budget: fly the unbounded run (and each budget, for the ratios) this many frames "
        "only (default: --frames)",
    )
    parser.add_argument(
        "--listening",
        type=int,
        nargs="*",
        default=[],
        help="budget: these budgets also with consensus.persistent_map = true",
    )
    parser.add_argument(
        "--windows",
        type=int,
        nargs="*",
        default=[],
        help="budget: also the budget learned from the data, objects.active_windows = K",
    )
    add_option(parser)
    parser.add_argument("--set", nargs="*", default=[], help="bounded-set settings (revisit)")
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--frames", type=int, default=None, help="5000 (cost), 300 (accuracy)")
    parser.add_argument("--retire", type=int, default=40, help="object_retire_after (frames)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.what == "budget":
        md = Markdown(args.markdown)
        budget(
            args.team,
            args.frames or 300,
            args.seed,
            args.budgets,
            md,
            args.reference_frames,
            args.listening,
            args.windows,
        )
        md.write()
    elif args.what == "revisit":
        revisit(args.frames or 1000, args.seed, _overrides(args.set))
    elif args.what == "cost":
        cost(args.robots, args.frames or 5000, args.retire, args.seed)
    else:
        accuracy(args.robots, args.frames or 300, args.retire, args.seed)


if __name__ == "__main__":
    main()
