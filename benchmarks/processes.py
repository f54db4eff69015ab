"""In-process vs one-process-per-robot (Zenoh on loopback): time and equality of the estimates.

Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/processes.py [--robots 3] [--steps 60]

Prints the wall time of each, the ratio, the largest difference between the two runs'
estimates, bytes per robot per step and message latency.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from teamslam.datasets import save_dataset
from teamslam.graph import complete
from teamslam.msckf import config_for, run_team
from teamslam.runtime.agent_process import load_robot_result
from teamslam.runtime.team_file import write_team_file
from teamslam.sim import lissajous_team


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--window", type=int, default=10)
    args = parser.parse_args()
    dataset = lissajous_team(robots=args.robots, steps=args.steps, seed=1)
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp) / "data"
        save_dataset(dataset, directory)
        begin = time.perf_counter()
        reference = run_team(
            dataset, config_for(dataset, {"filter.window": args.window}), progress=False
        )
        in_process = time.perf_counter() - begin
        team = write_team_file(
            Path(tmp) / "team.yaml",
            "bench",
            directory,
            complete(args.robots).adjacency,
            base_port=17600,
            settings={"filter.window": args.window},
            timeout_s=30.0,
        )
        begin = time.perf_counter()
        procs = [
            subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "teamslam",
                    "agent",
                    "--team",
                    str(team),
                    "--robot",
                    str(r),
                    "--out",
                    str(Path(tmp) / "out"),
                ],
                stdout=subprocess.DEVNULL,
            )
            for r in range(args.robots)
        ]
        for p in procs:
            p.wait()
        processes = time.perf_counter() - begin
        diff, summaries = 0.0, []
        for r in range(args.robots):
            arrays, summary = load_robot_result(Path(tmp) / "out", r)
            diff = max(diff, float(np.abs(arrays["poses"] - reference.poses[r]).max()))
            summaries.append(summary)
    print(f"{args.robots} robots, {args.steps} steps")
    print(f"in-process        {in_process:8.2f} s")
    print(f"processes (Zenoh) {processes:8.2f} s  ratio {processes / in_process:.2f}")
    print(f"largest pose difference {diff:.3g}")
    for s in summaries:
        print(
            f"robot {s['robot']}: {s['bytes_per_step']:.0f} B/step, message latency median "
            f"{s['message_latency_ms']['median']:.2f} ms p95 {s['message_latency_ms']['p95']:.2f}"
            f" ms, step latency median {s['step_latency_ms']['median']:.1f} ms"
        )


if __name__ == "__main__":
    main()
