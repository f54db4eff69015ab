"""Association between robots' separate maps without shared ids: precision, recall, time.

Run on demand (BLAS pinned to one thread)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/association.py [kitti] [sim] [ring] [scenarios] \
        [--frames 500 1000]

Each team's object ids are first made per robot (:func:`~teamslam.datasets.identity.
strip_object_ids`: no id in common across robots; which ids are the same object is kept as
ground truth), then every robot runs its own filter (``--separate``). For each robot pair the
final maps — ids, positions, marginal covariances — are associated
(:func:`~teamslam.association.associate`) and scored against the objects both maps hold:
correct, wrong, precision, recall, with the CPU time of one association call (median of
three, ``time.process_time``).

* ``kitti`` — KITTI 00 (three robots): the final maps, and the maps at ``--frames`` (each robot's
  filter run over its first F frames: what a robot holds while its map grows);
* ``sim`` — a simulated team (``teamslam simulate --robots 5 --steps 150 --seed 0``);

and both again with the second robot's whole map shifted 20 m and turned 30° about the vertical.
Last, a correspondence table per link is kept over the growing maps (the truncated ones, then
the final ones), as a robot would at run time: extended under its transform
(:meth:`~teamslam.association.CorrespondenceTable.extend`), then merged with a full association;
it prints the table's precision and recall and the CPU time of both calls.

* ``ring`` — the cost at run time: 15 simulated robots on a ring with 30% link loss (150 frames,
  ``filter.window = 10``, ids made per robot), consensus with own association. Prints the
  association's
  share of the per-robot-step time (``metrics.json["association"]["team"]``), the number of
  full associations and extensions and the CPU time of each kind (``time.thread_time`` around
  every call), with the run's RMSE, precision and recall.
* ``scenarios`` — accuracy on teams unlike the default one: each of
  :data:`teamslam.sim.SENSOR_SCENARIOS` (cameras in normalised coordinates or pixels, other
  noise levels; 3 robots, 200 steps, complete graph, ``filter.window = 10``) run with consensus
  twice:
  with the simulator's global ids (``association.mode = oracle``) and with ids made per robot
  (``own``). Prints both RMSEs, their ratio, and the own association's precision and recall.
* ``oracle`` — the same comparison, with the separate filters beside it, on the ``--teams``
  named: ``default`` (``teamslam simulate --robots 5 --steps 150 --seed 0``, ``window = 10``),
  ``ring`` (15 robots on a ring with 30% link loss, 150 steps, ``window = 10``) and ``kitti00``
  (KITTI 00, objects only, the settings ``teamslam run`` resolves; each dataset calibrated
  once) and ``grid`` (``teamslam simulate --route grid``: 4 cars, 400 steps through a grid
  city whose kerbs hold an object every 8 m, the layout where positions are most ambiguous;
  ``window = 10``). Prints the RMSEs, own / oracle, precision, recall, held / revoked pairs and the
  summary bytes per robot per frame. ``--appearance DIM`` simulates the teams with appearance
  (``teamslam simulate --appearance DIM``: each robot's own noisy descriptor of each object it
  saw, which its summaries carry); ``--useless-appearance`` then makes every descriptor equal
  (appearance that tells nothing apart). KITTI 00 has no appearance: it runs as without.

``--markdown FILE`` (``oracle``, ``scenarios``) writes the table as Markdown headed by the
commit, date, command and machine (``benchmarks/_markdown.py``).
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import teamslam.msckf.consensus.protocol as protocol
from _markdown import Markdown, add_option
from teamslam import api
from teamslam.association import (
    AssociationSettings,
    CorrespondenceTable,
    ObjectSummary,
    associate,
    score_correspondences,
)
from teamslam.datasets import import_reference, load_dataset
from teamslam.datasets.identity import strip_object_ids
from teamslam.geometry import so3
from teamslam.msckf import run_team
from teamslam.msckf.configure import build_settings, team_configs
from teamslam.msckf.consensus.protocol import ConsensusProtocol
from teamslam.sim import SENSOR_SCENARIOS, grid_city_team, lissajous_team, scenario_team

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEAMSLAM_DATA", ROOT.parent / "shared" / "data"))


def _drift(yaw_deg: float = 30.0, shift: float = 20.0) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = so3.exp(np.array([0.0, 0.0, np.deg2rad(yaw_deg)]))
    t[:3, 3] = [shift, 0.0, 0.0]
    return t


def _summaries(dataset, result) -> list[ObjectSummary]:
    return [
        ObjectSummary(i, result.object_ids[i], result.objects[i], result.object_covs[i])
        for i in range(dataset.n_robots)
    ]


def _table(label: str, dataset, summaries: list[ObjectSummary], drift: bool) -> dict:
    totals = {"correct": 0, "wrong": 0, "shared": 0, "times": []}
    for i in range(len(summaries)):
        for j in range(i + 1, len(summaries)):
            a, b = summaries[i], summaries[j]
            if drift:
                b = b.transformed(_drift())
            times = []
            for _ in range(3):  # CPU time of this process: robust to other load on the machine
                begin = time.process_time()
                result = associate(a, b)
                times.append(time.process_time() - begin)
            score = score_correspondences(
                result.pairs, a.ids, b.ids, dataset.true_objects(i), dataset.true_objects(j)
            )
            t = float(np.median(times))
            totals["times"].append(t)
            for k in ("correct", "wrong", "shared"):
                totals[k] += getattr(score, k)
            print(
                f"{label:<26} {i}-{j}  {len(a):4d} {len(b):4d}  {result.status:<9} "
                f"{score.shared:6d} {score.correct:7d} {score.wrong:5d} "
                f"{score.precision:9.3f} {score.recall:6.3f} {t * 1e3:8.1f}"
            )
    n = totals["correct"] + totals["wrong"]
    precision = totals["correct"] / n if n else 1.0
    recall = totals["correct"] / totals["shared"] if totals["shared"] else 1.0
    print(
        f"{label:<26} all  {'':9}  {'':9} {totals['shared']:6d} {totals['correct']:7d} "
        f"{totals['wrong']:5d} {precision:9.3f} {recall:6.3f} "
        f"{np.median(totals['times']) * 1e3:8.1f}"
    )
    return totals


def _header() -> None:
    print(f"{'maps':<26} pair  objects   status    shared correct wrong precision recall  cpu ms")


def _growing(label: str, dataset, checkpoints: list[tuple[str, list[ObjectSummary]]]) -> None:
    """A correspondence table per link kept over growing maps, as at run time: at each
    checkpoint the table is first extended under its transform, then a full association is
    merged into it."""
    n = dataset.n_robots
    tables = {(i, j): CorrespondenceTable(i, j) for i in range(n) for j in range(i + 1, n)}
    for name, summaries in checkpoints:
        correct = wrong = shared = 0
        t_extend, t_full = [], []
        for (i, j), table in tables.items():
            a, b = summaries[i], summaries[j]
            begin = time.process_time()
            table.extend(a, b)
            t_extend.append(time.process_time() - begin)
            begin = time.process_time()
            result = associate(a, b)
            t_full.append(time.process_time() - begin)
            table.merge(result, a, b)
            score = score_correspondences(
                table.pairs(), a.ids, b.ids, dataset.true_objects(i), dataset.true_objects(j)
            )
            correct, wrong, shared = (
                correct + score.correct,
                wrong + score.wrong,
                shared + score.shared,
            )
        held = correct + wrong
        print(
            f"{label + ' table at ' + name:<34} shared {shared:4d}  correct {correct:4d}  "
            f"wrong {wrong:3d}  precision {correct / held if held else 1.0:6.3f}  "
            f"recall {correct / shared if shared else 1.0:6.3f}  "
            f"extend {np.median(t_extend) * 1e3:6.1f} cpu ms  "
            f"associate {np.median(t_full) * 1e3:6.1f} cpu ms"
        )


def _evaluate(label: str, dataset, configs, frames: list[int]) -> None:
    result = run_team(dataset, config=configs, consensus=False, progress=False)
    summaries = _summaries(dataset, result)
    print(
        f"{label}: summary sent to a neighbour at the end: "
        + ", ".join(f"robot {s.robot} {len(s)} objects {s.nbytes:,} B" for s in summaries)
    )
    _table(f"{label} final", dataset, summaries, drift=False)
    _table(f"{label} final, 20 m 30°", dataset, summaries, drift=True)
    checkpoints = []
    for f in frames:
        head = dataset.head(f)
        partial = run_team(head, config=configs, consensus=False, progress=False)
        _table(f"{label} frame {f}", head, _summaries(head, partial), drift=False)
        checkpoints.append((f"frame {f}", _summaries(head, partial)))
    checkpoints.append(("the end", summaries))
    _growing(label, dataset, checkpoints)


def kitti(frames: list[int]) -> None:
    src = DATA / "distributed-msckf" / "kitti00"
    if not src.is_dir():
        print(f"KITTI 00 not found at {src}")
        return
    dataset = import_reference(src, object_ids="per-robot", seed=0)
    configs = team_configs(dataset, None)  # calibrated once, reused for the shorter runs
    _evaluate("kitti00", dataset, configs, frames)


def sim(frames: list[int]) -> None:
    dataset = strip_object_ids(lissajous_team(robots=5, steps=150, seed=0), seed=0)
    configs = team_configs(dataset, None)
    _evaluate("sim 5x150", dataset, configs, [f for f in frames if f < 151])


def ring() -> None:
    dataset = strip_object_ids(lissajous_team(robots=15, steps=150, seed=0), seed=0)
    spent = {"full": [], "extend": []}
    full, extend = protocol.associate, CorrespondenceTable.extend

    def timed_full(*args, **kwargs):
        begin = time.thread_time()
        out = full(*args, **kwargs)
        spent["full"].append(time.thread_time() - begin)
        return out

    def timed_extend(*args, **kwargs):
        begin = time.thread_time()
        out = extend(*args, **kwargs)
        spent["extend"].append(time.thread_time() - begin)
        return out

    protocol.associate, CorrespondenceTable.extend = timed_full, timed_extend
    try:
        begin = time.process_time()
        run = api.run(
            dataset,
            graph="ring",
            loss=0.3,
            settings={"filter.window": 10},
            association="own",
            report=False,
            progress=False,
        )
        total = time.process_time() - begin
    finally:
        protocol.associate, CorrespondenceTable.extend = full, extend
    team = run.metrics["association"]["team"]
    print(
        f"ring 15 robots, 30% loss: association share of step time "
        f"{100 * team['association_time_share']:.1f}%; run {total:.1f} cpu s; "
        f"{len(spent['full'])} full associations {sum(spent['full']):.2f} cpu s "
        f"({1e3 * np.median(spent['full']):.1f} ms median), {len(spent['extend'])} extensions "
        f"{sum(spent['extend']):.2f} cpu s; RMSE {run.metrics['trajectory_rmse_avg_m']:.4f} m, "
        f"precision {team['precision']:.3f}, recall {team['recall']:.3f}"
    )


def _truth_of(dataset, robot: int, ids: np.ndarray) -> np.ndarray:
    """The team object of each of ``robot``'s ids (-1: no truth)."""
    keys, values = dataset.true_objects(robot)
    order = np.argsort(keys)
    keys, values = keys[order], values[order]
    pos = np.clip(np.searchsorted(keys, ids), 0, max(keys.size - 1, 0))
    out = np.full(ids.shape, -1, np.int64)
    if keys.size:
        hit = keys[pos] == ids
        out[hit] = values[pos[hit]]
    return out


def delay(directory: str, graph: str, loss: float, window: int) -> None:
    """First-match delay of own association at run time, per link: the exchange at which the
    link's table first holds a pair, counted from the first exchange at which both maps hold
    ``min_inliers`` common objects (ground truth); with the run's RMSE, precision and recall
    and the recall averaged over every exchange of a link whose maps share objects (and over
    those from the link's first match on)."""
    dataset = load_dataset(directory)
    need = AssociationSettings().min_inliers
    seen: dict[tuple[int, int], list[tuple[int, int, int, int]]] = {}
    original = ConsensusProtocol._associate

    def recorded(self, j, request):
        out = original(self, j, request)
        own = self._summary
        if self.robot < j and own is not None and out:
            truth_a = _truth_of(dataset, self.robot, own.ids)
            truth_b = _truth_of(dataset, j, np.asarray(request.summary.ids))
            shared = np.intersect1d(truth_a[truth_a >= 0], truth_b[truth_b >= 0]).size
            pairs = self.tables[j].pairs()
            ta = _truth_of(dataset, self.robot, pairs[:, 0])
            tb = _truth_of(dataset, j, pairs[:, 1])
            correct = int(np.count_nonzero((ta == tb) & (ta >= 0)))
            seen.setdefault((self.robot, j), []).append(
                (self.step, shared, correct, len(pairs) - correct)
            )
        return out

    ConsensusProtocol._associate = recorded
    try:
        run = api.run(
            dataset,
            graph=graph,
            loss=loss,
            settings={"filter.window": window},
            association="own",
            report=False,
            progress=False,
        )
    finally:
        ConsensusProtocol._associate = original
    delays, late, recalls, after = [], [], [], []
    for (i, j), rows in sorted(seen.items()):
        rows = np.array(rows)
        ready = rows[rows[:, 1] >= need]
        if not ready.size:
            continue
        start = ready[0, 0]
        held = rows[rows[:, 2] + rows[:, 3] > 0]
        first = held[0, 0] if held.size else rows[-1, 0] + 1
        delays.append(first - start)
        late.append((first - start, i, j))
        active = rows[rows[:, 1] > 0]
        recalls.extend(active[:, 2] / active[:, 1])
        answered = active[active[:, 0] >= first]
        after.extend(answered[:, 2] / answered[:, 1])
    team = run.metrics["association"]["team"]
    worst = ", ".join(f"{a}-{b} {d}" for d, a, b in sorted(late, reverse=True)[:3])
    print(
        f"{Path(directory).name} {graph} loss {loss:g}: first match after {need} shared objects: "
        f"median {np.median(delays):.1f} frames, mean {np.mean(delays):.1f}, max "
        f"{np.max(delays)} over {len(delays)} links (worst {worst}); recall over time "
        f"{np.mean(recalls):.3f} ({np.mean(after):.3f} after the first match); final precision "
        f"{team['precision']:.3f} recall {team['recall']:.3f}; "
        f"RMSE {run.metrics['trajectory_rmse_avg_m']:.4f} m; "
        f"association share {100 * team['association_time_share']:.1f}%"
    )


def scenarios(window: int, md: Markdown, appearance: int = 0) -> None:
    """Consensus RMSE with oracle ids against own association on each sensor scenario (with
    simulated appearance of ``appearance`` dimensions when given)."""
    print(
        f"{'scenario':32} {'oracle m':>9} {'own m':>9} {'ratio':>6} {'precision':>9} {'recall':>7}"
    )
    md.table(
        f"Sensor scenarios (3 robots, 200 steps, complete graph, window {window}): consensus "
        "with the simulator's ids and with own association"
        + (f", appearance of {appearance} dimensions" if appearance else ""),
        [
            "scenario",
            "oracle ids RMSE [m]",
            "own association RMSE [m]",
            "own / oracle",
            "precision",
            "recall",
        ],
    )
    for name in SENSOR_SCENARIOS:
        team = scenario_team(name, appearance=appearance)
        runs = {}
        for association, data in (("oracle", team), ("own", strip_object_ids(team, seed=0))):
            runs[association] = api.run(
                data,
                graph="complete",
                settings={"filter.window": window},
                association=association,
                report=False,
                progress=False,
            ).metrics
        oracle = runs["oracle"]["trajectory_rmse_avg_m"]
        own = runs["own"]["trajectory_rmse_avg_m"]
        scored = runs["own"]["association"]["team"]
        print(
            f"{name:32} {oracle:9.4f} {own:9.4f} {own / oracle:6.3f} "
            f"{scored['precision']:9.3f} {scored['recall']:7.3f}",
            flush=True,
        )
        md.row(
            f"`{name}`",
            f"{oracle:.4f}",
            f"{own:.4f}",
            f"{own / oracle:.3f}",
            f"{scored['precision']:.3f}",
            f"{scored['recall']:.3f}",
        )
    md.end()


#: the teams of ``oracle``: what they are, and how each is made and run
ORACLE_TEAMS = {
    "default": "`make run` team: 5 robots, 150 steps, complete graph, window 10",
    "ring": "15 robots on a ring, 30% link loss, 150 steps, window 10",
    "kitti00": "KITTI 00: 3 robots, objects only, the settings `teamslam run` resolves",
    "grid": "grid city: 4 cars, 400 steps, objects every 8 m along the kerbs, 700 px camera, "
    "complete graph, window 10",
}


def _oracle_team(name: str, window: int, appearance: int = 0, useless: bool = False):
    """``(team with global ids, the same with ids per robot, graph, loss, settings)``; with
    ``appearance`` descriptors of that dimension (all equal when ``useless``)."""
    if name == "kitti00":
        src = DATA / "distributed-msckf" / "kitti00"
        if not src.is_dir():
            raise SystemExit(f"oracle: KITTI 00 not found at {src}")
        team = import_reference(src)
        stripped = import_reference(src, object_ids="per-robot", seed=0)
        return team, stripped, "complete", 0.0, {}
    extra = {"appearance": appearance} if appearance else {}
    if name == "grid":
        team, graph, loss = grid_city_team(seed=0, **extra), "complete", 0.0
    else:
        robots, graph, loss = (5, "complete", 0.0) if name == "default" else (15, "ring", 0.3)
        team = lissajous_team(robots=robots, steps=150, seed=0, **extra)
    stripped = strip_object_ids(team, seed=0)
    if appearance and useless:
        stripped = replace(
            stripped,
            robots=[
                replace(r, object_appearance=np.ones_like(r.object_appearance))
                for r in stripped.robots
            ],
        )
    return team, stripped, graph, loss, {"filter.window": window}


def _warm_up(appearance: int) -> None:
    """Run own association once on a small team, so that the compiled kernels' first call
    (numba compiles them or loads them from its cache) is charged to no measured team."""
    team = strip_object_ids(
        lissajous_team(
            robots=3, steps=30, seed=1, **({"appearance": appearance} if appearance else {})
        ),
        seed=0,
    )
    settings = build_settings(team, flags={"filter.window": 10})
    api.run(team, settings=settings, association="own", report=False, progress=False)


def oracle(
    teams: list[str], window: int, md: Markdown, appearance: int = 0, useless: bool = False
) -> None:
    """Consensus with the data's global ids, with own association, and separate filters."""
    print(
        f"{'team':9} {'oracle m':>9} {'own m':>9} {'ratio':>6} {'separate m':>10} "
        f"{'precision':>9} {'recall':>7} {'held':>5} {'revoked':>7} {'kB/robot-frame':>14} share"
    )
    looks = (
        ""
        if not appearance
        else f", appearance of {appearance} dimensions" + (" all equal" if useless else "")
    )
    md.table(
        "Consensus with the data's object ids (oracle), with own association (ids made per "
        f"robot{looks}), and the separate filters",
        [
            "team",
            "oracle ids RMSE [m]",
            "own association RMSE [m]",
            "own / oracle",
            "separate RMSE [m]",
            "precision",
            "recall",
            "held / revoked",
            "summary kB",
            "association time share",
        ],
        note="RMSE: trajectory RMSE averaged over the robots; precision and recall of own "
        "association against the objects both final maps hold; summary kB: object summaries "
        "sent per robot per frame; time share: the association's share of the robots' step "
        "time.",
    )
    _warm_up(appearance)
    for name in teams:
        team, stripped, graph, loss, settings = _oracle_team(name, window, appearance, useless)
        resolved = build_settings(team, flags=settings)  # calibrated once per dataset
        runs = {}
        for label, data, mode, association, config in (
            ("oracle", team, "consensus", "oracle", resolved),
            ("own", stripped, "consensus", "own", build_settings(stripped, flags=settings)),
            ("separate", team, "separate", None, resolved),
        ):
            runs[label] = api.run(
                data,
                mode=mode,
                graph=graph,
                loss=loss,
                settings=config,
                association=association,
                report=False,
                progress=False,
            ).metrics
        rmse = {k: runs[k]["trajectory_rmse_avg_m"] for k in ("oracle", "own", "separate")}
        scored = runs["own"]["association"]["team"]
        kb = scored["summary_bytes_per_robot_step"] / 1e3
        share = 100 * scored["association_time_share"]
        ratio = rmse["own"] / rmse["oracle"]
        print(
            f"{name:9} {rmse['oracle']:9.4f} {rmse['own']:9.4f} {ratio:6.3f} "
            f"{rmse['separate']:10.4f} {scored['precision']:9.3f} {scored['recall']:7.3f} "
            f"{scored['held']:5d} {scored['revoked']:7d} {kb:14.2f} {share:5.1f}% "
            f"(accepted {scored['accepted']})",
            flush=True,
        )
        md.row(
            ORACLE_TEAMS[name],
            f"{rmse['oracle']:.4f}",
            f"{rmse['own']:.4f}",
            f"{ratio:.3f}",
            f"{rmse['separate']:.4f}",
            f"{scored['precision']:.3f}",
            f"{scored['recall']:.3f}",
            f"{scored['held']} / {scored['revoked']}",
            f"{kb:.2f}",
            f"{share:.1f}%",
        )
    md.end()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "what",
        nargs="*",
        default=["kitti", "sim"],
        choices=("kitti", "sim", "ring", "delay", "scenarios", "oracle"),
    )
    parser.add_argument(
        "--teams",
        nargs="+",
        default=list(ORACLE_TEAMS),
        choices=list(ORACLE_TEAMS),
        help="oracle: the teams",
    )
    parser.add_argument(
        "--appearance",
        type=int,
        default=0,
        metavar="DIM",
        help="oracle, scenarios: simulate the teams with appearance descriptors of DIM dimensions",
    )
    parser.add_argument(
        "--useless-appearance",
        action="store_true",
        help="oracle, with --appearance: every descriptor equal",
    )
    parser.add_argument("--dataset", help="delay: a dataset directory with per-robot ids")
    parser.add_argument("--graph", default="complete", help="delay: communication graph")
    parser.add_argument("--loss", type=float, default=0.0, help="delay: link loss rate")
    parser.add_argument("--window", type=int, default=10, help="delay, scenarios: sliding window")
    parser.add_argument("--frames", type=int, nargs="*", default=[500, 1000, 1500])
    parser.add_argument("--sim-frames", type=int, nargs="*", default=[50, 100])
    add_option(parser)
    args = parser.parse_args()
    if args.appearance < 0:
        parser.error("--appearance: a dimension ≥ 0")
    if args.useless_appearance and not args.appearance:
        parser.error("--useless-appearance needs --appearance DIM")
    if args.markdown is not None and not {"oracle", "scenarios"} & set(args.what):
        parser.error("--markdown: only oracle and scenarios write Markdown")
    md = Markdown(args.markdown)
    if {"kitti", "sim"} & set(args.what):
        _header()
    if "kitti" in args.what:
        kitti(args.frames)
    if "sim" in args.what:
        sim(args.sim_frames)
    if "ring" in args.what:
        ring()
    if "delay" in args.what:
        if not args.dataset:
            parser.error("delay needs --dataset")
        delay(args.dataset, args.graph, args.loss, args.window)
    if "oracle" in args.what:
        oracle(args.teams, args.window, md, args.appearance, args.useless_appearance)
    if "scenarios" in args.what:
        scenarios(args.window, md, args.appearance)
    md.write()


if __name__ == "__main__":
    main()
