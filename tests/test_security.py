"""Secured teams: certificates, the security section, mutual TLS, access control, strangers.

Every network test stays on loopback, on ports 30800–32767 (below the ephemeral range and
apart from test_runtime's).
"""

from __future__ import annotations

import ipaddress
import json
import os
import stat
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.x509.oid import NameOID

from teamslam.datasets import save_dataset
from teamslam.errors import InputError
from teamslam.graph import complete
from teamslam.msckf import config_for, run_team
from teamslam.msckf.consensus.messages import CommonMarginalMessage, MapIdsMessage
from teamslam.runtime.agent_process import load_robot_result
from teamslam.runtime.launch import agent_command
from teamslam.runtime.security import (
    SecuritySection,
    apply_settings,
    check_credentials,
    endpoint_host,
    make_team_certificates,
    zenoh_security_settings,
)
from teamslam.runtime.team_file import TeamFileError, load_team_file, write_team_file
from teamslam.runtime.wire import encode, team_id
from teamslam.sim import lissajous_team


def _port(offset: int) -> int:
    """Loopback ports 30800–32767, distinct per test (offsets 0–31)."""
    return 30800 + (os.getpid() % 60) * 32 + offset


def _load(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


# ------------------------------------------------------------------ certificates
def test_certificates_name_the_robot_and_its_host_and_chain_to_the_team_ca(tmp_path):
    robots = {0: ("alpha", "127.0.0.1"), 1: ("bravo", "bravo.field.example"), 2: ("c", "::1")}
    made = make_team_certificates("t", robots, tmp_path / "certs")
    ca = _load(made.ca_certificate)
    assert ca.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    for robot, (name, host) in robots.items():
        creds = made.robots[robot]
        cert = _load(creds.certificate)
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == name
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        try:
            assert san.get_values_for_type(x509.IPAddress) == [ipaddress.ip_address(host)]
        except ValueError:
            assert san.get_values_for_type(x509.DNSName) == [host]
        assert not cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
        cert.verify_directly_issued_by(ca)  # raises if the CA did not sign it
        key = serialization.load_pem_private_key(creds.key.read_bytes(), None)
        assert key.public_key().public_numbers() == cert.public_key().public_numbers()
        assert stat.S_IMODE(creds.key.stat().st_mode) == 0o600
    assert stat.S_IMODE(made.ca_key.stat().st_mode) == 0o600
    # a second call reuses the CA: the old certificates still chain to it
    again = make_team_certificates("t", {3: ("delta", "10.0.0.4")}, tmp_path / "certs")
    assert again.ca_certificate.read_bytes() == made.ca_certificate.read_bytes()
    _load(again.robots[3].certificate).verify_directly_issued_by(ca)
    other = make_team_certificates("t", {0: ("alpha", "127.0.0.1")}, tmp_path / "other")
    with pytest.raises(InvalidSignature):
        _load(other.robots[0].certificate).verify_directly_issued_by(ca)
    with pytest.raises(InputError, match="distinct"):
        make_team_certificates("t", {0: ("x", "h"), 1: ("x", "h")}, tmp_path / "dup")


def test_endpoint_host():
    assert endpoint_host("tls/127.0.0.1:7447") == "127.0.0.1"
    assert endpoint_host("tls/robot-3.lan:7447") == "robot-3.lan"
    assert endpoint_host("tls/[fe80::1]:7447") == "fe80::1"
    for bad in ("127.0.0.1:7447", "tls/nohost", "tls/:7447", "tls/[::1:7447"):
        with pytest.raises(InputError):
            endpoint_host(bad)


def _secured_team_file(tmp_path: Path, directory: Path, base_port: int, name: str, **settings):
    made = make_team_certificates(
        name, {i: (f"robot-{i}", "127.0.0.1") for i in range(3)}, tmp_path / "certs"
    )
    security = SecuritySection(made.ca_certificate, made.robots)
    path = write_team_file(
        tmp_path / "team.yaml",
        name,
        directory,
        complete(3).adjacency,
        base_port=base_port,
        security=security,
        **settings,
    )
    return path, made


def test_security_section_round_trip_and_validation(tmp_path):
    path, made = _secured_team_file(tmp_path, tmp_path, 17400, "t")
    team = load_team_file(path)
    assert team.security is not None
    assert team.security.ca_certificate.resolve() == made.ca_certificate.resolve()
    assert team.security.robots[2].key.resolve() == made.robots[2].key.resolve()
    assert all(r.listen.startswith("tls/127.0.0.1:") for r in team.robots)
    assert [r.name for r in team.robots] == ["robot-0", "robot-1", "robot-2"]
    text = path.read_text()
    cases = {
        text.replace("tls/127.0.0.1:17401", "tcp/127.0.0.1:17401"): "must listen on tls/",
        text.replace("  verify_name: true\n", "  verify_name: maybe\n"): "verify_name",
        text.replace("  - id: 2\n    key:", "  - id: 7\n    key:"): "not a robot",
        text.replace("security:\n", "security:\n  colour: red\n"): "unknown field",
    }
    no_section = text.split("security:")[0]
    cases[no_section] = "no 'security' section"
    for bad, reason in cases.items():
        f = tmp_path / "bad.yaml"
        f.write_text(bad)
        with pytest.raises(TeamFileError, match=reason):
            load_team_file(f)


def test_missing_or_malformed_key_is_a_one_line_error(tmp_path):
    path, made = _secured_team_file(tmp_path, tmp_path, 17400, "t")
    team = load_team_file(path)
    assert check_credentials(team.security, 1) == team.security.robots[1]
    made.robots[1].key.unlink()
    with pytest.raises(InputError, match="robot 1: cannot read its private key") as info:
        check_credentials(team.security, 1)
    assert "\n" not in str(info.value)
    made.robots[2].key.write_text("-----BEGIN PRIVATE KEY-----\nnot base64\n")
    with pytest.raises(InputError, match=r"robot-2\.key is not a PEM private key") as info:
        check_credentials(team.security, 2)
    assert "\n" not in str(info.value)


def test_agent_with_a_missing_key_exits_2_with_one_line(tmp_path):
    path, made = _secured_team_file(tmp_path, tmp_path / "no-data", 17400, "t")
    made.robots[0].key.unlink()
    proc = subprocess.run(
        [sys.executable, "-m", "teamslam", "agent", "--team", str(path), "--robot", "0"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    # the dataset is missing too, so the key is checked before the dataset is read
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "cannot read its private key" in lines[0], proc.stderr


def test_team_certs_command_secures_a_team_file(tmp_path, capsys):
    from teamslam.cli import main

    plain = write_team_file(tmp_path / "team.yaml", "field", tmp_path, complete(3).adjacency)
    assert main(["team", "certs", str(plain), "--out", str(tmp_path / "keys")]) == 0
    team = load_team_file(plain)
    assert team.security is not None
    assert [r.listen for r in team.robots] == [f"tls/127.0.0.1:{17400 + i}" for i in range(3)]
    for r in team.robots:
        cert = _load(team.security.robots[r.id].certificate)
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == r.name
        assert stat.S_IMODE(team.security.robots[r.id].key.stat().st_mode) == 0o600
    assert (tmp_path / "team.yaml.bak").exists()
    assert "robot 2 'robot-2'" in capsys.readouterr().out


# ------------------------------------------------------------------ strangers on the wire
@pytest.fixture(scope="module")
def small_team(tmp_path_factory):
    directory = tmp_path_factory.mktemp("team") / "data"
    dataset = lissajous_team(robots=3, steps=24, seed=1, landmarks=600)
    save_dataset(dataset, directory)
    return dataset, directory


def _stranger_session(endpoints: list[str], tls: dict | None):
    import zenoh

    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("peer"))
    config.insert_json5("listen/endpoints", "[]")
    config.insert_json5("connect/endpoints", json.dumps(endpoints))
    config.insert_json5("scouting/multicast/enabled", "false")
    if tls is not None:
        apply_settings(config, tls)
    return zenoh.open(config)


def _forged(team_name: str, sender: int, receiver: int, step: int, ids) -> bytes:
    """A well-formed marginal in a neighbour's name: objects at the origin, tiny covariance."""
    ids = np.asarray(ids, dtype=np.int64)
    d = 3 * ids.size
    msg = CommonMarginalMessage(sender, receiver, step, ids, np.zeros(d), 1e-6 * np.eye(d))
    return encode(msg, team_id(team_name))


def test_strangers_are_kept_out_of_a_secured_team(small_team, tmp_path):
    """No TLS, another CA, a team-CA certificate of a non-member: not one byte gets in."""
    import zenoh

    dataset, directory = small_team
    name = f"sec-{os.getpid()}"
    base = _port(0)
    team_path, made = _secured_team_file(
        tmp_path, directory, base, name, timeout_s=20.0, settings={"filter.window": 8}
    )
    team = load_team_file(team_path)
    endpoints = [r.listen for r in team.robots]
    other_ca = make_team_certificates("other", {0: ("robot-1", "127.0.0.1")}, tmp_path / "o")
    intruder = make_team_certificates(name, {9: ("intruder", "127.0.0.1")}, tmp_path / "certs")
    members = {r.id: r.name for r in team.robots}

    def tls_for(creds) -> dict:
        # the stranger knows the team CA (a public certificate) and the team's rules
        section = SecuritySection(made.ca_certificate, {9: creds}, verify_name=False)
        return zenoh_security_settings(section, 9, name, members)

    procs = [
        subprocess.Popen(
            agent_command(team_path, r, tmp_path / "out"),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
        )
        for r in range(3)
    ]
    # a robot writes progress.json once its session listens: then the strangers come, each in
    # its own thread (opening a session whose handshake is refused can take seconds)
    deadline = time.monotonic() + 120
    while not all((tmp_path / "out" / f"robot_{r}" / "progress.json").exists() for r in range(3)):
        assert time.monotonic() < deadline and all(p.poll() is None for p in procs)
        time.sleep(0.02)
    strangers = {
        "no TLS": ([e.replace("tls/", "tcp/") for e in endpoints], None),
        "other CA": (endpoints, tls_for(other_ca.robots[0])),
        "non-member": (endpoints, tls_for(intruder.robots[9])),
    }
    stop = threading.Event()
    published = dict.fromkeys(strangers, 0)
    links = dict.fromkeys(strangers, 0)  # most links each stranger ever had at once
    overheard = []
    ids = dataset.object_ids[:6]

    def attack(label: str) -> None:
        session = _stranger_session(*strangers[label])
        subscriber = session.declare_subscriber(
            f"teamslam/{name}/**",
            lambda sample: overheard.append(sample),
            allowed_origin=zenoh.Locality.REMOTE,  # not the stranger's own puts
        )
        try:
            while not stop.is_set():
                links[label] = max(links[label], len(list(session.info.links())))
                for r in range(3):
                    sender = (r + 1) % 3
                    base_key = f"teamslam/{name}/to/{r}/from/{sender}/step"
                    session.put(f"{base_key}/1/ids", b"\x00garbage" * 8)
                    ids_msg = encode(MapIdsMessage(sender, r, 1, ids), team_id(name))
                    session.put(f"{base_key}/1/ids", ids_msg)
                    for t in range(1, dataset.robots[r].frames):
                        session.put(f"{base_key}/{t}/marginal", _forged(name, sender, r, t, ids))
                    published[label] += 2 + dataset.robots[r].frames - 1
                stop.wait(0.05)
        finally:
            subscriber.undeclare()
            session.close()

    attackers = [threading.Thread(target=attack, args=(label,)) for label in strangers]
    for thread in attackers:
        thread.start()
    try:
        outputs = [p.communicate(timeout=240)[0].decode() for p in procs]
    finally:
        stop.set()
        for thread in attackers:
            thread.join(timeout=60)
    for p, out in zip(procs, outputs, strict=True):
        assert p.returncode == 0, out
    assert all(n > 100 for n in published.values()), published
    # the handshake itself refused the first two; the non-member got a link and nothing else
    assert links["no TLS"] == 0 and links["other CA"] == 0
    assert links["non-member"] == 3
    assert overheard == []
    reference = run_team(dataset, config_for(dataset, {"filter.window": 8}), progress=False)
    for r in range(3):
        arrays, summary = load_robot_result(tmp_path / "out", r)
        assert summary["counters"]["rejected_wire"] == 0
        assert summary["counters"].get("rejected_messages", 0) == 0
        assert summary["counters"].get("links_lost", 0) == 0
        np.testing.assert_allclose(arrays["poses"], reference.poses[r], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(arrays["objects"], reference.objects[r], rtol=1e-9, atol=1e-9)


def test_a_robot_names_the_neighbour_it_cannot_authenticate(small_team, tmp_path):
    """Robot 1 holds a certificate of another CA: both say so by name, neither hangs."""
    _, directory = small_team
    name = f"auth-{os.getpid()}"
    team_path, made = _secured_team_file(
        tmp_path, directory, _port(8), name, timeout_s=0.5, settings={"filter.window": 8}
    )
    other = make_team_certificates("other", {1: ("robot-1", "127.0.0.1")}, tmp_path / "o")
    made.robots[1].key.write_bytes(other.robots[1].key.read_bytes())
    made.robots[1].certificate.write_bytes(other.robots[1].certificate.read_bytes())
    began = time.monotonic()
    procs = {
        r: subprocess.Popen(
            agent_command(team_path, r, tmp_path / "out"),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for r in (0, 1)
    }
    outputs = {r: p.communicate(timeout=180)[0] for r, p in procs.items()}
    assert time.monotonic() - began < 120
    for r, p in procs.items():
        assert p.returncode == 0, outputs[r]
    assert "robot 0: no authenticated link to neighbour robot 1 ('robot-1'" in outputs[0]
    assert "robot 1: no authenticated link to neighbour robot 0 ('robot-0'" in outputs[1]
    # robot 0 still reached robot 2? it is not running here: named as well
    assert "neighbour robot 2 ('robot-2'" in outputs[0]
    _, summary = load_robot_result(tmp_path / "out", 0)
    assert summary["lost_neighbours"] == [1, 2]


def test_run_secure_uses_throw_away_certificates(tmp_path, capsys):
    from teamslam.cli import main

    dataset = lissajous_team(robots=3, steps=8, seed=3, landmarks=300)
    save_dataset(dataset, tmp_path / "data")
    out = tmp_path / "run"
    argv = ["run", str(tmp_path / "data"), "--secure", "--window", "6", "--out", str(out)]
    assert main(argv) == 2  # --secure needs --processes
    assert "--secure needs --processes" in capsys.readouterr().err
    argv += ["--processes", "--base-port", str(_port(12))]
    assert main(argv) == 0, capsys.readouterr().err
    team = load_team_file(out / "team.yaml")
    assert team.security is not None and team.robots[0].listen.startswith("tls/")
    assert not (out / "certs").exists()  # the keys did not outlive the run
    metrics = json.loads((out / "metrics.json").read_text())
    assert all(t["counters"]["bytes"] > 0 for t in metrics["transport"])
    assert all(t["counters"].get("links_lost", 0) == 0 for t in metrics["transport"])


def test_a_member_cannot_speak_in_another_members_name(tmp_path):
    """Access control binds ``from/<i>`` to robot i's certificate; the key binds the sender."""
    from teamslam.runtime.zenoh_transport import ZenohTransport

    name = f"name-{os.getpid()}"
    team_path, _ = _secured_team_file(tmp_path, tmp_path, _port(20), name)
    team = load_team_file(team_path)
    members = {r.id: r.name for r in team.robots}
    robot_0 = ZenohTransport(team, 0)
    # robot 1's own credentials, used by a process that is not robot 1's agent
    peer = _stranger_session(
        [team.robots[0].listen], zenoh_security_settings(team.security, 1, name, members)
    )
    tid = team_id(name)
    try:
        honest = encode(MapIdsMessage(1, 0, 1, np.array([3, 4])), tid)
        received = []
        deadline = time.monotonic() + 20
        while not received and time.monotonic() < deadline:
            peer.put(f"teamslam/{name}/to/0/from/1/step/1/ids", honest)
            time.sleep(0.1)
            received = robot_0.collect(1, MapIdsMessage, {1}, 0.0)
        assert received and received[0].sender == 1
        # on robot 2's key: denied by access control, never decoded
        as_2 = encode(MapIdsMessage(2, 0, 2, np.array([5])), tid)
        peer.put(f"teamslam/{name}/to/0/from/2/step/2/ids", as_2)
        # on its own key but claiming robot 2 inside: decoded, then dropped
        peer.put(f"teamslam/{name}/to/0/from/1/step/2/ids", as_2)
        marker = encode(MapIdsMessage(1, 0, 3, np.array([6])), tid)
        peer.put(f"teamslam/{name}/to/0/from/1/step/3/ids", marker)  # in order, after both
        deadline = time.monotonic() + 10
        late: list = []
        while not any(m.step == 3 for m in late) and time.monotonic() < deadline:
            time.sleep(0.05)
            # each sender's newest ids message: a forged robot-2 message would show as sender 2
            late = robot_0.newest(MapIdsMessage, {1, 2}, 10, 3)
        assert [(m.sender, m.step) for m in late] == [(1, 3)]
        assert dict(robot_0.rejected) == {"sender differs from the key's": 1}
    finally:
        peer.close()
        robot_0.close()
