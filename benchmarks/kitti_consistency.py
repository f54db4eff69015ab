"""Pose NEES on KITTI 00 per linearisation policy and object loss, separate and with consensus.

Run on demand (BLAS pinned to one thread; needs ``../shared/data`` beside the repository or
``--data``)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/kitti_consistency.py \\
        [--variants std fej oc std+huber std+cauchy oc+huber] [--modes separate consensus hybrid] \\
        [--set object_update_iterations=3]

Each variant is a linearisation policy (``std``, ``fej``, ``oc``), optionally with a robust
object loss (``+huber``, ``+cauchy``), on top of the settings ``teamslam run`` resolves for the
data (its sensor model, else a calibration from the data) and any ``--set KEY=VALUE``. Mode
``hybrid`` is consensus with ``consensus_hybrid`` (new information at full weight). Prints per
variant and mode the trajectory RMSE and object error (team averages, metres), each robot's mean
and median pose NEES/6 over its frames (the χ² expectation is 1) and the object NIS per degree
of freedom.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from teamslam.datasets import import_reference
from teamslam.eval.metrics import team_metrics
from teamslam.msckf import run_team
from teamslam.msckf.settings import parse_assignments, resolve_config

MODES = ("separate", "consensus", "hybrid")
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def _settings(variant: str) -> dict:
    policy, _, loss = variant.partition("+")
    return {"linearization": policy, **({"object_loss": loss} if loss else {})}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA / "distributed-msckf" / "kitti00")
    parser.add_argument(
        "--variants", nargs="+", default=["std", "fej", "oc", "std+huber", "std+cauchy", "oc+huber"]
    )
    parser.add_argument(
        "--modes", nargs="+", default=["separate", "consensus"], choices=MODES, metavar="MODE"
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a filter setting for every robot and variant (repeatable)",
    )
    args = parser.parse_args()
    settings = parse_assignments(args.set)
    if not args.data.is_dir():
        raise SystemExit(f"no KITTI 00 data at {args.data} (see the data README)")
    dataset = import_reference(args.data)
    base = [replace(c, **settings) for c in resolve_config(dataset).robots]
    print(
        f"KITTI 00, {dataset.n_robots} robots, window {base[0].window}, "
        f"object σ {base[0].object_std:.2f} px" + "".join(f", {k}={v}" for k, v in settings.items())
    )
    print(
        f"{'variant':<11} {'mode':<10} {'RMSE m':>7} {'obj m':>6} {'NEES/6 mean per robot':>24} "
        f"{'median per robot':>20} {'object NIS':>10} {'s':>5}"
    )
    for variant in args.variants:
        configs = [replace(c, **_settings(variant)) for c in base]
        for mode in args.modes:
            begin = time.perf_counter()
            run_configs = configs
            if mode == "hybrid":
                run_configs = [replace(c, consensus_hybrid=True) for c in configs]
            consensus = mode in ("consensus", "hybrid")
            result = run_team(dataset, run_configs, consensus=consensus, progress=False)
            m = team_metrics(dataset, result)
            means = " ".join(f"{v:5.1f}" for v in m["nees_pose_avg"])
            medians = " ".join(f"{v:5.1f}" for v in m["nees_pose_median"])
            nis = (m.get("nis") or {}).get("objects")
            print(
                f"{variant:<11} {mode:<10} {m['trajectory_rmse_avg_m']:7.3f} "
                f"{m['object_error_avg_m']:6.3f} {means:>24} {medians:>20} "
                f"{np.nan if nis is None else nis:10.2f} {time.perf_counter() - begin:5.0f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
