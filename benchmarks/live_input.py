"""Live input on loopback: a rendered team's bag played by ``teamslam bag play`` into a subscriber.

Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/live_input.py [--robots 3] [--steps 100] \\
        [--width 640] [--rates 0 1 4] [--markdown FILE]

Renders a team (``teamslam simulate --images``), then for each rate plays its ``images.mcap``
with ``teamslam bag play`` in its own process into one :class:`~teamslam.ros2.live.Ros2Subscriber`
in this process (every topic; each robot's left and right images paired by
:class:`~teamslam.ros2.live.ApproximateTimeSync` with tolerance 0). Per rate: messages published
and received (any loss shows), stereo pairs formed, payload throughput between the first and
the last arrival, and each message's lateness: its arrival minus its recorded offset divided by
the rate, relative to the message for which that difference is least (what a live robot sees of
the player's schedule, the transport and the subscriber's decoding together, beyond the best
case; rate 0 has no schedule to be late on).
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from _markdown import Markdown, add_option
from teamslam.ros2.bag_play import bag_topics
from teamslam.ros2.live import ApproximateTimeSync, Ros2Subscriber


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _listening(port: int):
    import zenoh

    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("peer"))
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    config.insert_json5("connect/endpoints", "[]")
    config.insert_json5("scouting/multicast/enabled", "false")
    return config


def play_once(bag: Path, rate: float, topics: dict[str, str], robots: list[str]) -> dict:
    """One play of ``bag`` at ``rate`` into a fresh subscriber; what arrived and when."""
    port = _free_port()
    lock = threading.Lock()
    arrivals: list[tuple[int, int, int]] = []  # (received ns, log ns, bytes)
    syncs = {
        r: ApproximateTimeSync([f"/{r}/left/image_raw", f"/{r}/right/image_raw"], 0, 10)
        for r in robots
    }
    pairs = dict.fromkeys(robots, 0)

    def on_item(item) -> None:
        with lock:
            size = len(getattr(item.message, "data", b""))
            arrivals.append((item.received_ns, item.source_ns, size))
            robot = item.topic.split("/")[1]
            if item.topic.endswith("/image_raw"):
                pairs[robot] += len(syncs[robot].add(item))

    sub = Ros2Subscriber(topics, on_item, config=_listening(port))
    argv = [sys.executable, "-m", "teamslam", "bag", "play", str(bag), "--rate", f"{rate:g}"]
    argv += ["--connect", f"tcp/127.0.0.1:{port}", "--listen", "tcp/127.0.0.1:0"]
    argv += ["--wait-subscribers", "1", "--wait-timeout", "60"]
    try:
        done = subprocess.run(argv, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise SystemExit(f"bag play failed: {done.stderr.strip()}")
        published = int(done.stdout.rsplit("published ", 1)[1].split()[0])
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and sum(sub.counts.values()) < published:
            time.sleep(0.05)
    finally:
        sub.close()
    received = np.array(arrivals, dtype=np.int64).reshape(-1, 3)
    order = np.argsort(received[:, 0], kind="stable")
    received = received[order]
    span = (received[-1, 0] - received[0, 0]) / 1e9 if len(received) > 1 else float("nan")
    out = {
        "published": published,
        "received": int(sum(sub.counts.values())),
        "errors": int(sum(sub.errors.values())),
        "pairs": int(sum(pairs.values())),
        "mb_per_s": received[:, 2].sum() / 1e6 / span if span > 0 else float("nan"),
        "span_s": span,
    }
    if rate > 0 and len(received):
        due = received[:, 0] - (received[:, 1] - received[:, 1].min()) / rate
        late = due - due.min()
        out["lateness_ms"] = np.percentile(late / 1e6, [50, 95, 100])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=3)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--width", type=int, default=640, help="image width (4:3)")
    parser.add_argument("--rates", type=float, nargs="+", default=[0.0, 1.0, 4.0])
    parser.add_argument("--seed", type=int, default=0)
    add_option(parser)
    args = parser.parse_args()
    md = Markdown(args.markdown)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "team"
        argv = [sys.executable, "-m", "teamslam", "simulate", "--images", "--quiet"]
        argv += ["--robots", str(args.robots), "--steps", str(args.steps)]
        argv += ["--image-width", str(args.width), "--seed", str(args.seed), "--out", str(out)]
        subprocess.run(
            argv,
            check=True,
            stdout=subprocess.DEVNULL,
        )
        bag = out / "images.mcap"
        listed = bag_topics(bag)
        topics = {t: mt for t, (mt, _) in listed.items()}
        robots = sorted({t.split("/")[1] for t in topics})
        frames = listed[f"/{robots[0]}/left/image_raw"][1]
        height = args.width * 3 // 4
        md.table(
            f"bag play → subscriber on loopback: {len(robots)} robots × {frames} stereo frames "
            f"({args.width}×{height} mono8, 10 Hz), {sum(n for _, n in listed.values())} "
            f"messages, {bag.stat().st_size / 1e6:.0f} MB bag",
            [
                "rate",
                "published",
                "received",
                "refused",
                "stereo pairs",
                "MB/s",
                "lateness median (ms)",
                "p95 (ms)",
                "max (ms)",
            ],
            note="Lateness: a message's arrival minus its recorded offset divided by the rate, "
            "relative to the message for which that is least. Player and subscriber are "
            "separate processes on the same machine.",
        )
        for rate in args.rates:
            r = play_once(bag, rate, topics, robots)
            late = r.get("lateness_ms")
            cells = ["–"] * 3 if late is None else [f"{v:.1f}" for v in late]
            row = (
                "as fast as possible" if rate == 0 else f"{rate:g}",
                str(r["published"]),
                str(r["received"]),
                str(r["errors"]),
                f"{r['pairs']} of {len(robots) * frames}",
                f"{r['mb_per_s']:.0f}",
                *cells,
            )
            print("  ".join(row), flush=True)
            md.row(*row)
        md.end()
    md.write()


if __name__ == "__main__":
    main()
