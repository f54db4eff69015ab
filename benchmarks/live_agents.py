"""Live robots on loopback: a team's bag played by ``teamslam bag play`` into one
``teamslam agent --live`` process per robot, against the offline run of the same bag.

Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/live_agents.py images [--robots 3] [--steps 100] \\
        [--width 640] [--runs lockstep:0.25 async:1] [--markdown FILE]
    OPENBLAS_NUM_THREADS=1 python benchmarks/live_agents.py observations [--robots 5] \\
        [--steps 150] [--runs lockstep:1 async:10] [--markdown FILE]

``images``: a rendered team (``teamslam simulate --images``, 10 Hz stereo, odometry and ground
truth); offline, :func:`~teamslam.ros2.image_bags.dataset_from_bag` of its ``images.mcap``;
live, each robot runs the image front-end on its left/right topics. ``observations``: the ``make
run`` team (``teamslam simulate --robots 5 --steps 150 --seed 0``, 1 s between frames) exported
as a bag of odometry and ``StereoObservations`` (:func:`~teamslam.ros2.bags.export_bag`);
offline, :func:`~teamslam.ros2.bags.import_bag`. Both start each robot at its ground-truth
topic's first pose and use ``filter.window=10``; the noise levels are calibrated once beforehand
(``teamslam calibrate --frames 60 --write``, as ``make run`` does). The offline reference is
``teamslam team launch`` (lock-step robot processes) on the imported dataset; each live run
plays the bag at a rate, with the team file's ``sync`` set to the run's mode. Per run: frames
processed of those in the bag, frames dropped per stage, the latency from a frame's camera input
arriving to its pose being published (robots pooled: the median of the robots' medians, the
largest 99th percentile and maximum), the position RMSE against ground truth over every
processed frame next to the offline run's, the largest difference of a pose from the offline
run's (when every frame was processed), and how consensus went: the share of (frame,
neighbour) pairs in which a robot averaged with that neighbour, why the others were not, the
neighbours' messages found too old (discarded while the newest of their sender) and those
refused (robots pooled), and the robot processes' CPU time (their first frame to their last)
per frame processed against the CPU they had (what the library costs apart from what the
machine's load left it). Per robot, the
same on standard output: frames, drops, latency, RMSE against the offline run's of that robot,
averaged share, the front-end's, consensus's and the filter's time per frame.
"""

from __future__ import annotations

import argparse
import itertools
import json
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from _markdown import Markdown, add_option
from teamslam.datasets import load_dataset, save_dataset
from teamslam.runtime.team_file import write_team_file

_RUNS = itertools.count()


def _free_port(count: int = 1) -> int:
    """A port with ``count`` free ports from it (loopback)."""
    for _ in range(100):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            base = s.getsockname()[1]
        if base + count > 65535:
            continue
        try:
            sockets = []
            for k in range(count):
                t = socket.socket()
                sockets.append(t)
                t.bind(("127.0.0.1", base + k))
            return base
        except OSError:
            continue
        finally:
            for t in sockets:
                t.close()
    raise SystemExit("no free loopback ports")


def _teamslam(*args: str) -> list[str]:
    return [sys.executable, "-m", "teamslam", *args]


def images_team(tmp: Path, robots: int, steps: int, width: int) -> tuple[Path, Path, dict, str]:
    """A rendered team's bag and its offline dataset; the live inputs; a description."""
    from teamslam.ros2.image_bags import ImageTopics, dataset_from_bag

    argv = _teamslam("simulate", "--images", "--quiet", "--robots", str(robots))
    argv += ["--steps", str(steps), "--image-width", str(width), "--seed", "0"]
    subprocess.run([*argv, "--out", str(tmp / "rendered")], check=True, stdout=subprocess.DEVNULL)
    bag = tmp / "rendered" / "images.mcap"
    topics = [ImageTopics.default(f"robot_{i}") for i in range(robots)]
    save_dataset(dataset_from_bag(bag, topics, progress=False), tmp / "dataset")
    inputs = {
        "odometry": "/robot_{id}/odom",
        "left": "/robot_{id}/left/image_raw",
        "right": "/robot_{id}/right/image_raw",
        "camera_info": ["/robot_{id}/left/camera_info", "/robot_{id}/right/camera_info"],
        "ground_truth": "/robot_{id}/ground_truth",
        "sync_tolerance_s": 0.0,
    }
    height = width * 3 // 4
    what = f"rendered team, {robots} robots × {steps + 1} stereo frames {width}×{height} at 10 Hz"
    return bag, tmp / "dataset", inputs, what


def observations_team(tmp: Path, robots: int, steps: int) -> tuple[Path, Path, dict, str]:
    """The make-run team as a bag of odometry and observations, and its import."""
    from teamslam.ros2.bags import RobotTopics, export_bag, import_bag

    argv = _teamslam("simulate", "--robots", str(robots), "--steps", str(steps), "--seed", "0")
    subprocess.run([*argv, "--out", str(tmp / "sim")], check=True, stdout=subprocess.DEVNULL)
    bag = tmp / "team.mcap"
    export_bag(load_dataset(tmp / "sim"), bag, camera=tmp / "camera.json")
    names = [
        RobotTopics(f"robot_{i}", f"/robot_{i}/odom", f"/robot_{i}/ground_truth")
        for i in range(robots)
    ]
    dataset = import_bag(bag, names, "/{name}/stereo_observations", tmp / "camera.json")
    save_dataset(dataset, tmp / "dataset")
    inputs = {
        "odometry": "/robot_{id}/odom",
        "observations": "/robot_{id}/stereo_observations",
        "ground_truth": "/robot_{id}/ground_truth",
    }
    what = f"make-run team, {robots} robots × {steps + 1} frames of observations at 1 Hz"
    return bag, tmp / "dataset", inputs, what


def team_file(
    tmp: Path,
    name: str,
    dataset: Path,
    robots: int,
    sync: str,
    inputs: dict,
    player: int | None,
    quantile: float | None = 0.95,
) -> Path:
    path = write_team_file(
        tmp / f"{name}.yaml",
        name,
        dataset,
        ~np.eye(robots, dtype=bool),
        base_port=_free_port(robots),
    )
    data = yaml.safe_load(path.read_text())
    data.update(sync=sync, timeout_s=30.0, checkpoint_every=0, max_age_quantile=quantile)
    data["settings"] = {"filter": {"window": 10}}
    if player is None:  # offline
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        return path
    data["ros2"] = {
        "domain_id": 41,
        "connect": [f"tcp/127.0.0.1:{player}"],
        "listen": ["tcp/127.0.0.1:0"],
        "inputs": inputs,
    }
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def truth_rmse(dataset, stamps: list[list[int]], poses: list[np.ndarray]) -> float:
    """Position RMSE against the dataset's ground truth at the frames' stamps, robots pooled."""
    origin = int(dataset.metadata.get("ros2", {}).get("stamp_origin_ns", 0))
    errors = []
    for robot, frame_stamps, p in zip(dataset.robots, stamps, poses, strict=True):
        index = {int(origin + round(t * 1e9)): k for k, t in enumerate(robot.timestamps)}
        k = np.array([index[s] for s in frame_stamps])
        errors.append(p[:, :3, 3] - robot.T_world_body[k, :3, 3])
    e = np.concatenate(errors)
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def averaged_share(summaries: list[dict], robots: int) -> float:
    """The share of (frame, neighbour) pairs in which a robot averaged with that neighbour
    (a complete graph: ``robots − 1`` neighbours each; consensus starts at the second frame)."""
    pairs = sum(max(s["frames"] - 1, 0) * (robots - 1) for s in summaries)
    done = sum(len(steps) for s in summaries for steps in s["averaged_with"].values())
    return done / max(pairs, 1)


def robot_rmse(dataset, robot: int, stamps: list[int], poses: np.ndarray) -> float:
    """One robot's position RMSE against ground truth at its frames' stamps."""
    origin = int(dataset.metadata.get("ros2", {}).get("stamp_origin_ns", 0))
    sequence = dataset.robots[robot]
    index = {int(origin + round(t * 1e9)): k for k, t in enumerate(sequence.timestamps)}
    k = np.array([index[s] for s in stamps])
    e = poses[:, :3, 3] - sequence.T_world_body[k, :3, 3]
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def per_robot(dataset, off_stamps, offline, poses, summaries, robots: int) -> list[str]:
    """One line per robot: frames, drops, median latency, RMSE / the offline run's of the
    robot, averaged share and why not, messages found too old."""
    lines = []
    for i, s in enumerate(summaries):
        live = s["live"]
        rmse = robot_rmse(dataset, i, live["stamps_ns"], poses[i])
        off = robot_rmse(dataset, i, off_stamps[i], offline[i])
        why = s["not_averaged"]
        lines.append(
            f"  robot {i}: frames {live['frames']}, dropped {sum(live['dropped'].values())}, "
            f"latency p50 {live['latency_ms']['p50']:.0f} ms, RMSE {rmse:.4f} m = "
            f"{rmse / off:.2f} × offline, averaged {averaged_share([s], robots):.2f}, "
            f"not heard {why['not_heard']}, too old {why.get('too_old', 0)}, "
            f"messages too old {s['counters'].get('messages_too_old', 0)}, front-end "
            f"{live['stage_seconds']['frontend'] / max(live['frames'], 1) * 1e3:.0f} ms, "
            "consensus "
            f"{live['stage_seconds']['consensus'] / max(live['frames'], 1) * 1e3:.0f} ms and "
            f"filter {live['stage_seconds']['filter'] / max(live['frames'], 1) * 1e3:.0f} ms "
            "per frame"
        )
    return lines


def results(out: Path, robots: int) -> tuple[list[np.ndarray], list[dict]]:
    poses, summaries = [], []
    for i in range(robots):
        with np.load(out / f"robot_{i}" / "result.npz") as npz:
            poses.append(npz["robot_0_poses"])
        payload = json.loads((out / f"robot_{i}" / "result.json").read_text())
        summaries.append(payload["extra"]["per_robot"][0])
    return poses, summaries


def live_run(
    tmp: Path,
    bag: Path,
    dataset_dir: Path,
    robots: int,
    inputs: dict,
    mode: str,
    rate: float,
    quantile: float | None = 0.95,
) -> tuple[Path, float]:
    """Play the bag into one ``agent --live`` process per robot; the output folder and the
    seconds the player played (its start to its end)."""
    player = _free_port()
    name = f"{mode}-{rate:g}-{next(_RUNS)}".replace(".", "_")  # each run its own directory
    path = team_file(tmp, name, dataset_dir, robots, mode, inputs, player, quantile)
    out = tmp / name
    # lock-step: every robot must process every frame (a queue as long as the run);
    # asynchronous: a short queue bounds the latency
    queue = "100000" if mode == "lockstep" else "8"
    procs = [
        subprocess.Popen(
            _teamslam(
                "agent",
                "--live",
                "--team",
                str(path),
                "--robot",
                str(i),
                "--out",
                str(out),
                "--idle-timeout",
                "3",
                "--queue",
                queue,
            ),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(robots)
    ]
    try:
        play = _teamslam("bag", "play", str(bag), "--rate", f"{rate:g}", "--domain-id", "41")
        play += ["--listen", f"tcp/127.0.0.1:{player}", "--wait-subscribers", str(robots)]
        play += ["--wait-timeout", "900"]
        begin = time.monotonic()
        subprocess.run(play, check=True, stdout=subprocess.DEVNULL)
        wall = time.monotonic() - begin
        for p in procs:
            _, err = p.communicate(timeout=600)
            if p.returncode != 0:
                raise SystemExit(f"agent --live failed: {err.strip()}")
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    return out, wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("team", choices=["images", "observations"])
    parser.add_argument("--robots", type=int, default=None)
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--width", type=int, default=640, help="image width (4:3)")
    parser.add_argument(
        "--runs",
        nargs="+",
        default=None,
        metavar="MODE:RATE",
        help="lockstep:R or async:R (default lockstep:0.25 async:1 for images, lockstep:1 "
        "async:10 for observations); async:R:Q runs with max_age_quantile Q (or none) instead "
        "of --max-age-quantile",
    )
    parser.add_argument(
        "--max-age-quantile",
        default="0.95",
        help="the team file's max_age_quantile of the live runs ('none': the age limit is "
        "max_age_steps of a robot's own steps alone, the rule before it was learned)",
    )
    add_option(parser)
    args = parser.parse_args()
    md = Markdown(args.markdown)
    images = args.team == "images"
    robots = args.robots or (3 if images else 5)
    steps = args.steps or (100 if images else 150)
    runs = args.runs or (["lockstep:0.25", "async:1"] if images else ["lockstep:1", "async:10"])
    period = 0.1 if images else 1.0
    quantile = None if args.max_age_quantile == "none" else float(args.max_age_quantile)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if images:
            bag, dataset_dir, inputs, what = images_team(tmp, robots, steps, args.width)
        else:
            bag, dataset_dir, inputs, what = observations_team(tmp, robots, steps)
        # the noise levels calibrated once, as make run does (no robot calibrates at its start)
        subprocess.run(
            _teamslam("calibrate", str(dataset_dir), "--frames", "60", "--write"),
            check=True,
            stdout=subprocess.DEVNULL,
        )
        dataset = load_dataset(dataset_dir)
        offline_file = team_file(tmp, "offline", dataset_dir, robots, "lockstep", inputs, None)
        subprocess.run(
            _teamslam("team", "launch", str(offline_file), "--out", str(tmp / "offline")),
            check=True,
            stdout=subprocess.DEVNULL,
        )
        offline, _ = results(tmp / "offline", robots)
        off_stamps = [
            (
                int(dataset.metadata.get("ros2", {}).get("stamp_origin_ns", 0))
                + np.rint(r.timestamps * 1e9).astype(np.int64)
            ).tolist()
            for r in dataset.robots
        ]
        off_rmse = truth_rmse(dataset, off_stamps, offline)
        md.table(
            f"agent --live on loopback: {what}; offline position RMSE {off_rmse:.4f} m; "
            f"max_age_quantile {args.max_age_quantile}",
            [
                "sync",
                "rate",
                "frame period (ms)",
                "frames",
                "dropped (queue / sync / front-end)",
                "latency p50 (ms)",
                "p99 (ms)",
                "max (ms)",
                "RMSE (m)",
                "RMSE / offline",
                "max |Δ pose| vs offline",
                "averaged",
                "not averaged: not heard / too old / nothing common / no marginal / inconsistent",
                "messages too old",
                "refused",
                "robots' CPU per frame (ms)",
                "cores to keep up",
                "cores had",
            ],
            note="Latency: from the arrival of a frame's camera input to the publication of its "
            "pose (the front-end, waiting for the odometry to cover the stamp, consensus and "
            "the filter); p50 is the median of the robots' medians, p99 and max the largest "
            "over robots. Frames: processed of those in the bag. Δ pose: the largest absolute "
            "difference of a pose matrix entry from the offline run (only when every frame "
            "was processed). Averaged: the share of (frame, neighbour) pairs in which a robot "
            "averaged with that neighbour, and why the others were not (counted per pair): the "
            "neighbour's map ids were not heard, its newest map ids (or marginal) arrived but "
            "older than the age limit, no object to average with it, its marginal did not "
            "arrive, or it failed the consensus innovation check. Messages too old: neighbours' "
            "messages discarded as older than the age limit while the newest of their sender "
            "(asynchronous robots' age limit: learned per neighbour from the lags of its "
            "messages, team file max_age_quantile); refused: neighbours' messages refused by "
            "the checks (of a later step, malformed). CPU: the robot processes' CPU time (user + "
            "system, every thread: front-end, consensus, filter, input decoding, Zenoh) from "
            "each robot's first frame to its last, per frame processed; cores to keep up: that "
            "per frame times the robots' frames per second at the run's rate (every frame "
            "processed); cores had: the robots' CPU time over the time the player played. One "
            "process per robot and the player share the machine's cores.",
        )
        total = sum(r.frames for r in dataset.robots)
        for run in runs:
            mode, rate, *rule = run.split(":")
            rate = float(rate)
            q = quantile if not rule else None if rule[0] == "none" else float(rule[0])
            out, wall = live_run(tmp, bag, dataset_dir, robots, inputs, mode, rate, q)
            poses, summaries = results(out, robots)
            live = [s["live"] for s in summaries]
            frames = sum(s["frames"] for s in live)
            dropped = {k: sum(s["dropped"][k] for s in live) for k in ("queue", "sync", "frontend")}
            rmse = truth_rmse(dataset, [s["stamps_ns"] for s in live], poses)
            cpu = sum(s["cpu_seconds"] for s in live)
            same = frames == total and all(
                p.shape == o.shape for p, o in zip(poses, offline, strict=True)
            )
            diff = "–"
            if same:
                gaps = [float(np.abs(p - o).max()) for p, o in zip(poses, offline, strict=True)]
                diff = f"{max(gaps):.1e}"
            row = (
                mode if not rule else f"{mode}, max_age_quantile {rule[0]}",
                f"{rate:g}",
                f"{period / rate * 1e3:.0f}",
                f"{frames} of {total}",
                f"{dropped['queue']} / {dropped['sync']} / {dropped['frontend']}",
                f"{np.median([s['latency_ms']['p50'] for s in live]):.1f}",
                f"{max(s['latency_ms']['p99'] for s in live):.1f}",
                f"{max(s['latency_ms']['max'] for s in live):.1f}",
                f"{rmse:.4f}",
                f"{rmse / off_rmse:.3f}",
                diff,
                f"{averaged_share(summaries, robots):.2f}",
                " / ".join(
                    str(sum(s["not_averaged"].get(k, 0) for s in summaries))
                    for k in (
                        "not_heard",
                        "too_old",
                        "nothing_common",
                        "no_marginal",
                        "inconsistent",
                    )
                ),
                str(sum(s["counters"].get("messages_too_old", 0) for s in summaries)),
                str(sum(s["counters"].get("rejected_messages", 0) for s in summaries)),
                f"{cpu / max(frames, 1) * 1e3:.0f}",
                f"{cpu / max(frames, 1) * robots * rate / period:.2f}",
                f"{cpu / wall:.2f}",
            )
            print("  ".join(row), flush=True)
            print("\n".join(per_robot(dataset, off_stamps, offline, poses, summaries, robots)))
            md.row(*row)
        md.end()
    md.write()


if __name__ == "__main__":
    main()
