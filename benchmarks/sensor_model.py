"""A team's own data out of the box: calibrated σ against the truth, accuracy against true σ.

For every team of :data:`teamslam.sim.SENSOR_SCENARIOS` (sensors unlike every default), written
in the published layout and imported with no noise given anywhere, prints per team:

* the calibrated σ next to the generator's true σ (ratio);
* trajectory RMSE (no alignment, average over robots) of odometry alone, of the filter with the
  true σ, with the calibrated σ (what ``teamslam run DATASET`` does), and with what
  ``teamslam run`` used before sensor models existed (KITTI 00's noise for anything imported
  from the published layout) — separate and consensus.

Run on demand (BLAS pinned to one thread)::

    OPENBLAS_NUM_THREADS=1 python benchmarks/sensor_model.py [--robots 3] [--steps 200]
        [--scenarios NAME ...] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from teamslam.datasets import export_reference, import_reference
from teamslam.eval.metrics import team_metrics
from teamslam.msckf import MsckfConfig, run_team
from teamslam.msckf.configure import build_settings
from teamslam.sim import SENSOR_SCENARIOS, scenario_team

#: what ``teamslam run`` used before datasets carried a sensor model, for anything imported
#: from the published layout (KITTI 00's measured noise)
BEFORE_PUBLISHED = MsckfConfig.from_settings(
    {
        "filter.odometry_std": (0.015,) * 3 + (0.0012,) * 3,
        "filter.feature_std": 1.0,
        "filter.object_std": 15.0,
        "objects.min_depth": 5.0,
        "objects.max_depth": 30.0,
    }
)


def _rmse(dataset, config) -> dict:
    out = {}
    for mode, consensus in (("separate", False), ("consensus", True)):
        m = team_metrics(dataset, run_team(dataset, config, consensus=consensus, progress=False))
        out[mode] = m["trajectory_rmse_avg_m"]
        out["odometry"] = m["odometry_rmse_avg_m"]
    return out


def scenario(name: str, robots: int, steps: int, seed: int, window: int) -> dict:
    truth_team = scenario_team(name, robots, steps, seed)
    truth = build_settings(truth_team, flags={"filter.window": window}, calibrate="never").config
    with tempfile.TemporaryDirectory() as tmp:
        export_reference(truth_team, Path(tmp) / "published")
        imported = import_reference(Path(tmp) / "published")
    begin = time.perf_counter()
    effective = build_settings(imported, flags={"filter.window": window})
    seconds = time.perf_counter() - begin
    calibrated = effective.config
    row = {
        "team": truth_team.name,
        "calibration_seconds": seconds,
        "calibration_passes": len(effective.calibration.iterations),
        "sigma": {},
    }
    for key in ("odometry_std", "feature_std", "object_std"):
        true_value, estimate = getattr(truth.filter, key), getattr(calibrated.filter, key)
        if key == "feature_std" and not any(r.features.ids.size for r in truth_team.robots):
            continue
        ratio = np.asarray(estimate) / np.asarray(true_value)
        row["sigma"][key] = {
            "true": true_value,
            "calibrated": estimate,
            "ratio": ratio.tolist() if ratio.ndim else float(ratio),
        }
    row["true"] = _rmse(truth_team, truth)
    row["calibrated"] = _rmse(truth_team, calibrated)
    before = BEFORE_PUBLISHED.with_({"filter.window": window})
    row["before"] = _rmse(truth_team, before)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--window", type=int, default=10)
    parser.add_argument("--scenarios", nargs="+", default=list(SENSOR_SCENARIOS))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    rows = []
    with threadpool_limits(1):
        for name in args.scenarios:
            row = scenario(name, args.robots, args.steps, args.seed, args.window)
            rows.append(row)
            print(
                f"\n{row['team']}  (calibration {row['calibration_seconds']:.1f} s, "
                f"{row['calibration_passes']} passes)"
            )
            for key, v in row["sigma"].items():
                ratio = np.round(np.atleast_1d(v["ratio"]), 2).tolist()
                print(f"  {key:<13} calibrated/true {ratio}")
            print(
                f"  {'RMSE [m]':<13} {'odometry':>9} {'true σ':>9} {'calibrated':>11} {'before':>9}"
            )
            for mode in ("separate", "consensus"):
                print(
                    f"  {mode:<13} {row['true']['odometry']:9.3f} {row['true'][mode]:9.3f} "
                    f"{row['calibrated'][mode]:11.3f} {row['before'][mode]:9.3f}"
                )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
