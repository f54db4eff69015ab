"""Accuracy and consistency per linearisation policy and team mode, on real and generated teams.

Run on demand (BLAS pinned to one thread; KITTI 00 needs ``../shared/data`` beside the repository,
``TEAMSLAM_DATA`` or ``--data``)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/consistency.py [--teams kitti make-run long pixels] \\
        [--variants std fej oc std+huber] [--modes separate consensus hybrid increments] \\
        [--seeds 0 1] [--set objects.update_iterations=3]

Teams:

* ``kitti`` — KITTI 00 (3 robots, objects only), with the settings ``teamslam run`` resolves for
  it (a noise calibration from the data);
* ``make-run`` — the team of ``make run`` (5 robots × 150 frames in the Lissajous arena, window
  10, noise calibrated from its first 60 frames as ``teamslam calibrate --frames 60`` does);
* ``long`` — 3 robots driving 600 m side by side along the long non-repeating route, every object
  new once passed;
* ``pixels`` — 3 robots with a 700-pixel camera (1280 × 720) and σ 3 px on the Lissajous curves'
  turns, with geometric features.

The generated teams' noise is calibrated from their own data, so nothing is set by hand. Each
variant is a linearisation policy (``std``, ``fej``, ``oc``), optionally with a robust object loss
(``+huber``, ``+cauchy``). Modes: ``separate``; ``consensus`` (the paper's average);
``hybrid`` (new information at full weight, ``consensus.rule = hybrid``); ``increments`` (consensus
on
information increments, ``consensus.rule = increments``). Prints per team, variant and mode the
trajectory RMSE and object error (team averages, metres), each robot's mean and median pose NEES/6
over its frames (the χ² expectation is 1), the object NEES/3 (team mean) and the object NIS per
degree of freedom; with several seeds, one row per seed and their mean. Each team is made and
its noise calibrated once per seed, then shared by its variants and modes. ``--markdown FILE``
writes the table as Markdown headed by the commit, date, command and machine
(``benchmarks/_markdown.py``).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from _markdown import Markdown, add_option
from teamslam.datasets import import_reference
from teamslam.eval.metrics import object_nees, team_metrics
from teamslam.msckf import run_team
from teamslam.msckf.configure import build_settings
from teamslam.msckf.settings.sources import parse_assignments
from teamslam.sim import lissajous_team, long_route_team, scenario_team

MODES = ("separate", "consensus", "hybrid", "increments")
TEAMS = ("kitti", "make-run", "long", "pixels")
DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
#: what each mode sets on top of the variant's settings, and whether it exchanges
MODE_SETTINGS = {
    "separate": ({}, False),
    "consensus": ({}, True),
    "hybrid": ({"consensus.rule": "hybrid"}, True),
    "increments": ({"consensus.rule": "increments"}, True),
}


def _settings(variant: str) -> dict:
    policy, _, loss = variant.partition("+")
    return {"filter.linearization": policy, **({"objects.loss": loss} if loss else {})}


_TEAMS: dict[tuple[str, int], tuple] = {}


def team(name: str, seed: int, data: Path):
    """The team ``name`` (seed ``seed``) and the per-robot settings ``teamslam run`` resolves
    (made once, then reused: the calibration is the same for every variant and mode)."""
    if (name, seed) not in _TEAMS:
        _TEAMS[name, seed] = _make_team(name, seed, data)
    return _TEAMS[name, seed]


def _make_team(name: str, seed: int, data: Path):
    if name == "kitti":
        if not data.is_dir():
            raise SystemExit(f"no KITTI 00 data at {data} (see the data README)")
        dataset = import_reference(data)
        return dataset, build_settings(dataset).robots
    if name == "make-run":
        dataset = lissajous_team(robots=5, steps=150, seed=seed)
        flags, frames = {"filter.window": 10}, 60
    elif name == "long":
        dataset = long_route_team(robots=3, steps=600, seed=seed)
        flags, frames = {}, None
    elif name == "pixels":
        dataset = scenario_team("pixels-700-3px-features", robots=3, steps=200, seed=seed)
        flags, frames = {}, None
    else:
        raise SystemExit(f"unknown team {name!r}; teams: {', '.join(TEAMS)}")
    resolved = build_settings(dataset, flags=flags, calibrate="always", calibration_frames=frames)
    return dataset, resolved.robots


def row(dataset, configs, mode: str) -> dict:
    """One run's team metrics with ``configs`` in ``mode``, with its objects' NEES / 3."""
    extra, consensus = MODE_SETTINGS[mode]
    run_configs = [c.with_(extra) for c in configs]
    result = run_team(dataset, run_configs, consensus=consensus, progress=False)
    return {**team_metrics(dataset, result), "nees_object": object_nees(dataset, result)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--teams", nargs="+", default=["kitti"], choices=TEAMS, metavar="TEAM")
    parser.add_argument(
        "--data",
        type=Path,
        default=Path(os.environ.get("TEAMSLAM_DATA", DATA)) / "distributed-msckf" / "kitti00",
    )
    parser.add_argument(
        "--variants", nargs="+", default=["std", "fej", "oc", "std+huber", "std+cauchy", "oc+huber"]
    )
    parser.add_argument(
        "--modes", nargs="+", default=["separate", "consensus"], choices=MODES, metavar="MODE"
    )
    parser.add_argument(
        "--seeds", nargs="+", type=int, default=[0], help="seeds of the generated teams"
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a filter setting for every robot and variant (repeatable)",
    )
    add_option(parser)
    args = parser.parse_args()
    settings = parse_assignments(args.set)
    md = Markdown(args.markdown)
    md.table(
        "Accuracy and consistency per linearisation and team mode",
        [
            "team",
            "seed",
            "variant",
            "mode",
            "trajectory RMSE [m]",
            "object error [m]",
            "pose NEES/6, mean per robot",
            "pose NEES/6, median per robot",
            "object NEES/3",
            "object NIS per dof",
        ],
        note="NEES and NIS are normalised by their degrees of freedom: 1 is consistent, above 1 "
        "overconfident. Teams: `kitti` KITTI 00 (3 robots, objects only); `make-run` 5 "
        "Lissajous robots × 150 frames, window 10; `long` 3 robots × 600 m of new ground; "
        "`pixels` a 700-pixel camera with σ 3 px.",
    )
    print(
        f"{'team':<8} {'seed':>4} {'variant':<11} {'mode':<10} {'RMSE m':>7} {'obj m':>6} "
        f"{'NEES/6 mean per robot':>24} {'median per robot':>20} {'objNEES':>7} "
        f"{'obj NIS':>7} {'s':>5}"
    )
    for name in args.teams:
        seeds = [0] if name == "kitti" else args.seeds
        for variant in args.variants:
            for mode in args.modes:
                totals = []
                for seed in seeds:
                    dataset, base = team(name, seed, args.data)
                    configs = [c.with_({**settings, **_settings(variant)}) for c in base]
                    begin = time.perf_counter()
                    m = row(dataset, configs, mode)
                    nis = (m.get("nis") or {}).get("objects")
                    values = [
                        m["trajectory_rmse_avg_m"],
                        m["object_error_avg_m"],
                        float(np.mean(m["nees_object"])) if m["nees_object"].size else np.nan,
                        np.nan if nis is None else nis,
                    ]
                    totals.append([*values, *m["nees_pose_avg"]])
                    print(_line(name, str(seed), variant, mode, values, m, begin), flush=True)
                    md.row(*_cells(name, str(seed), variant, mode, values, m))
                if len(seeds) > 1:
                    mean = np.mean(totals, axis=0)
                    robots = {"nees_pose_avg": mean[4:], "nees_pose_median": []}
                    print(_line(name, "mean", variant, mode, mean[:4], robots, None), flush=True)
                    md.row(*_cells(name, "mean", variant, mode, mean[:4], robots))
    md.end()
    md.write()


def _cells(name, seed, variant, mode, values, m) -> list[str]:
    rmse, obj, obj_nees, nis = values
    return [
        f"`{name}`",
        seed,
        f"`{variant}`",
        mode,
        f"{rmse:.4f}",
        f"{obj:.3f}",
        " ".join(f"{v:.2f}" for v in m["nees_pose_avg"]),
        " ".join(f"{v:.2f}" for v in m["nees_pose_median"]) or "—",
        f"{obj_nees:.2f}",
        f"{nis:.2f}",
    ]


def _line(name, seed, variant, mode, values, m, begin) -> str:
    rmse, obj, obj_nees, nis = values
    means = " ".join(f"{v:5.1f}" for v in m["nees_pose_avg"])
    medians = " ".join(f"{v:5.1f}" for v in m["nees_pose_median"])
    took = "" if begin is None else f"{time.perf_counter() - begin:5.0f}"
    return (
        f"{name:<8} {seed:>4} {variant:<11} {mode:<10} {rmse:7.4f} {obj:6.3f} {means:>24} "
        f"{medians:>20} {obj_nees:7.2f} {nis:7.2f} {took:>5}"
    )


if __name__ == "__main__":
    with threadpool_limits(1):
        main()
