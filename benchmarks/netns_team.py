"""A team on several emulated hosts vs loopback: accuracy, bytes and step latency.

Each robot runs as its own process in its own Linux network namespace, joined to the others
through a bridge by a veth link capped at ``--rate-mbit`` (tc tbf, each direction) that drops
``--loss`` of the packets it delivers (iptables statistic match); latency is added with the
transport's injected delay (``--delay-ms``). The same team runs once on loopback. Needs root
(or CAP_NET_ADMIN), iproute2, tc and iptables. Run on demand::

    OPENBLAS_NUM_THREADS=1 python benchmarks/netns_team.py [--robots 5] [--steps 40] \\
        [--rate-mbit 1] [--loss 0.1] [--delay-ms 0] [--timeout-s 10] [--plain] \\
        [--set consensus.kl_threshold=0.05]

Prints per run: trajectory RMSE (team average), payload and link bytes per robot per step,
step latency (median and p95 over robots' steps), links lost and wall time, and the ratios.
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
from teamslam.eval.metrics import team_metrics
from teamslam.eval.outputs import json_safe
from teamslam.graph import complete
from teamslam.msckf.settings.sources import parse_assignments
from teamslam.runtime.agent_process import load_robot_result
from teamslam.runtime.launch import agent_command, gather
from teamslam.runtime.netns import EmulatedNetwork, unavailable_reason
from teamslam.runtime.security import SecuritySection, make_team_certificates
from teamslam.runtime.team_file import load_team_file, write_team_file
from teamslam.sim import lissajous_team


def _run(args, dataset, data_dir: Path, work: Path, net: EmulatedNetwork | None) -> dict:
    n = dataset.n_robots
    hosts = [net.address(i) for i in range(n)] if net is not None else ["127.0.0.1"] * n
    security = None
    if not args.plain:
        made = make_team_certificates(
            "bench", {i: (f"robot-{i}", h) for i, h in enumerate(hosts)}, work / "certs"
        )
        security = SecuritySection(made.ca_certificate, made.robots)
    team_path = write_team_file(
        work / "team.yaml",
        f"bench-{work.name}",
        data_dir,
        complete(n).adjacency,
        base_port=7447 if net is not None else 17700,
        security=security,
        host=hosts,
        shared_memory=False,
        timeout_s=args.timeout_s,
        message_delay_ms=args.delay_ms,
        settings={"filter.window": args.window, **json_safe(parse_assignments(args.set))},
    )
    out = work / "out"
    begin = time.perf_counter()
    if net is None:
        procs = [
            subprocess.Popen(agent_command(team_path, i, out), stdout=subprocess.DEVNULL)
            for i in range(n)
        ]
    else:
        procs = [
            net.popen(i, agent_command(team_path, i, out), stdout=subprocess.DEVNULL)
            for i in range(n)
        ]
    codes = [p.wait() for p in procs]
    wall = time.perf_counter() - begin
    if any(codes):
        raise SystemExit(f"robots exited with {codes} (logs: run with a terminal)")
    link_bytes = [net.counters(i).tx_bytes for i in range(n)] if net is not None else None
    team = load_team_file(team_path)
    metrics = team_metrics(dataset, gather(team, out))
    summaries = [load_robot_result(out, i)[1] for i in range(n)]
    steps = dataset.robots[0].frames - 1
    return {
        "rmse": metrics["trajectory_rmse_avg_m"],
        "payload_per_step": float(np.mean([s["bytes_per_step"] for s in summaries])),
        "link_per_step": float(np.mean(link_bytes)) / steps if link_bytes else None,
        "step_median_ms": float(np.median([s["step_latency_ms"]["median"] for s in summaries])),
        "step_p95_ms": float(np.median([s["step_latency_ms"]["p95"] for s in summaries])),
        "links_lost": int(sum(s["counters"].get("links_lost", 0) for s in summaries)),
        "wall_s": wall,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=5)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--window", type=int, default=10)
    parser.add_argument("--rate-mbit", type=float, default=1.0)
    parser.add_argument("--loss", type=float, default=0.1)
    parser.add_argument("--delay-ms", type=float, default=0.0)
    parser.add_argument("--timeout-s", type=float, default=10.0)
    parser.add_argument("--plain", action="store_true", help="TCP instead of mutual TLS")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a filter setting for every robot (repeatable)",
    )
    args = parser.parse_args()
    reason = unavailable_reason()
    if reason is not None:
        sys.exit(f"cannot emulate hosts here: {reason}")
    dataset = lissajous_team(robots=args.robots, steps=args.steps, seed=0)
    with tempfile.TemporaryDirectory() as tmp:
        data_dir = Path(tmp) / "data"
        save_dataset(dataset, data_dir)
        (Path(tmp) / "lo").mkdir()
        (Path(tmp) / "ns").mkdir()
        loopback = _run(args, dataset, data_dir, Path(tmp) / "lo", None)
        with EmulatedNetwork(args.robots, args.rate_mbit, args.loss, subnet="10.77.0") as net:
            emulated = _run(args, dataset, data_dir, Path(tmp) / "ns", net)
    print(
        f"{args.robots} robots, complete graph, {args.steps} steps, window {args.window}, "
        f"{'TCP' if args.plain else 'mutual TLS'}, lock-step timeout {args.timeout_s:g} s"
    )
    label = f"{args.rate_mbit:g} Mbit/s, {args.loss:.0%} loss, +{args.delay_ms:g} ms"
    print(f"{'':34s}{'loopback':>14s}{label:>30s}{'ratio':>8s}")
    rows = [
        ("trajectory RMSE avg [m]", "rmse", "{:.4f}"),
        ("payload bytes / robot / step", "payload_per_step", "{:.0f}"),
        ("link bytes / robot / step", "link_per_step", "{:.0f}"),
        ("step latency median [ms]", "step_median_ms", "{:.1f}"),
        ("step latency p95 [ms]", "step_p95_ms", "{:.1f}"),
        ("links lost (robot-steps)", "links_lost", "{:d}"),
        ("wall time [s]", "wall_s", "{:.1f}"),
    ]
    for name, key, fmt in rows:
        a, b = loopback[key], emulated[key]
        fa = "—" if a is None else fmt.format(a)
        ratio = f"{b / a:.2f}" if a not in (None, 0) and b is not None else ""
        print(f"{name:34s}{fa:>14s}{fmt.format(b):>30s}{ratio:>8s}")


if __name__ == "__main__":
    main()
