"""Only the team's robots get in: certificates, mutual TLS and access control for Zenoh.

A secured team has its own certificate authority; each robot holds a key and a certificate
naming the robot (CN) and its endpoint's host (subjectAltName). Links are Zenoh ``tls/`` links
with mutual authentication, and access control (``default_permission: deny``) allows robot
``i``'s link only puts on ``teamslam/<team>/to/*/from/<i>/**`` from it and on
``teamslam/<team>/to/<i>/**`` to it, plus the team's declarations: a member can never speak in
another's name. Zenoh refuses other peers silently, so :func:`authenticated_peers` reads the
authenticated names of the live links and the transport names every neighbour without one.
"""

from __future__ import annotations

import datetime as _dt
import ipaddress
import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import yaml

from teamslam._optional import require
from teamslam.errors import InputError

__all__ = [
    "ACL_MESSAGES",
    "RobotCredentials",
    "SecuritySection",
    "TeamCertificates",
    "access_control_config",
    "authenticated_peers",
    "certify_team_file",
    "check_credentials",
    "endpoint_host",
    "make_team_certificates",
    "zenoh_security_settings",
]

#: every message kind Zenoh's access control filters (zenoh 1.x spelling)
ACL_MESSAGES = (
    "put",
    "delete",
    "declare_subscriber",
    "query",
    "declare_queryable",
    "reply",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
)
_DECLARATIONS = [m for m in ACL_MESSAGES if m not in ("put", "delete")]


@dataclass(frozen=True)
class RobotCredentials:
    """One robot's private key and certificate (PEM files)."""

    key: Path
    certificate: Path


@dataclass(frozen=True)
class SecuritySection:
    """The ``security`` section of a team file.

    Attributes
    ----------
    ca_certificate
        The team CA's certificate (PEM): the only authority a robot trusts.
    robots
        Per robot id, its key and certificate. A robot needs only its own key on its machine.
    verify_name
        Check, when connecting, that the neighbour's certificate names the host dialled.
    """

    ca_certificate: Path
    robots: dict[int, RobotCredentials]
    verify_name: bool = True


@dataclass(frozen=True)
class TeamCertificates:
    """What :func:`make_team_certificates` wrote."""

    ca_certificate: Path
    ca_key: Path
    robots: dict[int, RobotCredentials]


def endpoint_host(endpoint: str) -> str:
    """The host of a Zenoh endpoint ``proto/HOST:PORT`` (IPv6 hosts in brackets)."""
    try:
        _, address = endpoint.split("/", 1)
    except ValueError:
        raise InputError(f"endpoint {endpoint!r} is not proto/HOST:PORT") from None
    address = address.split("#", 1)[0].split("?", 1)[0]
    if address.startswith("["):
        host, sep, _ = address[1:].partition("]")
        if not sep:
            raise InputError(f"endpoint {endpoint!r}: unclosed '[' in an IPv6 address")
        return host
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise InputError(f"endpoint {endpoint!r} is not proto/HOST:PORT")
    return host


# ------------------------------------------------------------------ certificates
def _crypto(name: str):
    """The module ``cryptography.<name>`` (the ``network`` extra)."""
    return require(f"cryptography.{name}", "network", "a secured team (its certificates)")


def _write_private(path: Path, data: bytes) -> None:
    """Write ``data`` readable by its owner only (mode 0600), also when ``path`` existed."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.fchmod(fd, 0o600)
        os.write(fd, data)
    finally:
        os.close(fd)


def _san(host: str):
    x509 = _crypto("x509")

    try:
        return x509.IPAddress(ipaddress.ip_address(host))
    except ValueError:
        return x509.DNSName(host)


def _new_key():
    ec = _crypto("hazmat.primitives.asymmetric.ec")

    return ec.generate_private_key(ec.SECP256R1())


def _key_pem(key) -> bytes:
    serialization = _crypto("hazmat.primitives.serialization")

    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def _cert_pem(cert) -> bytes:
    serialization = _crypto("hazmat.primitives.serialization")

    return cert.public_bytes(serialization.Encoding.PEM)


def _load_ca(cert_path: Path, key_path: Path):
    x509 = _crypto("x509")
    serialization = _crypto("hazmat.primitives.serialization")

    try:
        cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    except (OSError, ValueError, TypeError) as exc:
        raise InputError(f"cannot reuse the team CA in {cert_path.parent}: {exc}") from None
    return cert, key


def _issue_ca(team: str, days: int):
    x509 = _crypto("x509")
    hashes = _crypto("hazmat.primitives.hashes")
    NameOID = _crypto("x509.oid").NameOID

    key = _new_key()
    name = x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, f"teamslam team {team}"),
            x509.NameAttribute(NameOID.COMMON_NAME, f"{team} team CA"),
        ]
    )
    now = _dt.datetime.now(_dt.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - _dt.timedelta(minutes=5))
        .not_valid_after(now + _dt.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=False,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    return cert, key


def _issue_robot(ca_cert, ca_key, name: str, host: str, days: int):
    x509 = _crypto("x509")
    hashes = _crypto("hazmat.primitives.hashes")
    oid = _crypto("x509.oid")
    ExtendedKeyUsageOID, NameOID = oid.ExtendedKeyUsageOID, oid.NameOID

    key = _new_key()
    now = _dt.datetime.now(_dt.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - _dt.timedelta(minutes=5))
        .not_valid_after(now + _dt.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=False,
                crl_sign=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(
            x509.ExtendedKeyUsage(
                [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
            ),
            critical=False,
        )
        .add_extension(x509.SubjectAlternativeName([_san(host)]), critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False
        )
        .sign(ca_key, hashes.SHA256())
    )
    return cert, key


def make_team_certificates(
    team: str,
    robots: dict[int, tuple[str, str]],
    out: str | Path,
    days: int = 365,
    reuse_ca: bool = True,
) -> TeamCertificates:
    """Write a team CA and one key + certificate per robot into ``out``.

    Parameters
    ----------
    team
        The team's name (in the CA's subject).
    robots
        ``{robot id: (name, host)}``: the certificate's common name and the host of the robot's
        endpoint (an IP address or a DNS name), which becomes its subjectAltName.
    out
        Directory to write: ``ca.pem``, ``ca.key``, ``<name>.pem`` and ``<name>.key``. Private
        keys get mode 0600.
    days
        Validity of every certificate.
    reuse_ca
        When ``out`` already holds ``ca.pem`` and ``ca.key``, sign with that CA instead of
        making a new one (adding a robot does not re-key the team).
    """
    if days < 1:
        raise InputError(f"certificate validity must be at least one day, got {days}")
    _crypto("x509")  # the extra is there before anything is written
    names = [name for name, _ in robots.values()]
    if len(set(names)) != len(names):
        raise InputError("robot names must be distinct: each is a certificate's common name")
    for name in names:
        if not name or any(c in name for c in "/\\*\0") or name.startswith("."):
            raise InputError(f"robot name {name!r} cannot name a certificate file")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ca_cert_path, ca_key_path = out / "ca.pem", out / "ca.key"
    if reuse_ca and ca_cert_path.exists() and ca_key_path.exists():
        ca_cert, ca_key = _load_ca(ca_cert_path, ca_key_path)
    else:
        ca_cert, ca_key = _issue_ca(team, days)
        _write_private(ca_key_path, _key_pem(ca_key))
        ca_cert_path.write_bytes(_cert_pem(ca_cert))
    written = {}
    for robot, (name, host) in sorted(robots.items()):
        cert, key = _issue_robot(ca_cert, ca_key, name, host, days)
        key_path, cert_path = out / f"{name}.key", out / f"{name}.pem"
        _write_private(key_path, _key_pem(key))
        cert_path.write_bytes(_cert_pem(cert))
        written[robot] = RobotCredentials(key_path, cert_path)
    return TeamCertificates(ca_cert_path, ca_key_path, written)


def check_credentials(security: SecuritySection, robot: int) -> RobotCredentials:
    """The robot's own credentials, checked readable and well-formed; one-line error if not."""
    x509 = _crypto("x509")
    serialization = _crypto("hazmat.primitives.serialization")

    creds = security.robots.get(robot)
    if creds is None:
        raise InputError(f"security: no key and certificate for robot {robot}")
    checks = (
        ("team CA certificate", security.ca_certificate, x509.load_pem_x509_certificate),
        ("certificate", creds.certificate, x509.load_pem_x509_certificate),
        ("private key", creds.key, lambda b: serialization.load_pem_private_key(b, None)),
    )
    for what, path, parse in checks:
        try:
            data = Path(path).read_bytes()
        except OSError as exc:
            raise InputError(
                f"robot {robot}: cannot read its {what} {path} ({exc.strerror or exc})"
            ) from None
        try:
            parse(data)
        except (ValueError, TypeError) as exc:
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise InputError(f"robot {robot}: {path} is not a PEM {what} ({first})") from None
    return creds


# ------------------------------------------------------------------ Zenoh configuration
def access_control_config(team: str, members: dict[int, str]) -> dict:
    """Zenoh ``access_control``: deny by default; each member only on the team's keys.

    Parameters
    ----------
    team
        The team's name (its key prefix ``teamslam/<team>``).
    members
        ``{robot id: certificate common name}``.
    """
    prefix = f"teamslam/{team}"
    rules = [
        {
            "id": "team-declarations",
            "messages": _DECLARATIONS,
            "flows": ["ingress", "egress"],
            "permission": "allow",
            "key_exprs": [f"{prefix}/**"],
        }
    ]
    subjects = []
    policies = []
    for robot, name in sorted(members.items()):
        rules.append(
            {
                "id": f"from-{robot}",
                "messages": ["put"],
                "flows": ["ingress"],
                "permission": "allow",
                "key_exprs": [f"{prefix}/to/*/from/{robot}/**"],
            }
        )
        rules.append(
            {
                "id": f"to-{robot}",
                "messages": ["put"],
                "flows": ["egress"],
                "permission": "allow",
                "key_exprs": [f"{prefix}/to/{robot}/**"],
            }
        )
        subjects.append({"id": f"robot-{robot}", "cert_common_names": [name]})
        policies.append(
            {
                "id": f"member-{robot}",
                "rules": ["team-declarations", f"from-{robot}", f"to-{robot}"],
                "subjects": [f"robot-{robot}"],
            }
        )
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def zenoh_security_settings(
    security: SecuritySection, robot: int, team: str, members: dict[int, str]
) -> dict[str, object]:
    """``{config path: value}`` to insert into a Zenoh config for robot ``robot``.

    Mutual TLS on ``transport/link/tls`` (the robot's key and certificate for both listening
    and connecting, the team CA as the only root), only ``tls`` links, and
    :func:`access_control_config`.
    """
    creds = check_credentials(security, robot)
    key, cert = str(Path(creds.key).resolve()), str(Path(creds.certificate).resolve())
    return {
        "transport/link/protocols": ["tls"],
        "transport/link/tls": {
            "root_ca_certificate": str(Path(security.ca_certificate).resolve()),
            "listen_private_key": key,
            "listen_certificate": cert,
            "enable_mtls": True,
            "connect_private_key": key,
            "connect_certificate": cert,
            "verify_name_on_connect": security.verify_name,
            "close_link_on_expiration": True,
        },
        "access_control": access_control_config(team, members),
    }


def apply_settings(config, settings: dict[str, object]) -> None:
    """Insert ``settings`` (from :func:`zenoh_security_settings`) into a ``zenoh.Config``."""
    for path, value in settings.items():
        config.insert_json5(path, json.dumps(value))


def authenticated_peers(session) -> dict[str, str]:
    """``{zenoh id: certificate common name}`` of the session's live authenticated links."""
    out = {}
    for link in session.info.links():
        name = link.auth_identifier
        if name:
            out[str(link.zid)] = str(name)
    return out


__all__ += ["apply_settings"]


def certify_team_file(
    team_path: Path, out: Path, days: int = 365, update: bool = True
) -> tuple[SecuritySection, dict]:
    """Certificates for every robot of a team file and the file's secured content.

    Returns the security section and the team file's data with ``tls/`` endpoints and that
    section; with ``update`` the file is rewritten (the old one kept as ``FILE.bak``).
    """
    from teamslam.runtime.team_file import TeamFileError, load_team_file, security_payload
    from teamslam.textio import read_yaml

    team = load_team_file(team_path)
    robots = {r.id: (r.name, endpoint_host(r.listen)) for r in team.robots}
    written = make_team_certificates(team.team, robots, out, days=days)
    security = SecuritySection(written.ca_certificate, written.robots)
    data = read_yaml(team_path, TeamFileError)
    for entry, robot in zip(data["robots"], team.robots, strict=True):
        _, rest = robot.listen.split("/", 1)
        entry["listen"] = f"tls/{rest}"
    data["security"] = security_payload(security, Path(team_path).parent)
    if update:
        backup = team_path.with_name(team_path.name + ".bak")
        shutil.copyfile(team_path, backup)
        tmp = team_path.with_name(team_path.name + ".tmp")
        tmp.write_text(yaml.safe_dump(data, sort_keys=False))
        os.replace(tmp, team_path)
        load_team_file(team_path)  # the result must load
    return security, data
