"""Accuracy and speed of the distributed MSCKF (paper Table IV, Fig. 3, Fig. 4, Table I).

Run on demand (BLAS pinned to one thread)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py accuracy [--robots 3 5 10 15] [--seeds 3]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py loss [--robots 5 15]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py kitti
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py speed [--robots 5 15]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py scaling [--robots 5 10 25 50 100]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py messages --steps 150 [--robots 5]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py hybrid --steps 150 [--robots 5]

``accuracy`` and ``loss`` use the simulator with the full filter (geometric features and
objects) unless ``--objects-only``; they print separate vs consensus trajectory RMSE and object
error and the relative change. ``accuracy``, ``loss`` and ``kitti`` call the experiments of
``teamslam paper`` (:mod:`teamslam.paper.experiments`): the settings ``teamslam run`` resolves
from the data, plus ``--window`` (and ``--objects-only``). ``speed`` prints mean, median and
p95 time per robot per frame per stage (frame 0 excluded) and the accuracy of the run;
``kitti`` also prints those times.
``scaling`` runs teams of growing size on a random geometric graph (each robot talks to the
robots near it, so its neighbourhood does not grow with the team) and prints the median time
per robot per frame, overall and for consensus, and its ratio to the smallest team.
``hybrid`` compares the plain average with hybrid consensus (``consensus_hybrid``) on the
complete graph (one realisation) and on a ring with 30% link loss and the ideal filter (means
over ``--seeds`` noise realisations): accuracy, mean pose NEES/6, bytes and consensus time.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from teamslam.eval.metrics import team_metrics
from teamslam.msckf import config_for, run_team
from teamslam.paper.experiments import kitti_pair, stage_statistics, team_pairs
from teamslam.paper.experiments import loss_sweep as library_loss_sweep
from teamslam.sim import lissajous_team

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


STAGES = ("consensus", "propagation", "update", "initialisation")


def _settings(window, objects_only=False):
    """The benchmark's flags as settings on top of those resolved from the data."""
    settings = {"window": window}
    if objects_only:
        settings["use_geometric_features"] = False
    return settings


def _print_stages(label, stage_ms):
    """Mean, median and p95 per robot per frame of each stage and of the total, in ms."""
    for stage in (*STAGES, "total"):
        mean, median, p95 = stage_ms[stage]
        print(f"{label:>6} {stage:>15} {mean:8.2f} {median:8.2f} {p95:8.2f}")


def _stage_table(label, result):
    _print_stages(label, stage_statistics(result))


def accuracy(robots, seeds, steps, objects_only, window):
    """Paper Table IV: the library's experiment (``teamslam paper dvi --table 4``)."""
    pairs = team_pairs(robots, seeds, steps, _settings(window, objects_only), progress=False)
    print(
        f"{'robots':>6} {'sep traj':>9} {'con traj':>9} {'change':>7} "
        f"{'sep obj':>8} {'con obj':>8} {'change':>7} {'odometry':>9}"
    )
    for n in robots:
        rows = [
            [
                sep["trajectory_rmse_avg_m"],
                con["trajectory_rmse_avg_m"],
                sep["object_error_avg_m"],
                con["object_error_avg_m"],
                float(np.mean(con["odometry_rmse_m"])),
            ]
            for sep, con in zip(pairs[n]["separate"], pairs[n]["consensus"], strict=True)
        ]
        st, ct, so, co, odo = np.mean(rows, axis=0)
        print(
            f"{n:>6} {st:9.3f} {ct:9.3f} {100 * (ct / st - 1):6.0f}% {so:8.3f} {co:8.3f} "
            f"{100 * (co / so - 1):6.0f}% {odo:9.3f}"
        )


def loss_sweep(robots, steps, objects_only, window):
    """Paper Fig. 4: the library's experiment (``teamslam paper dvi --figure 4``)."""
    rates = (0.0, 0.3, 0.6, 0.9)
    sweep = library_loss_sweep(
        robots, rates, steps, settings=_settings(window, objects_only), progress=False
    )
    print(f"{'robots':>6} {'loss':>5} {'con traj':>9} {'con obj':>8} {'disagree':>9}")
    for n in robots:
        runs = [("sep", sweep[n]["separate"])]
        runs += [(f"{r:.1f}", sweep[n]["consensus"][r]) for r in rates]
        for label, m in runs:
            print(
                f"{n:>6} {label:>5} {m['trajectory_rmse_avg_m']:9.3f} "
                f"{m['object_error_avg_m']:8.3f} {m['object_disagreement_avg_m']:9.3f}"
            )


def kitti(window):
    """Paper Tables I–III and Fig. 3 on KITTI 00: the library's experiment (``teamslam paper
    dvi --table 1``), the two filters one after the other so that the times are alone."""
    src = DATA / "distributed-msckf" / "kitti00"
    if not src.is_dir():
        print(f"KITTI 00 not found at {src}")
        return
    m = kitti_pair(src, settings=_settings(window), workers=1, progress=False).metrics
    print(f"{'':<12} {'robot 1':>8} {'robot 2':>8} {'robot 3':>8} {'avg':>8}  obj err  disagree")
    odometry = m["separate"]["odometry_rmse_m"]
    print(
        f"{'odometry':<12} "
        + " ".join(f"{v:8.2f}" for v in odometry)
        + f" {float(np.mean(odometry)):8.2f}"
    )
    for name in ("separate", "consensus"):
        r = m[name]
        print(
            f"{name:<12} "
            + " ".join(f"{v:8.2f}" for v in r["trajectory_rmse_m"])
            + f" {r['trajectory_rmse_avg_m']:8.2f} {r['object_error_avg_m']:8.2f} "
            f"{r['object_disagreement_avg_m']:8.2f}"
        )
    print(f"\n{'':>6} {'stage':>15} {'mean ms':>8} {'med ms':>8} {'p95 ms':>8}")
    _print_stages("kitti", m["consensus"]["stage_ms"])


def speed(robots, steps, window, objects_only=False):
    print(f"{'robots':>6} {'stage':>15} {'mean ms':>8} {'med ms':>8} {'p95 ms':>8}")
    for n in robots:
        ds = lissajous_team(robots=n, steps=steps, seed=0)
        cfg = config_for(ds, window=window, use_geometric_features=not objects_only)
        begin = time.perf_counter()
        result = run_team(ds, cfg, consensus=True, progress=False)
        wall = time.perf_counter() - begin
        frames = ds.robots[0].frames
        _stage_table(str(n), result)
        print(f"{n:>6} {'team wall/frame':>15} {1e3 * wall / frames:8.2f}")
        m = team_metrics(ds, result)
        print(
            f"{n:>6} {'accuracy':>15} RMSE {m['trajectory_rmse_avg_m']:.6f} "
            f"obj {m['object_error_avg_m']:.6f} disagree {m['object_disagreement_avg_m']:.6f}"
        )


def scaling(robots, steps, window):
    from teamslam.graph import random_geometric

    print(
        f"{'robots':>6} {'degree':>6} {'ms/robot-step':>14} {'consensus ms':>13} "
        f"{'ratio':>6} {'traj RMSE':>10}"
    )
    first = None
    for n in robots:
        ds = lissajous_team(robots=n, steps=steps, seed=0)
        # a radius that keeps the expected degree fixed (above the connectivity threshold
        # ~ln n): the neighbourhood, not the team, sets a robot's work
        degree = max(6.0, 2.0 * np.log(n))
        graph = random_geometric(n, radius=float(np.sqrt(degree / (np.pi * n))), seed=0)
        cfg = config_for(ds, window=window)
        result = run_team(ds, cfg, graph=graph, consensus=True, progress=False)
        times = 1e3 * np.concatenate([f[1:] for f in result.frame_times])
        per_step = float(np.median(times.sum(axis=1)))
        first = first or per_step
        degree = graph.adjacency.sum(axis=1).mean()
        rmse = team_metrics(ds, result)["trajectory_rmse_avg_m"]
        print(
            f"{n:>6} {degree:6.1f} {per_step:14.2f} {np.median(times[:, 0]):13.2f} "
            f"{per_step / first:6.2f} {rmse:10.3f}",
            flush=True,
        )


MESSAGE_VARIANTS = {
    "joint, float64, every object (paper)": {
        "consensus_kl_threshold": 0.0,
        "consensus_float32": False,
    },
    "joint, float64, moved > 1e-3": {"consensus_float32": False},
    "joint, float32, moved > 1e-3 (default)": {},
    "joint, float32, moved > 0.01": {"consensus_kl_threshold": 1e-2},
    "joint, float32, moved > 0.05": {"consensus_kl_threshold": 5e-2},
    "joint, float32, moved > 0.1": {"consensus_kl_threshold": 1e-1},
    "per object, float32": {"consensus_per_object": True},
}


def _bytes_and_consensus_ms(dataset, result):
    """Consensus bytes sent per robot per step, and the median consensus time per robot-step."""
    steps = dataset.n_robots * (dataset.robots[0].frames - 1)
    sent = sum(c["bytes"] for c in result.counters) / steps
    cons = 1e3 * np.median(np.concatenate([f[1:, 0] for f in result.frame_times]))
    return sent, cons


def messages(robots, steps, window):
    """Accuracy and bytes of each kind of consensus message on one team."""
    n = robots[0]
    ds = lissajous_team(robots=n, steps=steps, seed=0)
    print(
        f"{'messages':<40} {'RMSE':>7} {'obj err':>8} {'disagree':>9} {'NEES/6':>7} "
        f"{'B/robot-step':>13} {'consensus ms':>13}"
    )
    for name, settings in MESSAGE_VARIANTS.items():
        cfg = config_for(ds, window=window, **settings)
        result = run_team(ds, cfg, consensus=True, progress=False)
        m = team_metrics(ds, result)
        sent, cons = _bytes_and_consensus_ms(ds, result)
        print(
            f"{name:<40} {m['trajectory_rmse_avg_m']:7.4f} {m['object_error_avg_m']:8.4f} "
            f"{m['object_disagreement_avg_m']:9.4f} {np.mean(m['nees_pose_avg']):7.2f} "
            f"{sent:13.0f} {cons:13.2f}",
            flush=True,
        )


def hybrid(robots, steps, window, seeds):
    """Plain vs hybrid consensus: accuracy, consistency, bytes, consensus time."""
    from teamslam.graph import complete, ring

    n = robots[0]
    print(
        f"{'team':<34} {'consensus':<9} {'RMSE':>7} {'obj err':>8} {'disagree':>9} "
        f"{'NEES/6':>7} {'B/robot-step':>13} {'consensus ms':>13}"
    )
    cases = [
        ("complete, std, 1 realisation", complete(n), 0.0, "std", [None]),
        (f"ring, 30% loss, ideal, {seeds} realisations", ring(n), 0.3, "ideal", range(seeds)),
    ]
    for label, graph, loss, policy, realisations in cases:
        for hybrid_on in (False, True):
            rows = []
            for k in realisations:
                ds = lissajous_team(robots=n, steps=steps, seed=0, noise_seed=k)
                cfg = config_for(
                    ds, window=window, linearization=policy, consensus_hybrid=hybrid_on
                )
                result = run_team(ds, cfg, graph=graph, loss=loss, seed=k or 0, progress=False)
                m = team_metrics(ds, result)
                sent, cons = _bytes_and_consensus_ms(ds, result)
                rows.append(
                    [
                        m["trajectory_rmse_avg_m"],
                        m["object_error_avg_m"],
                        m["object_disagreement_avg_m"],
                        np.mean(m["nees_pose_avg"]),
                        sent,
                        cons,
                    ]
                )
            r = np.mean(rows, axis=0)
            print(
                f"{label:<34} {'hybrid' if hybrid_on else 'plain':<9} {r[0]:7.4f} {r[1]:8.4f} "
                f"{r[2]:9.4f} {r[3]:7.2f} {r[4]:13.0f} {r[5]:13.2f}",
                flush=True,
            )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "what",
        choices=("accuracy", "loss", "kitti", "speed", "scaling", "messages", "hybrid"),
    )
    parser.add_argument("--robots", type=int, nargs="+", default=None)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--window", type=int, default=10)
    parser.add_argument("--objects-only", action="store_true")
    args = parser.parse_args()
    if args.what == "accuracy":
        accuracy(
            args.robots or [3, 5, 10, 15], args.seeds, args.steps, args.objects_only, args.window
        )
    elif args.what == "loss":
        loss_sweep(args.robots or [5, 15], args.steps, args.objects_only, args.window)
    elif args.what == "kitti":
        kitti(args.window)
    elif args.what == "messages":
        messages(args.robots or [5], args.steps, args.window)
    elif args.what == "hybrid":
        hybrid(args.robots or [5], args.steps, args.window, args.seeds)
    elif args.what == "scaling":
        scaling(args.robots or [5, 10, 25, 50, 100], args.steps, args.window)
    else:
        speed(args.robots or [5, 15], args.steps, args.window, args.objects_only)


if __name__ == "__main__":
    main()
