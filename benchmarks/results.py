"""Every table of the results pages, regenerated: each command that writes one, run in turn.

Run from the repository root (BLAS pinned to one thread for every command)::

    python benchmarks/results.py                 # every command, one after another
    python benchmarks/results.py --list          # the commands and the files they write
    python benchmarks/results.py --only speed-stages paper

Each command writes its own Markdown under ``docs/results/generated/`` (a benchmark's
``--markdown FILE``, ``teamslam paper … --out DIR``), headed by the commit, date, the exact
command and the machine (:mod:`teamslam.eval.provenance`); the pages under ``docs/results/``
include those files. :data:`COMMANDS` is the one list of them: ``tests/test_results.py`` checks
that every generated file names its command from it. The sizes are those the pages were measured
with: ``paper`` runs the paper's sizes for the tables on real data and the FEJ Monte Carlo (KITTI
00 whole, 100 runs), ``paper-sim`` the simulated teams at ``--quick`` sizes with 150 steps per
robot (the full sizes of ``teamslam paper all`` took 19.5 min on two idle workers, more than a
shared machine gave); change them here, rerun, commit the generated files.
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GENERATED = "docs/results/generated"

#: name → the command (as run from the repository root) and what it writes
COMMANDS: dict[str, tuple[str, str]] = {
    "paper": (
        "teamslam paper all --runs 100 --workers 1 --data ../shared/data --only dvi-table-1 "
        "dvi-table-2 dvi-table-3 fej-table-1 fej-table-2 fej-figure-4 fej-figure-5 fej-figure-6 "
        f"fej-victoria-park --out {GENERATED}/paper",
        f"{GENERATED}/paper",
    ),
    "paper-sim": (
        "teamslam paper all --quick --steps 150 --workers 1 --data ../shared/data --only "
        f"dvi-table-4 dvi-figure-4 --out {GENERATED}/paper-sim",
        f"{GENERATED}/paper-sim",
    ),
    "fej-environments": (
        "python benchmarks/fej_environments.py --data ../shared/data --runs 100 --layouts 10 "
        "--workers 2 "
        f"--markdown {GENERATED}/fej-environments.md",
        f"{GENERATED}/fej-environments.md",
    ),
    "consensus-default-team": (
        "python benchmarks/msckf_team.py accuracy --robots 5 --seeds 1 --steps 150 "
        f"--markdown {GENERATED}/consensus-default-team.md",
        f"{GENERATED}/consensus-default-team.md",
    ),
    "consensus-messages": (
        "python benchmarks/msckf_team.py messages --robots 5 --steps 150 "
        f"--markdown {GENERATED}/consensus-messages.md",
        f"{GENERATED}/consensus-messages.md",
    ),
    "speed-stages": (
        "python benchmarks/msckf_team.py speed --robots 5 15 --steps 100 "
        f"--markdown {GENERATED}/speed-stages.md",
        f"{GENERATED}/speed-stages.md",
    ),
    "speed-kitti": (
        f"python benchmarks/msckf_team.py kitti --markdown {GENERATED}/speed-kitti.md",
        f"{GENERATED}/speed-kitti.md",
    ),
    "speed-scaling": (
        "python benchmarks/msckf_team.py scaling --robots 5 10 25 50 --steps 60 "
        f"--markdown {GENERATED}/speed-scaling.md",
        f"{GENERATED}/speed-scaling.md",
    ),
    "association-default": (
        "python benchmarks/association.py oracle --teams default "
        f"--markdown {GENERATED}/association-default.md",
        f"{GENERATED}/association-default.md",
    ),
    "association-ring": (
        "python benchmarks/association.py oracle --teams ring "
        f"--markdown {GENERATED}/association-ring.md",
        f"{GENERATED}/association-ring.md",
    ),
    "association-appearance": (
        "python benchmarks/association.py oracle --teams ring default --appearance 32 "
        f"--markdown {GENERATED}/association-appearance.md",
        f"{GENERATED}/association-appearance.md",
    ),
    "association-appearance-useless": (
        "python benchmarks/association.py oracle --teams ring default --appearance 32 "
        f"--useless-appearance --markdown {GENERATED}/association-appearance-useless.md",
        f"{GENERATED}/association-appearance-useless.md",
    ),
    "association-grid": (
        "python benchmarks/association.py oracle --teams grid "
        f"--markdown {GENERATED}/association-grid.md",
        f"{GENERATED}/association-grid.md",
    ),
    "association-kitti": (
        "python benchmarks/association.py oracle --teams kitti00 "
        f"--markdown {GENERATED}/association-kitti.md",
        f"{GENERATED}/association-kitti.md",
    ),
    "tracking-sim": (
        "python benchmarks/tracking.py --seeds 0 --loop-closure both "
        f"--markdown {GENERATED}/tracking-sim.md",
        f"{GENERATED}/tracking-sim.md",
    ),
    "tracking-normalised": (
        "python benchmarks/tracking.py --no-sim --scenarios normalised-0.005-objects "
        "--robots 15 --steps 150 --seeds 0 --loop-closure off "
        f"--markdown {GENERATED}/tracking-normalised.md",
        f"{GENERATED}/tracking-normalised.md",
    ),
    "appearance-roc": (
        "python benchmarks/appearance_roc.py --robots 3 --steps 120 --every 6 --seed 1 "
        f"--street-render results/street-render --markdown {GENERATED}/appearance-roc.md",
        f"{GENERATED}/appearance-roc.md",
    ),
    "box-stereo": (
        f"python benchmarks/box_stereo.py --frames 40 --markdown {GENERATED}/box-stereo.md",
        f"{GENERATED}/box-stereo.md",
    ),
    "association-scenarios": (
        "python benchmarks/association.py scenarios "
        f"--markdown {GENERATED}/association-scenarios.md",
        f"{GENERATED}/association-scenarios.md",
    ),
    "association-scenarios-appearance": (
        "python benchmarks/association.py scenarios --appearance 32 "
        f"--markdown {GENERATED}/association-scenarios-appearance.md",
        f"{GENERATED}/association-scenarios-appearance.md",
    ),
    "active-budget": (
        "python benchmarks/msckf_long.py budget --frames 1000 --budgets 80 160 --listening 80 "
        f"--markdown {GENERATED}/active-budget.md",
        f"{GENERATED}/active-budget.md",
    ),
    "active-budget-long": (
        "python benchmarks/msckf_long.py budget --team long --frames 5000 --reference-frames 300 "
        f"--budgets 80 --markdown {GENERATED}/active-budget-long.md",
        f"{GENERATED}/active-budget-long.md",
    ),
    "active-budget-learned": (
        "python benchmarks/msckf_long.py budget --frames 500 --budgets 80 --windows 4 "
        f"--markdown {GENERATED}/active-budget-learned.md",
        f"{GENERATED}/active-budget-learned.md",
    ),
    "active-budget-learned-long": (
        "python benchmarks/msckf_long.py budget --team long --frames 300 --budgets 80 "
        f"--windows 4 --markdown {GENERATED}/active-budget-learned-long.md",
        f"{GENERATED}/active-budget-learned-long.md",
    ),
    "detector-team": (
        "python benchmarks/detector_team.py --robots 3 --steps 420 --render results/street-render "
        f"--markdown {GENERATED}/detector-team.md",
        f"{GENERATED}/detector-team.md",
    ),
    "detector-team-seed-18": (
        "python benchmarks/detector_team.py --robots 3 --steps 420 --seed 18 "
        f"--render results/street-render-18 --markdown {GENERATED}/detector-team-seed-18.md",
        f"{GENERATED}/detector-team-seed-18.md",
    ),
    "detector-team-seed-19": (
        "python benchmarks/detector_team.py --robots 3 --steps 420 --seed 19 "
        f"--render results/street-render-19 --markdown {GENERATED}/detector-team-seed-19.md",
        f"{GENERATED}/detector-team-seed-19.md",
    ),
    "render-objects": (
        f"python benchmarks/render_objects.py --markdown {GENERATED}/render-objects.md",
        f"{GENERATED}/render-objects.md",
    ),
    "consistency-kitti": (
        "python benchmarks/consistency.py --teams kitti --variants std fej oc "
        f"--modes separate consensus --markdown {GENERATED}/consistency-kitti.md",
        f"{GENERATED}/consistency-kitti.md",
    ),
    "cluster-overhead": (
        "python benchmarks/cluster.py --robots 3 --steps 40 --runs 20 --workers 2 --repeats 2 "
        f"--markdown {GENERATED}/cluster-overhead.md",
        f"{GENERATED}/cluster-overhead.md",
    ),
    "consistency-long-route": (
        "python benchmarks/long_route.py --seeds 37 43 0 --runs 10 --robots 3 --steps 100 "
        "--filters fej --modes separate consensus --workers 2 "
        f"--markdown {GENERATED}/consistency-long-route.md",
        f"{GENERATED}/consistency-long-route.md",
    ),
    "consistency-long-route-600": (
        "python benchmarks/long_route.py --seeds 43 --runs 2 --robots 3 --steps 600 "
        "--filters fej --modes consensus --workers 2 "
        f"--markdown {GENERATED}/consistency-long-route-600.md",
        f"{GENERATED}/consistency-long-route-600.md",
    ),
    "consistency-long-route-600-active": (
        "python benchmarks/long_route.py --seeds 43 37 0 --runs 10 --robots 3 --steps 600 "
        "--filters fej --modes consensus --set consensus.set=active --workers 2 "
        f"--markdown {GENERATED}/consistency-long-route-600-active.md",
        f"{GENERATED}/consistency-long-route-600-active.md",
    ),
    "consistency-long-route-600-active-reanchored": (
        "python benchmarks/long_route.py --seeds 43 37 0 --runs 10 --robots 3 --steps 600 "
        "--filters fej --modes consensus --set consensus.set=active "
        "--set objects.reanchor_with_consensus=true --workers 2 "
        f"--markdown {GENERATED}/consistency-long-route-600-active-reanchored.md",
        f"{GENERATED}/consistency-long-route-600-active-reanchored.md",
    ),
    "consistency-long-route-600-linearisations": (
        "python benchmarks/long_route.py --seeds 43 37 0 --runs 10 --robots 3 --steps 600 "
        "--filters std oc ideal --modes separate --workers 2 "
        f"--markdown {GENERATED}/consistency-long-route-600-linearisations.md",
        f"{GENERATED}/consistency-long-route-600-linearisations.md",
    ),
    "consistency-long-route-600-separate": (
        "python benchmarks/long_route.py --seeds 43 37 0 --runs 10 --robots 3 --steps 600 "
        "--filters fej --modes separate --workers 2 "
        f"--markdown {GENERATED}/consistency-long-route-600-separate.md",
        f"{GENERATED}/consistency-long-route-600-separate.md",
    ),
    "consistency-long-route-600-features": (
        "python benchmarks/long_route.py --seeds 43 37 0 --runs 10 --robots 3 --steps 600 "
        "--filters ideal fej --modes separate --set filter.use_objects=false --workers 2 "
        f"--markdown {GENERATED}/consistency-long-route-600-features.md",
        f"{GENERATED}/consistency-long-route-600-features.md",
    ),
    "consistency-long-route-600-objects": (
        "python benchmarks/long_route.py --seeds 43 37 0 --runs 10 --robots 3 --steps 600 "
        "--filters ideal fej --modes separate --set filter.use_geometric_features=false "
        "--set objects.reanchor_probability=0 --workers 2 "
        f"--markdown {GENERATED}/consistency-long-route-600-objects.md",
        f"{GENERATED}/consistency-long-route-600-objects.md",
    ),
    "consistency-long-route-600-objects-reanchored": (
        "python benchmarks/long_route.py --seeds 43 37 0 --runs 10 --robots 3 --steps 600 "
        "--filters fej --modes separate --set filter.use_geometric_features=false --workers 2 "
        f"--markdown {GENERATED}/consistency-long-route-600-objects-reanchored.md",
        f"{GENERATED}/consistency-long-route-600-objects-reanchored.md",
    ),
    "consistency-rigid-directions-off": (
        "python benchmarks/consistency.py --teams make-run kitti --variants fej "
        "--modes consensus --set consensus.rigid_directions=false "
        f"--markdown {GENERATED}/consistency-rigid-directions-off.md",
        f"{GENERATED}/consistency-rigid-directions-off.md",
    ),
    "consistency-at-first-estimates": (
        "python benchmarks/consistency.py --teams make-run kitti --variants fej "
        "--modes consensus --set consensus.rigid_directions=false "
        "--set consensus.at_first_estimates=true "
        f"--markdown {GENERATED}/consistency-at-first-estimates.md",
        f"{GENERATED}/consistency-at-first-estimates.md",
    ),
    "consistency-long-route-600-rigid-directions-off": (
        "python benchmarks/long_route.py --seeds 43 --runs 2 --robots 3 --steps 600 "
        "--filters fej --modes consensus --set consensus.set=active "
        "--set consensus.rigid_directions=false --workers 2 "
        f"--markdown {GENERATED}/consistency-long-route-600-rigid-directions-off.md",
        f"{GENERATED}/consistency-long-route-600-rigid-directions-off.md",
    ),
    "consistency-long-route-600-at-first-estimates": (
        "python benchmarks/long_route.py --seeds 43 --runs 2 --robots 3 --steps 600 "
        "--filters fej --modes consensus --set consensus.set=active "
        "--set consensus.rigid_directions=false --set consensus.at_first_estimates=true "
        "--workers 2 "
        f"--markdown {GENERATED}/consistency-long-route-600-at-first-estimates.md",
        f"{GENERATED}/consistency-long-route-600-at-first-estimates.md",
    ),
    "consistency-make-run": (
        "python benchmarks/consistency.py --teams make-run --variants std fej oc "
        f"--modes separate consensus --markdown {GENERATED}/consistency-make-run.md",
        f"{GENERATED}/consistency-make-run.md",
    ),
    "live-input": (
        "python benchmarks/live_input.py --robots 3 --steps 100 --width 640 --rates 0 1 4 "
        f"--markdown {GENERATED}/live-input.md",
        f"{GENERATED}/live-input.md",
    ),
    "frontend-cost-stages": (
        "python benchmarks/frontend_cost.py --repeats 3 "
        f"--markdown {GENERATED}/frontend-cost-stages.md",
        f"{GENERATED}/frontend-cost-stages.md",
    ),
    "frontend-cost-objects": (
        "python benchmarks/frontend_cost.py --repeats 3 --objects shapes "
        f"--markdown {GENERATED}/frontend-cost-objects.md",
        f"{GENERATED}/frontend-cost-objects.md",
    ),
    "frontend-cost": (
        "python benchmarks/frontend_cost.py --repeats 3 --accuracy --variant max_features=250 "
        "--variant lk_window_share=0.019 --variant lk_levels=1 --variant affine_iterations=1 "
        "--variant stereo_affine_iterations=0 --variant marker_threshold_passes=1 "
        "--variant detection_interval=2 --variant detection_interval=3 "
        "--variant max_features=250,lk_window_share=0.019,affine_iterations=1 "
        f"--markdown {GENERATED}/frontend-cost.md",
        f"{GENERATED}/frontend-cost.md",
    ),
    "live-robots-images": (
        "python benchmarks/live_agents.py images --robots 3 --steps 100 --width 640 "
        f"--runs lockstep:0.25 async:0.25 async:1 --markdown {GENERATED}/live-robots-images.md",
        f"{GENERATED}/live-robots-images.md",
    ),
    "foxglove-view": (
        "python benchmarks/foxglove_view.py --steps 150 --image-steps 60 --width 640 "
        f"--markdown {GENERATED}/foxglove-view.md",
        f"{GENERATED}/foxglove-view.md",
    ),
    "live-robots-observations": (
        "python benchmarks/live_agents.py observations --robots 5 --steps 150 "
        f"--runs lockstep:1 async:1 async:10 --markdown {GENERATED}/live-robots-observations.md",
        f"{GENERATED}/live-robots-observations.md",
    ),
    "live-robots-age-limit": (
        f"python benchmarks/async_lag.py --markdown {GENERATED}/live-robots-age-limit.md",
        f"{GENERATED}/live-robots-age-limit.md",
    ),
}

#: one BLAS / OpenMP / numba thread: times comparable across machines with other work
SINGLE_THREAD = {
    name: "1"
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
}


def argv_of(command: str) -> list[str]:
    """The process to start for ``command`` (this interpreter for ``python`` and ``teamslam``)."""
    words = shlex.split(command)
    if words[0] == "teamslam":
        return [sys.executable, "-m", "teamslam", *words[1:]]
    if words[0] == "python":
        return [sys.executable, *words[1:]]
    raise ValueError(f"not a command of the results pages: {command}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--list", action="store_true", help="print the commands, run nothing")
    parser.add_argument(
        "--only", nargs="+", choices=list(COMMANDS), default=None, help="run only these"
    )
    args = parser.parse_args()
    chosen = args.only or list(COMMANDS)
    if args.list:
        for name in chosen:
            command, writes = COMMANDS[name]
            print(f"{name:<24} {writes}\n    {command}")
        return 0
    env = {**os.environ, **SINGLE_THREAD}
    src = str(ROOT / "src")
    env["PYTHONPATH"] = os.pathsep.join(p for p in (src, env.get("PYTHONPATH")) if p)
    for name in chosen:
        command, writes = COMMANDS[name]
        print(f"== {name}: {command}", flush=True)
        begin = time.perf_counter()
        done = subprocess.run(argv_of(command), cwd=ROOT, env=env)
        if done.returncode != 0:
            print(f"{name} failed (exit {done.returncode}); {writes} not rewritten", flush=True)
            return done.returncode
        print(f"== {name}: wrote {writes} in {time.perf_counter() - begin:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
