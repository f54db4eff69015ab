"""Speed of the ROS 2 outputs: MCAP export of a run, team-bag export/import, CDR per frame.

Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/ros2_io.py [--robots 5] [--steps 150]

Simulates a team, runs the distributed MSCKF once, then prints the median over repeats of:
writing the run as MCAP (and its size), writing the team as a bag and importing it back, and
the per-frame cost of the live messages (PoseStamped, a Path of all frames so far, the
MarkerArray of the map) built and serialised to CDR as the robot process does.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from teamslam.eval.estimates import save_estimates
from teamslam.msckf import config_for, run_team
from teamslam.ros2 import messages as m
from teamslam.ros2.bags import RobotTopics, export_bag, import_bag
from teamslam.ros2.mcap_export import export_mcap
from teamslam.sim import lissajous_team


def _median(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        begin = time.perf_counter()
        fn()
        times.append(time.perf_counter() - begin)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=5)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    team = lissajous_team(robots=args.robots, steps=args.steps, seed=0)
    result = run_team(team, config_for(team, {"filter.window": 10}), progress=False)
    with tempfile.TemporaryDirectory() as tmp, threadpool_limits(1):
        tmp = Path(tmp)
        save_estimates(tmp / "run" / "estimates.npz", team, result)
        counter = iter(range(10**6))
        seconds = _median(
            lambda: export_mcap(tmp / "run", tmp / f"run{next(counter)}.mcap"), args.repeats
        )
        size = (tmp / "run0.mcap").stat().st_size
        print(f"MCAP export of the run: {seconds:.3f} s median, {size / 1e6:.2f} MB")
        seconds = _median(
            lambda: export_bag(team, tmp / f"bag{next(counter)}.mcap", camera=tmp / "cam.json"),
            args.repeats,
        )
        bag = next(tmp.glob("bag*.mcap"))
        print(f"team bag export: {seconds:.3f} s median, {bag.stat().st_size / 1e6:.2f} MB")
        robots = [
            RobotTopics(f"robot_{i}", f"/robot_{i}/odom", f"/robot_{i}/ground_truth")
            for i in range(args.robots)
        ]
        seconds = _median(
            lambda: import_bag(bag, robots, "/{name}/stereo_observations", tmp / "cam.json"),
            args.repeats,
        )
        print(f"team bag import: {seconds:.3f} s median")
    poses, stamps = result.poses[0], np.arange(result.poses[0].shape[0]) * 10**9
    ids, objects, covs = result.object_ids[0], result.objects[0], result.object_covs[0]
    frame = len(stamps) - 1
    published = m.poses_stamped(poses[:frame], stamps[:frame])

    def live_frame() -> None:
        m.serialize(m.pose_stamped(poses[frame], int(stamps[frame])))
        m.serialize(m.path_msg([*published, m.pose_stamped(poses[frame], 0)], stamps))
        m.serialize(m.object_markers(ids, objects, covs, int(stamps[frame]), 0, 0.1))

    seconds = _median(live_frame, 20)
    print(
        f"live messages of the last frame (path of {frame + 1} poses, {ids.size} objects): "
        f"{seconds * 1e3:.2f} ms median"
    )


if __name__ == "__main__":
    main()
