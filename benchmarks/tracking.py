"""Each robot tracking its own detections against oracle ids: accuracy, tracking quality, cost.

For each case the same detections are run twice through separate filters (no consensus):
with the dataset's ids (the oracle) and with the ids removed (``strip_object_ids(to="none")``,
each robot's :mod:`teamslam.msckf.objects.tracking` naming its detections). Printed: trajectory RMSE
(mean over robots, as ``teamslam run``), its ratio to the oracle, CLEAR-MOT / IDF1
(:mod:`teamslam.eval.tracking`), false objects confirmed per 1000 frames, the tracking time
as a share of the per-robot-step time (wall, the agent's stage timings; and CPU time of this
thread, per robot-frame — the measure on a shared machine), and where the IDF1 is lost
(missed and false detections, wrong ids on a revisit — more than a window of frames from the
object's own id — or within a pass; :func:`~teamslam.eval.tracking.idf1_losses`), and how
many of the tracker's re-identifications (a detection given to an object not seen for ``N``
frames) were right (:func:`~teamslam.eval.tracking.revisit_precision`). Each case runs without
and with loop closure in each robot's own map (``tracking.loop_closure``,
:mod:`teamslam.msckf.objects.loop_closure`; ``--loop-closure off|on|both``), whose CPU time counts
as
tracking; printed with it: the merged pairs and how many were right (both objects' own
detections mostly of the same true object, :func:`closure_precision`).

Usage::

    python benchmarks/tracking.py [--kitti DATASET_DIR] [--robots 5 --steps 300] [--seeds 0 1]
                                  [--scenarios NAME …] [--no-sim] [--watch-revisits]
                                  [--loop-closure both] [--set KEY=VALUE …]

``DATASET_DIR`` is a dataset with ids (e.g. ``teamslam data import-reference … K``); its
settings are resolved (calibrated when it has no sensor model) on the oracle dataset and used
for both runs. ``--scenarios`` adds sensor scenarios (:mod:`teamslam.sim.scenarios`, e.g.
``normalised-0.005-objects``: ``K = I``) of ``--robots`` and ``--steps`` for each seed, given
without their sensor model, so calibrated from the data as a user's team with no noise given.
``--markdown FILE`` writes the final table as Markdown headed by the commit, date, command and
machine (``benchmarks/_markdown.py``).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from _markdown import Markdown, add_option
from teamslam.datasets.identity import strip_object_ids
from teamslam.datasets.storage import load_dataset
from teamslam.eval.metrics import trajectory_rmse
from teamslam.eval.tracking import (
    hypotheses_of,
    idf1_losses,
    revisit_precision,
    tracking_metrics,
)
from teamslam.msckf.agent import MsckfAgent
from teamslam.msckf.configure import config_for
from teamslam.msckf.settings.sources import ConfigError, parse_assignments
from teamslam.sim.lissajous import lissajous_team
from teamslam.sim.scenarios import SENSOR_SCENARIOS, scenario_team


def run_separate(dataset, config, revisit_d2: list | None = None) -> tuple[float, list, float]:
    """Every robot's filter alone; mean trajectory RMSE, the agents and the wall time (with
    ``revisit_d2``, :func:`watch_revisits` fills it). Each agent gets ``cpu``: the CPU time of
    its steps and of its tracker (thread time, s)."""
    agents, rmse = [], []
    begin = time.perf_counter()
    for i, robot in enumerate(dataset.robots):
        agent = MsckfAgent(i, dataset.calibration, robot, config)
        if revisit_d2 is not None:
            watch_revisits(agent, robot.detections, config.filter.window, revisit_d2)
        agent.cpu = {"step": 0.0, "tracking": 0.0}
        if agent.tracker is not None:
            time_tracker(agent)
        poses = np.empty((robot.frames, 4, 4))
        for t in range(robot.frames):
            start = time.thread_time()
            agent.step(t)
            agent.cpu["step"] += time.thread_time() - start
            poses[t] = agent.state.current_pose
        rmse.append(trajectory_rmse(poses, robot.T_world_body))
        agents.append(agent)
    return float(np.mean(rmse)), agents, time.perf_counter() - begin


def time_tracker(agent) -> None:
    """Count the CPU time of ``agent``'s tracker in ``agent.cpu["tracking"]``."""
    assign = agent.tracker.assign

    def timed(*args):
        start = time.thread_time()
        frame = assign(*args)
        agent.cpu["tracking"] += time.thread_time() - start
        return frame

    agent.tracker.assign = timed


def watch_revisits(agent, detections, gap: int, out: list) -> None:
    """Measure how consistent the filter is where re-identification needs it: at the first
    detection of each revisit (a true object whose last named detection is more than ``gap``
    frames old), append the squared Mahalanobis distance of the detection from the object it
    was named as, predicted with the filter's own innovation covariance (``inf`` when that
    object is not predicted: dropped, behind the camera or too far)."""
    tracker = agent.tracker
    assign = tracker.assign
    last: dict[int, tuple[int, int]] = {}  # true object -> (id, frame) of its last named one

    def watched(t, z, classes, state, odometry_cov, appearance=None):
        tracker._forget_mapped(state)
        _, ids, _, pred, s, _, _, _ = tracker._predict(t, state, odometry_cov)
        frame = assign(t, z, classes, state, odometry_cov, appearance)
        truth = detections.truth[detections.offsets[t] : detections.offsets[t + 1]]
        for j, obj in enumerate(truth.tolist()):
            if obj < 0 or not np.all(np.isfinite(z[j])):
                continue
            if obj in last and t - last[obj][1] > gap:
                row = np.flatnonzero(ids == last[obj][0])
                r = z[j] - pred[row[0]] if row.size else None
                out.append(float(r @ np.linalg.solve(s[row[0]], r)) if row.size else np.inf)
                last.pop(obj)
            if frame.ids[j] >= 0:
                last[obj] = (int(frame.ids[j]), t)
        return frame

    tracker.assign = watched


def closure_precision(truth: np.ndarray, raw: np.ndarray, closures: list) -> tuple[int, int]:
    """How many loop closures ``(frame, new id, old id)`` were right: ``(right, judged)``; a
    closure is judged when both objects' own detections (``raw``: the ids before any merge)
    include true ones, and right when the true object most of each one's were is the same."""

    def majority(oid: int) -> int:
        own = truth[(raw == oid) & (truth >= 0)]
        if not own.size:
            return -1
        values, counts = np.unique(own, return_counts=True)
        return int(values[np.argmax(counts)])

    right = judged = 0
    for _, new, old in closures:
        a, b = majority(new), majority(old)
        if a >= 0 and b >= 0:
            judged += 1
            right += int(a == b)
    return right, judged


def compare(name: str, dataset, config, watch: bool = False) -> dict:
    """Oracle ids against own tracking on the same detections (``watch``: with
    :func:`watch_revisits`, whose extra prediction is counted in the tracking time)."""
    oracle, _, oracle_s = run_separate(dataset, config)
    stripped = strip_object_ids(dataset, to="none")
    revisit_d2: list[float] = []
    own, agents, own_s = run_separate(stripped, config, revisit_d2 if watch else None)
    d2 = np.array(revisit_d2)
    hypotheses = hypotheses_of(agents)
    metrics = tracking_metrics(stripped, hypotheses)
    losses: dict[str, int] = {}
    revisits = [0, 0, 0]  # taken, judged, right
    closures = [0, 0, 0]  # merged pairs, judged, right
    for robot, hyp, agent in zip(stripped.robots, hypotheses, agents, strict=True):
        det = robot.detections
        part = idf1_losses(det.offsets, det.truth, hyp, revisit_gap=config.filter.window)
        for key, value in part.items():
            losses[key] = losses.get(key, 0) + value
        right, judged = revisit_precision(det.offsets, det.truth, hyp, agent.tracker.revisits)
        revisits[0] += len(agent.tracker.revisits)
        revisits[1] += judged
        revisits[2] += right
        if agent.tracker.loop is not None:
            raw = np.concatenate(agent.tracker.log).astype(np.int64)
            right, judged = closure_precision(det.truth, raw, agent.tracker.loop.closures)
            closures[0] += len(agent.tracker.loop.closures)
            closures[1] += judged
            closures[2] += right
    tracking_s = sum(a.timings["tracking"] for a in agents)
    steps = sum(sum(a.timings[k] for k in a.timings) for a in agents)
    frames = sum(robot.frames for robot in stripped.robots)
    cpu_tracking = sum(a.cpu["tracking"] for a in agents)
    cpu_steps = sum(a.cpu["step"] for a in agents)
    team = metrics["team"] if metrics else {}
    return {
        "case": name,
        "oracle_rmse": oracle,
        "own_rmse": own,
        "ratio": own / oracle,
        "idf1": team.get("idf1", float("nan")),
        "mota": team.get("mota", float("nan")),
        "id_switches": team.get("id_switches", 0),
        "fragmentations": team.get("fragmentations", 0),
        "objects": f"{team.get('objects_created', 0)}/{team.get('objects_true', 0)}",
        "false_per_1000": metrics["false_objects_per_1000_frames"] if metrics else float("nan"),
        "tracking_share": tracking_s / steps if steps else float("nan"),
        "tracking_cpu_share": cpu_tracking / cpu_steps if cpu_steps else float("nan"),
        "tracking_cpu_ms": 1e3 * cpu_tracking / frames if frames else float("nan"),
        "step_cpu_ms": 1e3 * cpu_steps / frames if frames else float("nan"),
        "seconds": oracle_s + own_s,
        "losses": losses,
        "revisits": revisits,
        "closures": closures,
        "revisit_d2": d2,
        "gate": agents[0].tracker.gate,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kitti", help="a dataset directory with ids (e.g. KITTI 00)")
    parser.add_argument("--robots", type=int, default=5)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--seeds", type=int, nargs="*", default=[0])
    parser.add_argument("--clutter", type=float, default=0.05)
    parser.add_argument("--miss", type=float, default=0.10)
    parser.add_argument("--classes", type=int, default=0)
    parser.add_argument("--no-sim", action="store_true")
    parser.add_argument(
        "--scenarios",
        nargs="*",
        default=[],
        choices=sorted(SENSOR_SCENARIOS),
        help="sensor scenarios of --robots and --steps per seed, calibrated from the data",
    )
    parser.add_argument(
        "--loop-closure",
        choices=("on", "off", "both"),
        default="both",
        help="loop closure in each robot's own map (track_loop_closure); both: a row for each",
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a filter setting for both runs of every case (as teamslam run --set)",
    )
    parser.add_argument(
        "--watch-revisits",
        action="store_true",
        help="how often a revisited object is inside its gate (costs tracking time)",
    )
    add_option(parser)
    args = parser.parse_args()
    md = Markdown(args.markdown)
    try:
        settings = parse_assignments(args.set)
    except ConfigError as exc:
        parser.error(str(exc))
    if "tracking.loop_closure" in settings:
        parser.error("loop closure is chosen by --loop-closure, not --set tracking.loop_closure")
    rows = []
    closure = {"on": (True,), "off": (False,), "both": (False, True)}[args.loop_closure]
    if args.kitti:
        dataset = load_dataset(args.kitti)
        for on in closure:
            config = config_for(dataset, settings).with_({"tracking.loop_closure": on})
            name = f"{dataset.name} closure {'on' if on else 'off'}"
            rows.append(compare(name, dataset, config, args.watch_revisits))
            print_table(rows[-1:])
    for name in args.scenarios:
        for seed in args.seeds:
            team = scenario_team(
                name, robots=args.robots, steps=args.steps, seed=seed, sensor_model=False
            )
            for on in closure:
                config = config_for(team, settings).with_({"tracking.loop_closure": on})
                case = f"{name} {args.robots}r {args.steps}s s{seed} {'loop' if on else 'main'}"
                rows.append(compare(case, team, config, args.watch_revisits))
                print_table(rows[-1:])
    if not args.no_sim:
        for seed in args.seeds:
            team = lissajous_team(
                robots=args.robots,
                steps=args.steps,
                seed=seed,
                clutter=args.clutter,
                miss=args.miss,
                classes=args.classes,
            )
            for on in closure:
                name = (
                    f"sim {args.robots}r {args.steps}s s{seed} c{args.clutter} m{args.miss} "
                    f"{'loop' if on else 'main'}"
                )
                config = config_for(team, settings, calibrate="never").with_(
                    {"tracking.loop_closure": on}
                )
                rows.append(compare(name, team, config, args.watch_revisits))
                print_table(rows[-1:])
    print()
    print_table(rows)
    markdown_table(md, rows, args)
    md.write()


def markdown_table(md: Markdown, rows: list[dict], args) -> None:
    """The cases as one Markdown table."""
    md.table(
        "Own tracking against the data's ids (oracle), separate filters on the same detections",
        [
            "case",
            "oracle RMSE [m]",
            "own RMSE [m]",
            "own / oracle",
            "IDF1",
            "MOTA",
            "ID switches",
            "objects made / true",
            "false objects per 1000 frames",
            "tracking CPU per robot-frame [ms] (share)",
            "re-identifications right / judged",
            "loop-closure merges right / judged",
        ],
        note=" ".join(_case_notes(args))
        + " `main`: without loop closure in each robot's own map, `loop`: with it.",
    )
    for r in rows:
        _, judged, right = r["revisits"]
        merged, m_judged, m_right = r["closures"]
        md.row(
            r["case"],
            f"{r['oracle_rmse']:.3f}",
            f"{r['own_rmse']:.3f}",
            f"{r['ratio']:.3f}",
            f"{r['idf1']:.3f}",
            f"{r['mota']:.3f}",
            r["id_switches"],
            r["objects"],
            f"{r['false_per_1000']:.2f}",
            f"{r['tracking_cpu_ms']:.3f} ({100 * r['tracking_cpu_share']:.1f}%)",
            f"{right} / {judged}",
            f"{m_right} / {m_judged}" if merged else "—",
        )
    md.end()


def _case_notes(args) -> list[str]:
    """What the table's cases are, one sentence per kind that ran."""
    notes = []
    if args.kitti:
        notes.append("Dataset cases: the data's ids are the oracle.")
    if args.scenarios:
        notes.append(
            f"Scenario cases (`teamslam.sim.scenarios`): {args.robots} robots, {args.steps} "
            "steps, seed `sN`, no sensor model given (the noise calibrated from the data)."
        )
    if not args.no_sim:
        notes.append(
            f"Simulated cases: {args.robots} robots, {args.steps} steps, clutter "
            f"{args.clutter}, miss rate {args.miss}, seed `sN`."
        )
    return notes


def print_table(rows: list[dict]) -> None:
    """One line per case."""
    head = (
        f"{'case':<44} {'oracle m':>9} {'own m':>8} {'ratio':>6} {'IDF1':>6} {'MOTA':>6} "
        f"{'IDSW':>5} {'frag':>5} {'objects':>9} {'false/1k':>8} {'track %':>7}"
    )
    print(head)
    for r in rows:
        print(
            f"{r['case']:<44} {r['oracle_rmse']:9.3f} {r['own_rmse']:8.3f} {r['ratio']:6.3f} "
            f"{r['idf1']:6.3f} {r['mota']:6.3f} {r['id_switches']:5d} {r['fragmentations']:5d} "
            f"{r['objects']:>9} {r['false_per_1000']:8.2f} {100 * r['tracking_share']:7.2f}"
        )
        loss = r["losses"]
        if loss.get("loss"):
            print(
                f"{'':<44} IDF1 loss {loss['loss']} = missed {loss['missed']} + false "
                f"{loss['false']} + 2 × wrong ids (revisits {loss['wrong_revisit']}, within a "
                f"pass {loss['wrong_within_pass']}, of unmapped objects {loss['wrong_unmapped']})"
            )
        print(
            f"{'':<44} CPU per robot-frame: tracking {r['tracking_cpu_ms']:.3f} ms of a "
            f"{r['step_cpu_ms']:.3f} ms step ({100 * r['tracking_cpu_share']:.1f}%)"
        )
        taken, judged, right = r["revisits"]
        print(f"{'':<44} re-identifications {taken}: {right} right of {judged} with ground truth")
        merged, judged, right = r["closures"]
        if merged:
            print(f"{'':<44} loop closures {merged} pairs: {right} right of {judged} judged")
        d2 = r["revisit_d2"]
        if d2.size:
            print(
                f"{'':<44} revisits {d2.size}: the object inside its gate (χ²(4) ≤ "
                f"{r['gate']:.1f}) at the first detection {np.mean(d2 <= r['gate']):.0%}, "
                f"median d² {np.median(d2):.1f} (χ²(4): 3.4)"
            )


if __name__ == "__main__":
    main()
