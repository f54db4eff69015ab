"""Command-line pieces of a secured team: ``teamslam team certs`` and ``teamslam run --secure``.

:func:`register` adds them to the ``teamslam`` parser (after the ``team`` and ``run`` commands
exist): ``certs`` under ``team``, and the ``--secure`` flag of ``run``, which with
``--processes`` runs the team with throw-away certificates (mutual TLS and access control on
loopback), removed when the run ends.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path

import yaml

from teamslam.errors import InputError
from teamslam.runtime.security import (
    SecuritySection,
    endpoint_host,
    make_team_certificates,
)

__all__ = ["certify_team_file", "register"]


def _subparsers_of(parser: argparse.ArgumentParser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action
    return None


def register(subparsers) -> None:
    """Add ``team certs`` and ``run --secure`` to the ``teamslam`` parser."""
    team = subparsers.choices.get("team")
    if team is None:
        team = subparsers.add_parser("team", help="run a team of robot processes")
    team_sub = _subparsers_of(team)
    if team_sub is None:
        team_sub = team.add_subparsers(dest="team_command", metavar="ACTION")
        team_sub.required = True
    certs = team_sub.add_parser(
        "certs",
        help="make a team CA and each robot's key and certificate; secure the team file",
        description="Make a certificate authority for the team and, per robot, a private key "
        "(mode 0600) and a certificate whose common name is the robot's name and whose "
        "subjectAltName is the host of its endpoint. The team file gains a 'security' section "
        "and tls/ endpoints (the previous file is kept as FILE.bak). A CA already in --out is "
        "reused.",
    )
    certs.add_argument("team_file", type=Path, help="team file (team.yaml)")
    certs.add_argument("--out", type=Path, required=True, help="directory for keys and certs")
    certs.add_argument("--days", type=int, default=365, help="validity of the certificates")
    certs.add_argument(
        "--no-update",
        action="store_true",
        help="leave the team file alone and print the security section to add",
    )
    certs.set_defaults(handler=_cmd_team_certs)

    run = subparsers.choices.get("run")
    if run is not None:
        run.add_argument(
            "--secure",
            action="store_true",
            help="with --processes: mutual TLS and access control with throw-away certificates",
        )
        plain = run.get_default("handler")
        run.set_defaults(handler=lambda args: _cmd_run(args, plain))
    agent = subparsers.choices.get("agent")
    if agent is not None:
        unchecked = agent.get_default("handler")
        agent.set_defaults(handler=lambda args: _cmd_agent(args, unchecked))


def _cmd_agent(args: argparse.Namespace, unchecked) -> int:
    from teamslam.runtime.security import check_credentials
    from teamslam.runtime.team_file import load_team_file

    team = load_team_file(args.team)
    if team.security is not None and 0 <= args.robot < team.n:
        check_credentials(team.security, args.robot)
    return unchecked(args)


def certify_team_file(
    team_path: Path, out: Path, days: int = 365, update: bool = True
) -> tuple[SecuritySection, dict]:
    """Certificates for every robot of a team file and the file's secured content.

    Returns the security section and the team file's data with ``tls/`` endpoints and that
    section; with ``update`` the file is rewritten (the old one kept as ``FILE.bak``).
    """
    from teamslam.runtime.team_file import (
        TeamFileError,
        load_team_file,
        security_payload,
    )
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


def _cmd_team_certs(args: argparse.Namespace) -> int:
    security, data = certify_team_file(
        Path(args.team_file), Path(args.out), args.days, update=not args.no_update
    )
    print(f"team CA: {security.ca_certificate} (keep {Path(args.out) / 'ca.key'} off the robots)")
    for robot, creds in sorted(security.robots.items()):
        name = data["robots"][robot].get("name", f"robot-{robot}")
        print(f"robot {robot} '{name}': {creds.key} (0600), {creds.certificate}")
    if args.no_update:
        print("\nadd to the team file (and make every endpoint tls/):")
        print(yaml.safe_dump({"security": data["security"]}, sort_keys=False), end="")
    else:
        print(f"updated {args.team_file} (security section, tls/ endpoints; was saved as .bak)")
    return 0


def _cmd_run(args: argparse.Namespace, plain) -> int:
    if not getattr(args, "secure", False):
        return plain(args)
    if not args.processes or args.out is None or args.compare or args.separate:
        raise InputError("--secure needs --processes and --out (it runs consensus only)")
    from teamslam import cli
    from teamslam.datasets import load_dataset
    from teamslam.graph import make
    from teamslam.runtime.team_file import write_team_file

    dataset = load_dataset(args.dataset)
    effective = cli._settings(args, dataset)
    print(cli._settings_line(dataset, effective))
    out = Path(args.out)
    name = f"run-{os.getpid()}"
    keys = out / "certs"
    robots = {i: (f"robot-{i}", "127.0.0.1") for i in range(dataset.n_robots)}
    written = make_team_certificates(name, robots, keys, days=1, reuse_ca=False)
    try:
        team_path = write_team_file(
            out / "team.yaml",
            name,
            args.dataset,
            make(args.graph, dataset.n_robots, seed=args.seed).adjacency,
            base_port=args.base_port,
            security=SecuritySection(written.ca_certificate, written.robots),
            message_loss=args.loss,
            filter=effective.config.to_json(),
        )
        print(f"secured team: mutual TLS, access control; throw-away certificates in {keys}")
        return cli._launch_and_report(team_path, out, effective)
    finally:
        shutil.rmtree(keys, ignore_errors=True)
        sys.stdout.flush()
