"""Several hosts on one machine: each robot in its own Linux network namespace.

:class:`EmulatedNetwork` makes one namespace per host, joined by veth pairs to a bridge in a hub
namespace and to nothing else, with an optional bandwidth cap per link (``tc`` token bucket)
and random packet loss (``iptables`` statistic match); latency comes from the transport's
injected delay. Needs ``ip``, ``tc`` and ``iptables`` as root or with CAP_NET_ADMIN
(:func:`unavailable_reason` says why not); the context manager removes every namespace and
stops every process it started, also when the body raises.
"""

from __future__ import annotations

import itertools
import json
import os
import shutil
import signal
import subprocess
from dataclasses import dataclass, field

__all__ = ["EmulatedNetwork", "LinkCounters", "unavailable_reason"]

_serial = itertools.count()


def _run(*cmd: str) -> str:
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=30)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)}: {proc.stderr.strip() or proc.returncode}")
    return proc.stdout


def unavailable_reason(loss: bool = True, rate: bool = True) -> str | None:
    """Why network namespaces cannot be used here, or None when they can."""
    tools = ["ip"] + (["tc"] if rate else []) + (["iptables"] if loss else [])
    missing = [t for t in tools if shutil.which(t) is None]
    if missing:
        return f"missing tool(s): {', '.join(missing)}"
    if hasattr(os, "geteuid") and os.geteuid() != 0:
        try:
            with open("/proc/self/status") as f:
                caps = next(line for line in f if line.startswith("CapEff:"))
            if not int(caps.split()[1], 16) & (1 << 12):  # CAP_NET_ADMIN
                return "not root and no CAP_NET_ADMIN: cannot make network namespaces"
        except (OSError, StopIteration, ValueError):
            return "not root: cannot make network namespaces"
    probe = f"tsl-probe-{os.getpid()}-{next(_serial)}"
    try:
        _run("ip", "netns", "add", probe)
    except (RuntimeError, OSError, subprocess.TimeoutExpired) as exc:
        return f"cannot make a network namespace ({exc})"
    try:
        if loss:
            try:
                _run(
                    "ip", "netns", "exec", probe, "iptables", "-A", "INPUT", "-m", "statistic",
                    "--mode", "random", "--probability", "0.5", "-j", "DROP",
                )  # fmt: skip
            except (RuntimeError, OSError) as exc:
                return f"iptables statistic match unavailable ({exc})"
        if rate:
            try:
                _run(
                    "ip", "netns", "exec", probe, "tc", "qdisc", "add", "dev", "lo", "root",
                    "tbf", "rate", "1mbit", "burst", "32kbit", "latency", "400ms",
                )  # fmt: skip
            except (RuntimeError, OSError) as exc:
                return f"tc tbf unavailable ({exc})"
    finally:
        subprocess.run(["ip", "netns", "del", probe], capture_output=True, timeout=30)
    return None


@dataclass
class LinkCounters:
    """What went over one host's link (read from the kernel)."""

    tx_bytes: int
    rx_bytes: int
    dropped_by_loss: int


@dataclass
class EmulatedNetwork:
    """``hosts`` hosts, each in its own network namespace, on one emulated switch.

    Parameters
    ----------
    hosts
        Number of hosts (at most 250).
    rate_mbit
        Bandwidth cap of each direction of each link (None: uncapped).
    loss
        Probability that a packet a host receives is dropped.
    subnet
        First three octets of the hosts' IPv4 addresses (``<subnet>.<1 + host>``); these
        exist only inside the namespaces made here.
    """

    hosts: int
    rate_mbit: float | None = None
    loss: float = 0.0
    subnet: str = "10.77.0"
    prefix: str = field(default="")
    _made: list[str] = field(default_factory=list, repr=False)
    _procs: list[subprocess.Popen] = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        if not 1 <= self.hosts <= 250:
            raise ValueError(f"hosts must lie in 1..250, got {self.hosts}")
        if not 0.0 <= self.loss < 1.0:
            raise ValueError(f"loss must lie in [0, 1), got {self.loss}")
        if self.rate_mbit is not None and not self.rate_mbit > 0:
            raise ValueError(f"rate_mbit must be positive, got {self.rate_mbit}")
        if not self.prefix:
            self.prefix = f"tsl{os.getpid()}-{next(_serial)}"

    # ------------------------------------------------------------------ names
    @property
    def hub(self) -> str:
        """Namespace of the bridge."""
        return f"{self.prefix}-hub"

    def namespace(self, host: int) -> str:
        """Namespace of ``host``."""
        return f"{self.prefix}-h{host}"

    def address(self, host: int) -> str:
        """IPv4 address of ``host`` (inside the namespaces only)."""
        return f"{self.subnet}.{host + 1}"

    # ------------------------------------------------------------------ life cycle
    def __enter__(self) -> EmulatedNetwork:
        try:
            self._create()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _add_namespace(self, name: str) -> None:
        _run("ip", "netns", "add", name)
        self._made.append(name)
        _run("ip", "-n", name, "link", "set", "lo", "up")

    def _tbf(self, namespace: str, device: str) -> None:
        rate = f"{self.rate_mbit * 1000:.0f}kbit"
        # burst ≥ rate / HZ and ≥ one MTU; queue up to 400 ms before dropping
        burst = max(32, int(self.rate_mbit * 1000 / 100))
        _run(
            "ip", "netns", "exec", namespace, "tc", "qdisc", "add", "dev", device, "root",
            "tbf", "rate", rate, "burst", f"{burst}kbit", "latency", "400ms",
        )  # fmt: skip

    def _create(self) -> None:
        self._add_namespace(self.hub)
        _run("ip", "-n", self.hub, "link", "add", "br0", "type", "bridge")
        _run("ip", "-n", self.hub, "link", "set", "br0", "up")
        for h in range(self.hosts):
            ns = self.namespace(h)
            self._add_namespace(ns)
            port = f"p{h}"
            _run(
                "ip", "-n", self.hub, "link", "add", port, "type", "veth",
                "peer", "name", "eth0", "netns", ns,
            )  # fmt: skip
            _run("ip", "-n", self.hub, "link", "set", port, "master", "br0", "up")
            _run("ip", "-n", ns, "addr", "add", f"{self.address(h)}/24", "dev", "eth0")
            _run("ip", "-n", ns, "link", "set", "eth0", "up")
            if self.rate_mbit is not None:
                self._tbf(ns, "eth0")  # what the host sends
                self._tbf(self.hub, port)  # what it receives
            if self.loss > 0:
                _run(
                    "ip", "netns", "exec", ns, "iptables", "-A", "INPUT", "-i", "eth0",
                    "-m", "statistic", "--mode", "random", "--probability", f"{self.loss}",
                    "-j", "DROP",
                )  # fmt: skip

    def popen(self, host: int, command: list[str], **kwargs) -> subprocess.Popen:
        """Start ``command`` inside ``host``'s namespace (stopped again by :meth:`close`)."""
        proc = subprocess.Popen(["ip", "netns", "exec", self.namespace(host), *command], **kwargs)
        self._procs.append(proc)
        return proc

    def counters(self, host: int) -> LinkCounters:
        """Bytes sent and received on ``host``'s link and packets dropped as lost."""
        ns = self.namespace(host)
        link = json.loads(_run("ip", "-j", "-s", "-n", ns, "link", "show", "dev", "eth0"))[0]
        tx, rx = link["stats64"]["tx"]["bytes"], link["stats64"]["rx"]["bytes"]
        dropped = 0
        if self.loss > 0:
            out = _run("ip", "netns", "exec", ns, "iptables", "-L", "INPUT", "-v", "-n", "-x")
            for line in out.splitlines():
                if "statistic" in line and "DROP" in line:
                    dropped += int(line.split()[0])
        return LinkCounters(tx, rx, dropped)

    def close(self) -> None:
        """Stop the processes started here and delete every namespace made (idempotent)."""
        for proc in self._procs:
            if proc.poll() is None:
                try:
                    proc.send_signal(signal.SIGKILL)
                except ProcessLookupError:
                    pass
                proc.wait(timeout=10)
        self._procs.clear()
        for name in reversed(self._made):
            subprocess.run(["ip", "netns", "del", name], capture_output=True, timeout=30)
        self._made.clear()

    def leftover(self) -> list[str]:
        """Namespaces of this network that still exist (empty after :meth:`close`)."""
        listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
        return [line.split()[0] for line in listed.splitlines() if line.startswith(self.prefix)]
