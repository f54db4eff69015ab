"""Accuracy and speed of the distributed MSCKF (paper Table IV, Fig. 3, Fig. 4, Table I).

Run on demand (BLAS pinned to one thread)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py accuracy [--robots 3 5 10 15] [--seeds 3]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py loss [--robots 5 15]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py kitti
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py speed [--robots 5 15]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py scaling [--robots 5 10 25 50 100]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py messages --steps 150 [--robots 5]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py hybrid --steps 150 [--robots 5]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py iterations --steps 100 [--robots 5]
    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py bounded {team,kitti} [--set k=v ...]

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
``hybrid`` compares the plain average with hybrid consensus (``consensus.rule = hybrid``) on the
complete graph (one realisation) and on a ring with 30% link loss and the ideal filter (means
over ``--seeds`` noise realisations): accuracy, mean pose NEES/6, bytes and consensus time.
``iterations`` runs one team with ``consensus.iterations`` 1, 2 and 3, plain and on information
increments, on a ring and on the complete graph, and prints per robot-step the CPU time of the
whole run (process time) and of consensus (its share of the stage times), the bytes sent, and
the accuracy, pose NEES/6 and object disagreement; ratios are to ``L = 1`` of the same row.
``bounded`` runs one team twice in one process — the paper's consensus set and the bounded one
(``consensus.set = active`` with the ``--set`` overrides) — and prints the median time per
robot-step of each stage, bytes per robot-step and accuracy of both, and the ratio of the
published code's time to each (``team``: ``--robots`` robots, objects only, ``--steps``;
``kitti``: KITTI 00). With ``--published-code DIR`` (a checkout of the paper's code: ``run.py``,
``src/``, ``params/``) it also writes the same team in the published layout, runs that code's
``run.py`` on it in a subprocess (single-threaded BLAS; ``--published-python`` names an
interpreter with its packages) and prints the CPU time per robot-step of both — the child's from
``resource.getrusage``, less the CPU time of a child that only imports its modules; ours the
process time of the whole in-process run — and their ratio, all from this one run. Without it
the ratio is to a figure recorded earlier (``PUBLISHED_MS``), labelled as such. Both runs of
ours follow a warm-up on a small team (imports and compiled kernels are not timed); a run with
consensus off gives the filter's own CPU time, the bound on any ratio consensus alone can reach.
``--baseline DIR`` (another checkout of this library) runs the same team with the paper's set
through ``DIR/src`` in a subprocess, warmed up alike, for ours before and after in one run::

    OPENBLAS_NUM_THREADS=1 python benchmarks/msckf_team.py bounded team --robots 15 --steps 100 \
        --published-code DIR --published-python PYTHON [--baseline CHECKOUT]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from _markdown import Markdown, add_option
from teamslam.datasets import import_reference
from teamslam.eval.metrics import team_metrics
from teamslam.msckf import config_for, run_team
from teamslam.paper.experiments import kitti_pair, stage_statistics, team_pairs
from teamslam.paper.experiments import loss_sweep as library_loss_sweep
from teamslam.sim import lissajous_team

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


STAGES = ("consensus", "propagation", "update", "initialisation")


def _settings(window, objects_only=False):
    """The benchmark's flags as settings on top of those resolved from the data."""
    settings = {"filter.window": window}
    if objects_only:
        settings["filter.use_geometric_features"] = False
    return settings


STAGE_COLUMNS = ["team", "stage", "mean [ms]", "median [ms]", "p95 [ms]"]


def _print_stages(label, stage_ms, md):
    """Mean, median and p95 per robot per frame of each stage and of the total, in ms."""
    for stage in (*STAGES, "total"):
        mean, median, p95 = stage_ms[stage]
        print(f"{label:>6} {stage:>15} {mean:8.2f} {median:8.2f} {p95:8.2f}")
        md.row(label, stage, f"{mean:.2f}", f"{median:.2f}", f"{p95:.2f}")


def _stage_table(label, result, md):
    _print_stages(label, stage_statistics(result), md)


def accuracy(robots, seeds, steps, objects_only, window, md):
    """Paper Table IV: the library's experiment (``teamslam paper dvi --table 4``)."""
    pairs = team_pairs(robots, seeds, steps, _settings(window, objects_only), progress=False)
    md.table(
        f"Separate vs consensus, simulated teams ({steps} steps, {seeds} seed(s), window "
        f"{window}{', objects only' if objects_only else ''}; means over the seeds)",
        [
            "robots",
            "separate trajectory RMSE [m]",
            "consensus trajectory RMSE [m]",
            "change",
            "separate object error [m]",
            "consensus object error [m]",
            "change",
            "odometry RMSE [m]",
        ],
    )
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
        md.row(
            n,
            f"{st:.3f}",
            f"{ct:.3f}",
            f"{100 * (ct / st - 1):.0f}%",
            f"{so:.3f}",
            f"{co:.3f}",
            f"{100 * (co / so - 1):.0f}%",
            f"{odo:.3f}",
        )
    md.end()


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


def kitti(window, md):
    """Paper Tables I–III and Fig. 3 on KITTI 00: the library's experiment (``teamslam paper
    dvi --table 1``), the two filters one after the other so that the times are alone."""
    src = DATA / "distributed-msckf" / "kitti00"
    if not src.is_dir():
        print(f"KITTI 00 not found at {src}")
        return
    m = kitti_pair(src, settings=_settings(window), workers=1, progress=False).metrics
    print(f"{'':<12} {'robot 1':>8} {'robot 2':>8} {'robot 3':>8} {'avg':>8}  obj err  disagree")
    md.table(
        f"KITTI 00, three robots, objects only, window {window}: trajectory RMSE per robot [m]",
        ["", "robot 1", "robot 2", "robot 3", "average", "object error", "disagreement"],
    )
    odometry = m["separate"]["odometry_rmse_m"]
    print(
        f"{'odometry':<12} "
        + " ".join(f"{v:8.2f}" for v in odometry)
        + f" {float(np.mean(odometry)):8.2f}"
    )
    md.row("odometry", *(f"{v:.2f}" for v in odometry), f"{float(np.mean(odometry)):.2f}", "", "")
    for name in ("separate", "consensus"):
        r = m[name]
        print(
            f"{name:<12} "
            + " ".join(f"{v:8.2f}" for v in r["trajectory_rmse_m"])
            + f" {r['trajectory_rmse_avg_m']:8.2f} {r['object_error_avg_m']:8.2f} "
            f"{r['object_disagreement_avg_m']:8.2f}"
        )
        md.row(
            name,
            *(f"{v:.2f}" for v in r["trajectory_rmse_m"]),
            f"{r['trajectory_rmse_avg_m']:.2f}",
            f"{r['object_error_avg_m']:.2f}",
            f"{r['object_disagreement_avg_m']:.2f}",
        )
    md.end()
    print(f"\n{'':>6} {'stage':>15} {'mean ms':>8} {'med ms':>8} {'p95 ms':>8}")
    md.table("KITTI 00, consensus: time per robot per frame (frame 0 excluded)", STAGE_COLUMNS)
    _print_stages("kitti", m["consensus"]["stage_ms"], md)
    md.end()


def speed(robots, steps, window, md, objects_only=False):
    print(f"{'robots':>6} {'stage':>15} {'mean ms':>8} {'med ms':>8} {'p95 ms':>8}")
    accuracy = []
    md.table(
        f"Time per robot per frame by stage (frame 0 excluded): Lissajous teams, {steps} steps, "
        f"window {window}, {'objects only' if objects_only else 'features and objects'}, "
        "complete graph, consensus",
        STAGE_COLUMNS,
    )
    for n in robots:
        ds = lissajous_team(robots=n, steps=steps, seed=0)
        cfg = config_for(
            ds, {"filter.window": window, "filter.use_geometric_features": not objects_only}
        )
        begin = time.perf_counter()
        result = run_team(ds, cfg, consensus=True, progress=False)
        wall = time.perf_counter() - begin
        frames = ds.robots[0].frames
        _stage_table(f"{n} robots", result, md)
        print(f"{n:>6} {'team wall/frame':>15} {1e3 * wall / frames:8.2f}")
        m = team_metrics(ds, result)
        print(
            f"{n:>6} {'accuracy':>15} RMSE {m['trajectory_rmse_avg_m']:.6f} "
            f"obj {m['object_error_avg_m']:.6f} disagree {m['object_disagreement_avg_m']:.6f}"
        )
        accuracy.append((n, 1e3 * wall / frames, m))
    md.end()
    md.table(
        "The same runs: wall time per team frame and accuracy",
        [
            "robots",
            "team wall per frame [ms]",
            "trajectory RMSE [m]",
            "object error [m]",
            "disagreement [m]",
        ],
    )
    for n, wall, m in accuracy:
        md.row(
            n,
            f"{wall:.1f}",
            f"{m['trajectory_rmse_avg_m']:.6f}",
            f"{m['object_error_avg_m']:.6f}",
            f"{m['object_disagreement_avg_m']:.6f}",
        )
    md.end()


def scaling(robots, steps, window, md):
    from teamslam.graph import random_geometric

    md.table(
        f"Team size on a random geometric graph (expected degree max(6, 2 ln n)); {steps} steps, "
        f"window {window}, features and objects; medians per robot-step",
        [
            "robots",
            "mean degree",
            "ms per robot-step",
            "consensus ms",
            "ratio to first",
            "trajectory RMSE [m]",
        ],
    )
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
        cfg = config_for(ds, {"filter.window": window})
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
        md.row(
            n,
            f"{degree:.1f}",
            f"{per_step:.2f}",
            f"{np.median(times[:, 0]):.2f}",
            f"{per_step / first:.2f}",
            f"{rmse:.3f}",
        )
    md.end()


MESSAGE_VARIANTS = {
    "joint, float64, every object (paper)": {
        "consensus.kl_threshold": 0.0,
        "consensus.float32": False,
    },
    "joint, float64, moved > 1e-3": {"consensus.float32": False},
    "joint, float32, moved > 1e-3 (default)": {},
    "joint, float32, moved > 0.01": {"consensus.kl_threshold": 1e-2},
    "joint, float32, moved > 0.05": {"consensus.kl_threshold": 5e-2},
    "joint, float32, moved > 0.1": {"consensus.kl_threshold": 1e-1},
    "per object, float32": {"consensus.per_object": True},
}


def _bytes_and_consensus_ms(dataset, result):
    """Consensus bytes sent per robot per step, and the median consensus time per robot-step."""
    steps = dataset.n_robots * (dataset.robots[0].frames - 1)
    sent = sum(c["bytes"] for c in result.counters) / steps
    cons = 1e3 * np.median(np.concatenate([f[1:, 0] for f in result.frame_times]))
    return sent, cons


def messages(robots, steps, window, md):
    """Accuracy and bytes of each kind of consensus message on one team."""
    n = robots[0]
    ds = lissajous_team(robots=n, steps=steps, seed=0)
    md.table(
        f"Consensus messages on one Lissajous team ({n} robots, {steps} steps, seed 0, window "
        f"{window}, complete graph)",
        [
            "messages",
            "trajectory RMSE [m]",
            "object error [m]",
            "disagreement [m]",
            "pose NEES/6",
            "bytes per robot-step",
            "consensus median [ms]",
        ],
    )
    print(
        f"{'messages':<40} {'RMSE':>7} {'obj err':>8} {'disagree':>9} {'NEES/6':>7} "
        f"{'B/robot-step':>13} {'consensus ms':>13}"
    )
    for name, settings in MESSAGE_VARIANTS.items():
        cfg = config_for(ds, {"filter.window": window, **settings})
        result = run_team(ds, cfg, consensus=True, progress=False)
        m = team_metrics(ds, result)
        sent, cons = _bytes_and_consensus_ms(ds, result)
        print(
            f"{name:<40} {m['trajectory_rmse_avg_m']:7.4f} {m['object_error_avg_m']:8.4f} "
            f"{m['object_disagreement_avg_m']:9.4f} {np.mean(m['nees_pose_avg']):7.2f} "
            f"{sent:13.0f} {cons:13.2f}",
            flush=True,
        )
        md.row(
            name,
            f"{m['trajectory_rmse_avg_m']:.4f}",
            f"{m['object_error_avg_m']:.4f}",
            f"{m['object_disagreement_avg_m']:.4f}",
            f"{np.mean(m['nees_pose_avg']):.2f}",
            f"{sent:,.0f}",
            f"{cons:.2f}",
        )
    md.end()


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
                    ds,
                    {
                        "filter.window": window,
                        "filter.linearization": policy,
                        "consensus.rule": "hybrid" if hybrid_on else "average",
                    },
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


def iterations(robots, steps, window):
    """``consensus.iterations`` 1, 2, 3: CPU and bytes per robot-step, accuracy, consistency."""
    from teamslam.graph import complete, ring

    n = robots[0]
    ds = lissajous_team(robots=n, steps=steps, seed=0)
    robot_steps = n * (ds.robots[0].frames - 1)
    print(
        f"{'graph':<9} {'mode':<11} {'L':>2} {'CPU ms':>8} {'ratio':>6} {'cons ms':>8} "
        f"{'B/robot-step':>13} {'ratio':>6} {'RMSE':>7} {'NEES/6':>7} {'disagree':>9}"
    )
    for graph in (ring(n), complete(n)):
        for mode, settings in (("plain", {}), ("increments", {"consensus.rule": "increments"})):
            first = None
            for count in (1, 2, 3):
                cfg = config_for(
                    ds, {"filter.window": window, "consensus.iterations": count, **settings}
                )
                begin = time.process_time()
                result = run_team(ds, cfg, graph=graph, progress=False)
                cpu = 1e3 * (time.process_time() - begin) / robot_steps
                stages = np.sum([[t[k] for k in STAGES] for t in result.timings], axis=0)
                cons = cpu * stages[0] / stages.sum()  # consensus's share of the CPU time
                sent = sum(c["bytes"] for c in result.counters) / robot_steps
                first = first or (cpu, sent)
                m = team_metrics(ds, result)
                print(
                    f"{graph.name:<9} {mode:<11} {count:>2} {cpu:8.2f} {cpu / first[0]:6.2f} "
                    f"{cons:8.2f} {sent:13.0f} {sent / first[1]:6.2f} "
                    f"{m['trajectory_rmse_avg_m']:7.4f} {np.mean(m['nees_pose_avg']):7.2f} "
                    f"{m['object_disagreement_avg_m']:9.4f}",
                    flush=True,
                )


#: ms per robot-step of the published code on these runs (same machine, single-threaded BLAS),
#: *recorded* when the speed work began — a fallback printed only without ``--published-code``
PUBLISHED_MS = {"team": 19.9, "kitti": 25.0}

#: the published code's parameter file for each team (in its ``params/`` directory) and the name
#: and sequence it is run under; ``simulated`` makes its ``run.py`` invert the odometry
PUBLISHED_LAYOUT = {
    "team": ("simulated_nrobot_15.yaml", "simulated", "team"),
    "kitti": ("kitti_00.yaml", "kitti", "00"),
}

SINGLE_THREAD = {
    name: "1"
    for name in (
        "OPENBLAS_NUM_THREADS",
        "OMP_NUM_THREADS",
        "MKL_NUM_THREADS",
        "NUMBA_NUM_THREADS",
        "VECLIB_MAXIMUM_THREADS",
    )
}


def _published_params(what, checkout, cfg, ds, window):
    """The published code's parameters for this team: its own file for the kind of data, with
    consensus on, objects only (``use_msckf`` off; the teams here carry no geometric tracks it
    could use), no result file, a window of ``filter.window`` poses (as ours), and for the simulated
    team its reprojection gates scaled from normalised coordinates (its simulated teams have
    ``K = I``) to this camera's pixels, with the noise and depth range of the sensor model the
    data was made with."""
    import yaml

    name = PUBLISHED_LAYOUT[what][0]
    source = Path(checkout) / "params" / name
    if not source.is_file():
        raise SystemExit(f"--published-code: {source} not found (the checkout lacks params/{name})")
    params = yaml.safe_load(source.read_text())
    params.update(consensus_average=True, use_msckf=False, save_result=False, max_num_cam=window)
    if what == "team":
        # its file is for data in normalised coordinates (K = I), where its two reprojection
        # gates are in those units: here they are scaled to this camera's pixels; the noise
        # and depth range are the sensor model the data was made with
        fx = float(ds.calibration.camera.intrinsics[0, 0])
        params.update(
            motion_noise=float(np.mean(np.square(cfg.filter.odometry_std))),
            obj_obs_noise=float((cfg.filter.object_std / fx) ** 2),
            obj_init_fnum_thre=int(cfg.objects.init_observations),
            obj_init_dist_min_thre=float(cfg.objects.min_depth),
            obj_init_dist_max_thre=float(cfg.objects.max_depth),
            obj_init_reproj_thre=float(params["obj_init_reproj_thre"]) * fx,
            obj_update_reproj_thre=float(params["obj_update_reproj_thre"]) * fx,
        )
    return params


def run_published_code(what, ds, cfg, window, checkout, python):
    """Run the published code (``run.py`` of a checkout) on ``ds`` in a subprocess.

    The team is written in the published layout (:func:`teamslam.datasets.export_reference`, an
    empty geometric-track file when the team has none) in a temporary working directory with the
    parameters of :func:`_published_params`; ``run.py`` runs there with single-threaded BLAS and
    a non-interactive plotting backend. Returns the child's CPU seconds (user + system, from
    ``resource.getrusage(RUSAGE_CHILDREN)``), the CPU seconds of a child that only imports its
    modules, its robot-steps, and the last lines it printed.
    """
    import pickle
    import resource
    import subprocess
    import tempfile

    import yaml

    from teamslam.datasets import export_reference

    checkout = Path(checkout).resolve()
    if not (checkout / "run.py").is_file():
        raise SystemExit(f"--published-code: no run.py in {checkout}")
    params = _published_params(what, checkout, cfg, ds, window)
    _, dataset, sequence = PUBLISHED_LAYOUT[what]
    env = {**os.environ, **SINGLE_THREAD, "MPLBACKEND": "Agg"}

    def child_cpu(args, cwd):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True)
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if done.returncode != 0:
            tail = "\n".join(done.stderr.strip().splitlines()[-15:])
            raise SystemExit(f"the published code failed ({' '.join(args)}):\n{tail}")
        spent = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        return spent, done.stdout

    with tempfile.TemporaryDirectory(prefix="published-") as work:
        data = Path(work) / "Data" / dataset / sequence
        export_reference(ds, data, inverted_odometry=dataset == "simulated")
        if not (data / "geo_features_messages").exists():
            empty = [[{} for _ in range(r.frames)] for r in ds.robots]
            (data / "geo_features_messages").write_bytes(pickle.dumps(empty))
        (Path(work) / "params").mkdir()
        (Path(work) / "params" / f"{dataset}_{sequence}.yaml").write_text(yaml.safe_dump(params))
        imports = "import src.agent, matplotlib.pyplot, tqdm, yaml"
        startup, _ = child_cpu([python, "-c", imports], cwd=checkout)
        cpu, out = child_cpu(
            [python, str(checkout / "run.py"), "--dataset", dataset, "--data_id", sequence], work
        )
    steps = sum(r.odometry.shape[0] for r in ds.robots)
    return cpu, startup, steps, _published_counts(out), params


def _published_counts(out):
    """Totals over robots of what the published ``run.py`` prints at the end."""
    import re

    patterns = {
        "objects in the state": r"robot \d+ has (\d+) objects",
        "steps with a known object observed": r"robot \d+ has (\d+) EKF update chances",
        "steps with an object update": r"robot \d+ EKF updated (\d+) times",
        "consensus averages applied": r"robot \d+ fused (\d+) times",
    }
    return {
        what: sum(int(n) for n in re.findall(pattern, out)) for what, pattern in patterns.items()
    }


#: The warm-up team run before any timed run, here and in a baseline's subprocess: long enough
#: that objects are mapped and averaged, so every compiled kernel is compiled (or loaded from
#: its cache) before the clock starts — a 2-robot, 5-step team left the consensus kernels to
#: compile inside the timed run of a fresh checkout (measured: 13.6 against 10.3 ms per step)
WARM_ROBOTS, WARM_STEPS = 3, 30

BASELINE_CHILD = f"""
import json, sys, time
from pathlib import Path
from teamslam.datasets import import_reference
from teamslam.msckf import config_for, run_team
from teamslam.sim import lissajous_team
what, robots, steps, window, settings, kitti = json.loads(sys.argv[1])
warm = lissajous_team(robots={WARM_ROBOTS}, steps={WARM_STEPS}, seed=1)
flags = {{"filter.window": window, **settings}}
run_team(warm, config_for(warm, flags), consensus=True, progress=False)
ds = import_reference(Path(kitti)) if what == "kitti" else lissajous_team(robots, steps, seed=0)
cfg = config_for(ds, flags)
begin = time.process_time()
run_team(ds, cfg, consensus=True, progress=False)
spent = time.process_time() - begin
print(json.dumps({{"ms": 1e3 * spent / sum(r.frames for r in ds.robots)}}))
"""


def run_baseline(checkout, what, robots, steps, window, settings, kitti):
    """CPU milliseconds per robot-step of the same team run by another checkout of this
    library (``checkout/src`` first on the path) in a subprocess, warmed up on a small team
    first as the in-process runs are (its imports and compiled kernels not counted)."""
    import json
    import subprocess

    src = Path(checkout).resolve() / "src"
    if not (src / "teamslam").is_dir():
        raise SystemExit(f"--baseline: no src/teamslam in {checkout}")
    env = {**os.environ, **SINGLE_THREAD, "PYTHONPATH": str(src)}
    args = json.dumps([what, robots, steps, window, settings, str(kitti)])
    done = subprocess.run(
        [sys.executable, "-c", BASELINE_CHILD, args], env=env, capture_output=True, text=True
    )
    if done.returncode != 0:
        tail = "\n".join(done.stderr.strip().splitlines()[-15:])
        raise SystemExit(f"the baseline run failed:\n{tail}")
    return json.loads(done.stdout.strip().splitlines()[-1])["ms"]


def bounded(
    what, robots, steps, window, overrides, published_code=None, python=None, baseline=None
):
    """The paper's consensus set against the bounded one, on one team, in one process (and the
    published code on the same team in a subprocess, given its checkout)."""
    from msckf_long import ConsensusCpu  # the benchmarks' directory is on the path

    if what == "kitti":
        src = Path(os.environ.get("TEAMSLAM_DATA", DATA)) / "distributed-msckf" / "kitti00"
        if not src.is_dir():
            print(f"KITTI 00 not found at {src}")
            return
        ds = import_reference(src)
        base = {}
    else:
        ds = lissajous_team(robots=robots, steps=steps, seed=0)
        base = {"filter.use_geometric_features": False}
    print(f"{what}: {ds.n_robots} robots, {ds.robots[0].frames} frames; bounded: {overrides}")
    # imports and compiled kernels, not timed
    warm = lissajous_team(robots=WARM_ROBOTS, steps=WARM_STEPS, seed=1)
    run_team(
        warm, config_for(warm, {"filter.window": window, **base}), consensus=True, progress=False
    )
    rows, work = {}, {}
    for name, extra in (("all", {}), ("active", {"consensus.set": "active", **overrides})):
        cfg = config_for(ds, {"filter.window": window, **base, **extra})
        cpu = ConsensusCpu()
        begin = time.process_time()
        try:
            result = run_team(ds, cfg, consensus=True, progress=False)
        finally:
            cpu.close()
        process_ms = 1e3 * (time.process_time() - begin) / sum(r.frames for r in ds.robots)
        work[name] = (
            sum(len(ids) for ids in result.object_ids),
            sum(c.get("updates", 0) for c in result.counters),
        )
        times = 1e3 * np.concatenate([f[1:] for f in result.frame_times])
        m = team_metrics(ds, result)
        sent, _ = _bytes_and_consensus_ms(ds, result)
        consensus_cpu = 1e3 * np.median([v for (_, t), v in cpu.spent.items() if t > 0])
        rows[name] = (
            np.median(times, axis=0),
            np.median(times.sum(axis=1)),
            sent,
            m,
            consensus_cpu,
            process_ms,
        )
    print(
        f"{'set':<7} "
        + " ".join(f"{s:>14}" for s in (*STAGES, "total"))
        + f" {'B/step':>9} {'consensus CPU':>14}"
    )
    for name, (stages, total, sent, _, consensus_cpu, _) in rows.items():
        print(
            f"{name:<7} "
            + " ".join(f"{v:14.2f}" for v in (*stages, total))
            + f" {sent:9.0f} {consensus_cpu:14.2f}"
        )
    a, b = rows["all"][1], rows["active"][1]
    print(
        f"active/all total {b / a:.3f}; consensus {rows['active'][0][0] / rows['all'][0][0]:.3f}"
        f"; consensus CPU {rows['active'][4] / rows['all'][4]:.3f}"
    )
    ours = {name: row[5] for name, row in rows.items()}
    cfg = config_for(ds, {"filter.window": window, **base})
    begin = time.process_time()
    run_team(ds, cfg, consensus=False, progress=False)
    alone = 1e3 * (time.process_time() - begin) / sum(r.frames for r in ds.robots)
    print(
        f"CPU per robot-step without consensus (each robot's filter alone): {alone:.2f} ms; "
        f"consensus costs the rest (all {ours['all'] - alone:.2f} ms)"
    )
    if baseline is not None:
        before = run_baseline(
            baseline, what, robots, steps, window, base, src if what == "kitti" else ""
        )
        print(
            f"baseline {baseline} (same team, this run, subprocess): {before:.2f} ms per "
            f"robot-step (all); before/after ×{before / ours['all']:.2f}"
        )
    print(
        "CPU per robot-step, whole run (process time): "
        + ", ".join(f"{name} {ms:.2f} ms" for name, ms in ours.items())
    )
    print(
        "ours, totals over robots: "
        + "; ".join(
            f"{name}: objects in the state {n}, steps with an update {u}"
            for name, (n, u) in work.items()
        )
    )
    if published_code is not None:
        cfg = config_for(ds, {"filter.window": window, **base})
        cpu, startup, robot_steps, tail, params = run_published_code(
            what, ds, cfg, window, published_code, python or sys.executable
        )
        theirs = 1e3 * (cpu - startup) / robot_steps
        print(
            f"published code, same team, this run: {cpu:.1f} s CPU (its imports alone "
            f"{startup:.1f} s, subtracted) over {robot_steps} robot-steps = {theirs:.2f} ms per "
            f"robot-step; window {params['max_num_cam']}, consensus on, objects only"
        )
        print(
            "published code, totals over robots: "
            + ", ".join(f"{what} {count}" for what, count in tail.items())
        )
        print(
            "published code / ours (CPU per robot-step, one run): "
            + ", ".join(f"×{theirs / ms:.2f} ({name})" for name, ms in ours.items())
            + (f", ×{theirs / before:.2f} (baseline, all)" if baseline is not None else "")
            + f"; at most ×{theirs / alone:.2f} with consensus free"
        )
    elif what == "kitti" or (robots == 15 and steps == 100):
        published = PUBLISHED_MS.get(what if what == "kitti" else "team")
        print(
            f"published code {published} ms (recorded, not this run; median wall time): "
            f"×{published / a:.2f} (all), ×{published / b:.2f} (active)"
        )
    keys = ("trajectory_rmse_avg_m", "object_error_avg_m", "object_disagreement_avg_m")
    for name, (*_, m, _, _) in rows.items():
        print(f"{name:<7} RMSE/obj/disagree " + " ".join(f"{m[k]:.5f}" for k in keys))
    ratio = [rows["active"][3][k] / rows["all"][3][k] for k in keys]
    print("ratio   " + " ".join(f"{r:.3f}" for r in ratio))


#: the subcommands that write ``--markdown``
MARKDOWN = ("accuracy", "kitti", "speed", "scaling", "messages")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "what",
        choices=(
            "accuracy",
            "loss",
            "kitti",
            "speed",
            "scaling",
            "messages",
            "hybrid",
            "iterations",
            "bounded",
        ),
    )
    parser.add_argument("team", nargs="?", default="team", choices=("team", "kitti"))
    parser.add_argument("--set", nargs="*", default=[], help="bounded-set settings (bounded)")
    parser.add_argument("--robots", type=int, nargs="+", default=None)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--window", type=int, default=10)
    parser.add_argument("--objects-only", action="store_true")
    parser.add_argument(
        "--published-code",
        type=Path,
        default=None,
        help="bounded: a checkout of the published code (run.py, src/, params/) to run on the "
        "same team in a subprocess",
    )
    parser.add_argument(
        "--baseline",
        type=Path,
        default=None,
        help="bounded: another checkout of this library (its src/) to run the same team with "
        "the paper's set in a subprocess: ours before and after in one run",
    )
    parser.add_argument(
        "--published-python",
        default=None,
        help="bounded: the Python that runs the published code (default: this one)",
    )
    add_option(parser)
    args = parser.parse_args()
    if args.markdown is not None and args.what not in MARKDOWN:
        parser.error(f"--markdown: {args.what} writes no Markdown (only {', '.join(MARKDOWN)})")
    md = Markdown(args.markdown)
    if args.what == "bounded":
        from teamslam.msckf.settings.sources import parse_assignments

        bounded(
            args.team,
            (args.robots or [15])[0],
            args.steps,
            args.window,
            parse_assignments(args.set),
            args.published_code,
            args.published_python,
            args.baseline,
        )
    elif args.what == "accuracy":
        accuracy(
            args.robots or [3, 5, 10, 15],
            args.seeds,
            args.steps,
            args.objects_only,
            args.window,
            md,
        )
    elif args.what == "loss":
        loss_sweep(args.robots or [5, 15], args.steps, args.objects_only, args.window)
    elif args.what == "kitti":
        kitti(args.window, md)
    elif args.what == "messages":
        messages(args.robots or [5], args.steps, args.window, md)
    elif args.what == "hybrid":
        hybrid(args.robots or [5], args.steps, args.window, args.seeds)
    elif args.what == "iterations":
        iterations(args.robots or [5], args.steps, args.window)
    elif args.what == "scaling":
        scaling(args.robots or [5, 10, 25, 50, 100], args.steps, args.window, md)
    else:
        speed(args.robots or [5, 15], args.steps, args.window, md, args.objects_only)
    md.write()


if __name__ == "__main__":
    main()
