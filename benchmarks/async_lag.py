"""Asynchronous live robots that fall behind by different amounts, in one process and on a
schedule: the age limit of the neighbours' messages by a robot's own steps against the one
learned from their lags, without the machine's load in the numbers.

Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/async_lag.py [--robots 5] [--steps 150] \\
        [--speeds 0.95 0.6 0.75 0.55 0.7] [--queue 8] [--markdown FILE]

The ``make run`` team (``teamslam simulate --robots 5 --steps 150 --seed 0``, 1 s between
frames) exported as a bag of odometry and ``StereoObservations`` and fed, message by message in
recorded order, to one :class:`~teamslam.live.LiveRobot` per robot (``sync: async``,
``filter.window=10``, the noise levels calibrated once as ``make run`` does), all in one thread:
at each frame of the bag robot ``i`` processes ``speeds[i]`` frames on average, so a slower robot
falls behind, its queue of ``queue`` frames fills and it drops its oldest frames — the same
frames in every run. Per age rule (``max_age_quantile`` null: ``max_age_steps`` of a robot's own
steps; 0.95: learned from the neighbours' lags), the frames processed, the position RMSE over
them against the run in which every robot keeps up (same rule), the share of (frame, neighbour)
pairs averaged and the pairs not averaged because the neighbour's newest message was too old,
robots pooled and per robot.
"""

from __future__ import annotations

import argparse
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from _markdown import Markdown, add_option
from live_agents import _teamslam, observations_team
from teamslam.datasets import load_dataset


def messages(bag: Path) -> list:
    """The bag's messages in recorded order, as a subscriber hands them over."""
    from teamslam.ros2 import messages as m
    from teamslam.ros2.live import Received

    highlevel = m.rosbags("highlevel")
    items = []
    with highlevel.AnyReader([bag], default_typestore=m.typestore()) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = m.stamp_ns(msg.header.stamp)
            items.append(Received(conn.topic, conn.msgtype, stamp, msg, time.monotonic_ns()))
    return items


def run(dataset, config, items, speeds, queue: int, quantile, out: Path) -> list:
    """The team's live robots in one thread on the schedule ``speeds``; the robots."""
    from teamslam.live import LiveInputs, LiveRobot
    from teamslam.msckf.consensus.transport import MemoryNetwork
    from teamslam.runtime.team_file import RobotEntry, TeamFile

    n = len(dataset.robots)
    entries = [RobotEntry(i, "tcp/127.0.0.1:0", [j for j in range(n) if j != i]) for i in range(n)]
    team = TeamFile(
        "lag", None, entries, sync="async", max_age_quantile=quantile, checkpoint_every=0
    )
    network = MemoryNetwork(n)
    robots = [
        LiveRobot(
            team,
            i,
            LiveInputs(
                f"/robot_{i}/odom",
                observations=f"/robot_{i}/stereo_observations",
                ground_truth=f"/robot_{i}/ground_truth",
                queue=queue,
            ),
            config,
            out,
            calibration=dataset.calibration,
            transport=network.endpoint(i),
            say=lambda text: None,
        )
        for i in range(n)
    ]
    credit = np.zeros(n)
    last = f"/robot_{n - 1}/stereo_observations"
    for item in items:
        robots[int(item.topic.split("/")[1].rsplit("_", 1)[1])].feed(item)
        if item.topic == last:  # a frame of the bag went by
            credit += speeds
            for i, robot in enumerate(robots):
                while credit[i] >= 1 and robot.process_queued():
                    credit[i] -= 1
                credit[i] = min(credit[i], 1.0)
    for robot in robots:
        robot.finish()
    while any(robot.process_queued() for robot in robots):
        pass
    return robots


def position_errors(dataset, robot, index: int) -> np.ndarray:
    """``(frames, 3)`` a robot's position errors against ground truth at its frames."""
    origin = int(dataset.metadata["ros2"]["stamp_origin_ns"])
    sequence = dataset.robots[index]
    at = {origin + round(t * 1e9): k for k, t in enumerate(sequence.timestamps)}
    frames = [at[int(s)] for s in robot.sequence.stamps_ns[: robot.sequence.frames]]
    return robot.driver.poses[: robot.driver.done, :3, 3] - sequence.T_world_body[frames, :3, 3]


def rmse(errors: list[np.ndarray]) -> float:
    e = np.concatenate(errors)
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=5)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument(
        "--speeds",
        type=float,
        nargs="+",
        default=[0.95, 0.6, 0.75, 0.55, 0.7],
        help="frames each robot processes per frame of the bag (one per robot)",
    )
    parser.add_argument("--queue", type=int, default=8, help="each robot's queue, in frames")
    add_option(parser)
    args = parser.parse_args()
    if len(args.speeds) != args.robots or not all(0 < s <= 1 for s in args.speeds):
        raise SystemExit(f"--speeds: one number in (0, 1] per robot ({args.robots})")
    md = Markdown(args.markdown)
    speeds = np.array(args.speeds)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        bag, dataset_dir, _, what = observations_team(tmp, args.robots, args.steps)
        subprocess.run(
            _teamslam("calibrate", str(dataset_dir), "--frames", "60", "--write"),
            check=True,
            stdout=subprocess.DEVNULL,
        )
        from teamslam.msckf.configure import config_for

        dataset = load_dataset(dataset_dir)
        config = config_for(dataset, {"filter.window": 10}, "never")
        items = messages(bag)
        md.table(
            f"Asynchronous live robots in one process: {what}; each robot processes "
            f"{' / '.join(f'{s:g}' for s in speeds)} frames per frame of the bag, queue "
            f"{args.queue}",
            [
                "age limit",
                "frames",
                "RMSE (m)",
                "RMSE / every frame",
                "per robot: RMSE / every frame",
                "averaged",
                "too old (pairs)",
                "messages too old",
            ],
            note="The same frames are dropped in every run (a schedule, not the machine's "
            "load). Age limit: max_age_steps (3) of a robot's own steps, or learned per "
            "neighbour from the lags of its messages (max_age_quantile 0.95 of the lags plus "
            "the neighbour's interval, never below the former). RMSE: position, over every "
            "frame processed, against the run of the same rule in which every robot keeps up "
            "(no frame dropped). Averaged: the share of (frame, neighbour) pairs in which a "
            "robot averaged with that neighbour; too old: pairs not averaged because the "
            "neighbour's newest message was older than the limit; messages too old: discarded "
            "as such while the newest of their sender.",
        )
        for name, quantile in (("own steps", None), ("learned (0.95)", 0.95)):
            full = run(dataset, config, items, np.ones(args.robots), 10_000, quantile, tmp / "a")
            robots = run(dataset, config, items, speeds, args.queue, quantile, tmp / "b")
            full_e = [position_errors(dataset, r, i) for i, r in enumerate(full)]
            errors = [position_errors(dataset, r, i) for i, r in enumerate(robots)]
            ratio = [rmse([e]) / rmse([f]) for e, f in zip(errors, full_e, strict=True)]
            drivers = [r.driver for r in robots]
            pairs = sum(max(d.done - 1, 0) * (args.robots - 1) for d in drivers)
            averaged = sum(len(s) for d in drivers for s in d.averaged_with.values())
            row = (
                name,
                f"{sum(d.done for d in drivers)} of {sum(r.frames for r in dataset.robots)}",
                f"{rmse(errors):.4f}",
                f"{rmse(errors) / rmse(full_e):.3f}",
                " / ".join(f"{x:.2f}" for x in ratio),
                f"{averaged / max(pairs, 1):.2f}",
                str(sum(d.not_averaged["too_old"] for d in drivers)),
                str(sum(d.agent.counters.get("messages_too_old", 0) for d in drivers)),
            )
            print("  ".join(row), flush=True)
            md.row(*row)
        md.end()
    md.write()


if __name__ == "__main__":
    main()
