"""Several hosts emulated: each robot in its own network namespace, capped and lossy links.

Needs root (or CAP_NET_ADMIN), iproute2, tc and iptables; skips with the reason otherwise.
Addresses 10.77.x.y exist only inside the namespaces the tests make, and every namespace is
removed again, also when a test fails.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from teamslam.datasets import save_dataset
from teamslam.graph import complete
from teamslam.msckf import config_for, run_team
from teamslam.runtime.agent_process import load_robot_result
from teamslam.runtime.launch import agent_command
from teamslam.runtime.netns import EmulatedNetwork, unavailable_reason
from teamslam.runtime.security import SecuritySection, make_team_certificates
from teamslam.runtime.team_file import write_team_file
from teamslam.sim import lissajous_team

_REASON = unavailable_reason()
#: seconds a robot waits for a message before giving up on it: a guard against a hung peer
_GUARD_S = 900.0
pytestmark = pytest.mark.skipif(_REASON is not None, reason=f"network namespaces: {_REASON}")


def test_namespaces_are_removed_when_the_body_fails():
    net = EmulatedNetwork(2, rate_mbit=1.0, loss=0.1, subnet="10.77.9")
    with pytest.raises(RuntimeError, match="boom"), net:
        assert len(net.leftover()) == 3
        sleeper = net.popen(0, [sys.executable, "-c", "import time; time.sleep(60)"])
        raise RuntimeError("boom")
    assert net.leftover() == []
    assert sleeper.poll() is not None  # stopped, not left running


def test_secured_team_on_three_emulated_hosts_with_capped_lossy_links(tmp_path):
    """1 Mbit/s per link, 10% loss, mutual TLS between 10.77.0.1–3: the loopback result.

    What the protocol guarantees, whatever the machine's load: lock-step robots wait for every
    message of a step (TCP retransmits what the link drops, a full queue blocks the sender), so
    no link is lost and each robot's estimate is the in-process one. The lock-step timeout is
    only a guard against a hung peer, far beyond any wait a slow (loaded) robot causes: with
    a timeout a loaded robot can outlast (its first frame compiles the kernels), a neighbour
    counts a lost link and the estimates differ.
    """
    dataset = lissajous_team(robots=3, steps=16, seed=1, landmarks=600)
    save_dataset(dataset, tmp_path / "data")
    with EmulatedNetwork(3, rate_mbit=1.0, loss=0.1, subnet="10.77.0") as net:
        hosts = [net.address(i) for i in range(3)]
        made = make_team_certificates(
            "hosts", {i: (f"robot-{i}", h) for i, h in enumerate(hosts)}, tmp_path / "certs"
        )
        team_path = write_team_file(
            tmp_path / "team.yaml",
            "hosts",
            tmp_path / "data",
            complete(3).adjacency,
            base_port=7447,
            security=SecuritySection(made.ca_certificate, made.robots),
            host=hosts,
            shared_memory=False,  # every byte over the emulated links
            timeout_s=_GUARD_S,  # wait for the messages (events), not for a clock
            settings={"filter.window": 8},
        )
        procs = [
            net.popen(
                i,
                agent_command(team_path, i, tmp_path / "out"),
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
            )
            for i in range(3)
        ]
        outputs = [p.communicate(timeout=2 * _GUARD_S)[0].decode() for p in procs]
        counters = [net.counters(i) for i in range(3)]
    assert net.leftover() == []
    for p, out in zip(procs, outputs, strict=True):
        assert p.returncode == 0, out
    reference = run_team(dataset, config_for(dataset, {"filter.window": 8}), progress=False)
    for r in range(3):
        arrays, summary = load_robot_result(tmp_path / "out", r)
        # the messages crossed the host's link (TLS and TCP add to the payload) …
        assert counters[r].tx_bytes > summary["counters"]["bytes"]
        # … and the link dropped some of the packets the host should have received
        assert counters[r].dropped_by_loss > 0
        assert summary["counters"].get("links_lost", 0) == 0
        np.testing.assert_allclose(arrays["poses"], reference.poses[r], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(arrays["objects"], reference.objects[r], rtol=1e-9, atol=1e-9)
