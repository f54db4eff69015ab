"""The cost of a live robot's Foxglove view, per frame, without and with a client on loopback.

Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/foxglove_view.py [--steps 150] \\
        [--image-steps 60] [--width 640] [--markdown FILE]

Two robots on live inputs (:class:`~teamslam.live.LiveRobot` fed a bag's messages in this
process, as the tests feed them): robot 0 of a simulated team on its observations
(``lissajous_team``, as ``teamslam simulate`` makes it), and a rendered robot on its stereo
images with a simulated detector's boxes (the image front-end and the tracker run). After a
run that warms up what is compiled on first use, each is run three times: without a view, with
a :class:`~teamslam.viz.foxglove.FoxgloveView` no client connects to, and with one whose every
channel one Foxglove WebSocket client (subprotocol ``foxglove.sdk.v1``, on loopback, in a
process of its own as a viewer is) subscribes to. Per run: the median, 95th percentile and
largest time of the view's ``publish`` per frame (in the robot's thread: what the filter waits
for), the median of the robot's step after its front-end (consensus, filter, publication and
the view: ``LiveRobot.step_seconds``) for scale, the messages and bytes the client received,
and whether the estimates equal those of the run without a view (they must, bit for bit).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _markdown import Markdown, add_option
from teamslam.live import LiveInputs, LiveRobot
from teamslam.runtime.team_file import RobotEntry, TeamFile
from teamslam.viz.foxglove import FoxgloveView

SUBPROTOCOL = "foxglove.sdk.v1"  # the SDK's name of the Foxglove WebSocket protocol
ODOM, OBS = "/robot_0/odom", "/robot_0/stereo_observations"
LEFT, RIGHT = "/robot_0/left/image_raw", "/robot_0/right/image_raw"
INFO = ("/robot_0/left/camera_info", "/robot_0/right/camera_info")
TRUTH, BOXES = "/robot_0/ground_truth", "/robot_0/detections"


class TimedView(FoxgloveView):
    """A view that times each of its ``publish`` calls."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.seconds: list[float] = []

    def publish(self, *args, **kwargs) -> None:
        begin = time.perf_counter()
        super().publish(*args, **kwargs)
        self.seconds.append(time.perf_counter() - begin)


def count_messages(url: str, channels: int) -> None:
    """The client's process: subscribe to every channel of the server at ``url``, count the
    messages and bytes that arrive until the server closes, print them as JSON."""
    from websockets.sync.client import connect

    messages = size = 0
    with connect(url, subprotocols=[SUBPROTOCOL], open_timeout=30) as ws:
        advertised: dict[int, dict] = {}
        while len(advertised) < channels:
            text = json.loads(ws.recv(timeout=30))
            if text["op"] == "advertise":
                advertised.update({c["id"]: c for c in text["channels"]})
        subscriptions = [{"id": k + 1, "channelId": cid} for k, cid in enumerate(advertised)]
        ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
        try:
            for frame in ws:
                if isinstance(frame, bytes) and frame[0] == 0x01:  # message data
                    messages += 1
                    size += len(frame) - 13
        except Exception:  # the server went away
            pass
    print(json.dumps({"messages": messages, "bytes": size}), flush=True)


class CountingClient:
    """A Foxglove WebSocket client in a process of its own (as a viewer is), subscribed to
    every channel; what it counted once the server closes."""

    def __init__(self, url: str, channels: int) -> None:
        argv = [sys.executable, __file__, "--client", url, "--channels", str(channels)]
        self.process = subprocess.Popen(argv, stdout=subprocess.PIPE, text=True)

    def counts(self) -> dict:
        out, _ = self.process.communicate(timeout=60)
        return json.loads(out.strip().splitlines()[-1])


def bag_messages(bag: Path, topics: set[str]) -> list:
    """The bag's messages on ``topics`` in recorded order, as a subscriber hands them over."""
    from teamslam.ros2 import messages as m
    from teamslam.ros2.live import Received

    out = []
    with m.rosbags("highlevel").AnyReader([bag], default_typestore=m.typestore()) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        for conn, _, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            out.append(Received(conn.topic, conn.msgtype, m.stamp_ns(msg.header.stamp), msg, 0))
    return out


def observations_case(tmp: Path, steps: int):
    from teamslam.msckf.configure import build_settings
    from teamslam.ros2.bags import RobotTopics, export_bag, import_bag
    from teamslam.sim import lissajous_team

    team = lissajous_team(robots=5, steps=steps, seed=0)
    bag, camera = tmp / "team.mcap", tmp / "camera.json"
    export_bag(team, bag, camera=camera)
    dataset = import_bag(bag, [RobotTopics("robot_0", ODOM)], OBS, camera)
    config = build_settings(dataset, calibrate="never").config
    inputs = LiveInputs(ODOM, observations=OBS, queue=100_000)
    return inputs, config, dataset.calibration, bag_messages(bag, {ODOM, OBS})


def images_case(tmp: Path, steps: int, width: int):
    from teamslam.datasets.images import rendered_team_inputs
    from teamslam.msckf.configure import build_settings
    from teamslam.ros2.image_bags import ImageTopics, dataset_from_bag, images_to_bag
    from teamslam.sim.detector import DetectorConfig
    from teamslam.sim.render import RenderConfig, render_team

    config = RenderConfig(
        image_size=(width, width * 3 // 4),
        focal=width * 0.66,
        layout="street",
        objects="shapes",
        robots=1,
        steps=steps,
        markers_per_wall=0,
    )
    render_team(config, tmp / "rendered", detector=DetectorConfig())
    rendered = rendered_team_inputs(tmp / "rendered")
    bag = tmp / "boxes.mcap"
    images_to_bag(
        rendered["left_dirs"],
        rendered["right_dirs"],
        rendered["camera"],
        rendered["timestamps"],
        bag,
        odometry=rendered["odometry"],
        ground_truth=rendered["ground_truth"],
        robot_names=["robot_0"],
        detections=rendered["detections"],
    )
    topics = dataclasses.replace(ImageTopics.default("robot_0"), detections=BOXES)
    dataset = dataset_from_bag(bag, [topics], progress=False)
    settings = build_settings(dataset, calibrate="never").config
    inputs = LiveInputs(
        ODOM, left=LEFT, right=RIGHT, camera_info=INFO, queue=100_000, ground_truth=TRUTH,
        detections=BOXES,
    )  # fmt: skip
    items = bag_messages(bag, {ODOM, LEFT, RIGHT, TRUTH, BOXES, *INFO})
    return inputs, settings, None, items


def run(case, out: Path, view_mode: str) -> dict:
    """One robot over the case's messages; ``view_mode``: ``none``, ``no client``, ``client``."""
    inputs, config, calibration, items = case
    team = TeamFile(
        team="view", dataset=None, robots=[RobotEntry(0, "tcp/127.0.0.1:0", [])],
        checkpoint_every=0,
    )  # fmt: skip
    view = None if view_mode == "none" else TimedView(0, "127.0.0.1", 0)
    client = counts = None
    try:
        if view_mode == "client":
            client = CountingClient(view.url, len(view.topics))
            deadline = time.monotonic() + 30
            while not all(map(view.subscribed, view.topics)) and time.monotonic() < deadline:
                time.sleep(0.01)
        robot = LiveRobot(
            team, 0, inputs, config, out, calibration=calibration, view=view, say=lambda s: None
        )
        for item in items:
            robot.feed(dataclasses.replace(item, received_ns=time.monotonic_ns()))
        robot.finish()
        robot.run()
        if client is not None:  # what is under way arrives
            time.sleep(1.0)
    finally:
        if view is not None:
            view.close()
        if client is not None:
            counts = client.counts()
    frames = robot.sequence.frames
    return {
        "frames": frames,
        "poses": robot.driver.poses[:frames].copy(),
        "view_ms": None if view is None else np.asarray(view.seconds) * 1e3,
        "step_ms": np.asarray(robot.step_seconds) * 1e3,
        "messages": None if counts is None else counts["messages"],
        "bytes": None if counts is None else counts["bytes"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=150, help="frames of the observations robot")
    parser.add_argument("--image-steps", type=int, default=60, help="frames of the image robot")
    parser.add_argument("--width", type=int, default=640, help="image width, pixels")
    parser.add_argument("--client", metavar="URL", help=argparse.SUPPRESS)
    parser.add_argument("--channels", type=int, help=argparse.SUPPRESS)
    add_option(parser)
    args = parser.parse_args()
    if args.client:  # the client's own process
        count_messages(args.client, args.channels)
        return
    md = Markdown(args.markdown)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cases = {
            "observations": observations_case(tmp / "obs", args.steps),
            f"images {args.width} px, boxes": images_case(
                tmp / "img", args.image_steps, args.width
            ),
        }
        md.table(
            "Cost of the Foxglove view per frame (in the robot's thread)",
            [
                "robot",
                "view",
                "frames",
                "view p50 ms",
                "view p95 ms",
                "view max ms",
                "step p50 ms",
                "messages received",
                "MB received",
                "estimates as without a view",
            ],
            "step: the robot's step after its front-end (consensus, filter, publication, the "
            "view), for scale; a client subscribes to every channel (pose, path, map, /tf, "
            "image, boxes, calibration, latency).",
        )
        for name, case in cases.items():
            (tmp / name).mkdir()
            run(case, tmp / name / "warm-up", "none")  # compiles what numba compiles
            results = {m: run(case, tmp / name / m.replace(" ", "-"), m) for m in MODES}
            for mode, r in results.items():
                same = np.array_equal(r["poses"], results["none"]["poses"])
                view = r["view_ms"]
                cells = (
                    ("–",) * 3
                    if view is None
                    else tuple(f"{v:.3f}" for v in np.percentile(view, [50, 95, 100]))
                )
                row = (
                    name,
                    mode,
                    str(r["frames"]),
                    *cells,
                    f"{np.median(r['step_ms']):.1f}",
                    "–" if r["messages"] is None else str(r["messages"]),
                    "–" if r["bytes"] is None else f"{r['bytes'] / 1e6:.2f}",
                    "yes" if same else "NO",
                )
                print(" | ".join(row), flush=True)
                md.row(*row)
        md.end()
    md.write()


MODES = ("none", "no client", "client")

if __name__ == "__main__":
    main()
