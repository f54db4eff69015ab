"""The team file (``team.yaml``): who the robots are, what they run on, whom they talk to.

Example::

    team: lissajous-demo             # name; also separates teams on a shared network
    dataset: results/team3           # a teamslam team dataset (each robot uses its slice)
    sync: lockstep                   # or: async
    timeout_s: 5.0                   # lock-step: how long to wait for a neighbour's messages
    max_age_steps: 3                 # async: oldest neighbour marginal still used
    checkpoint_every: 25             # frames between checkpoints (0: never)
    message_loss: 0.0                # injected loss rate of sent messages (experiments)
    message_delay_ms: 0.0            # injected delay before each send
    shared_memory: true              # Zenoh may hand large messages to robots on the same
                                     # machine through shared memory instead of the network
    settings:                        # any filter setting, by group (teamslam config show
      filter: {window: 10, object_std: 2.0}   # lists them), or dotted: consensus.rule: hybrid
    ros2: {domain_id: 0}             # optional: every robot publishes ROS 2 topics over
                                     # rmw_zenoh (teamslam.ros2.rmw_zenoh.ros2_settings)
    robots:
      - id: 0
        listen: tcp/127.0.0.1:17400  # default: tcp/127.0.0.1:<17400 + id>
        name: robot-0                # default: robot-<id>; the common name of its certificate
        neighbours: [1, 2]
      - id: 1
        neighbours: [0, 2]
      - id: 2
        neighbours: [0, 1]
        dataset: other/team          # optional: another dataset …
        dataset_robot: 0             # … and which of its robots

A secured team (mutual TLS and access control, :mod:`teamslam.runtime.security`) adds::

    security:
      ca_certificate: certs/ca.pem   # the team CA: the only authority a robot trusts
      verify_name: true              # on connect, the neighbour's certificate must name its host
      robots:                        # each robot's key and certificate (a robot's machine
        - {id: 0, key: certs/robot-0.key, certificate: certs/robot-0.pem}   # needs only its own)
        - ...

and every endpoint is then a ``tls/HOST:PORT`` endpoint (``teamslam team certs`` writes both).

Each agent listens on its own endpoint and connects to its neighbours' (Zenoh peer mode, no
router, multicast scouting off so it runs on closed networks). The consensus weights are not
fixed by the file: at each step they are the Metropolis–Hastings weights of the links that
worked, ``A_ij = 1 / (1 + max(d_i, d_j))`` with ``d_i`` the neighbours robot ``i`` heard that
step (its degree travels in its marginals), as in the in-process run
(:class:`~teamslam.msckf.consensus.protocol.ConsensusProtocol`,
:func:`teamslam.graph.metropolis_weight`).
Loading validates everything and names the first problem; the ``filter`` settings are checked
for every robot again before a launch (:func:`teamslam.api.launch`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from teamslam.errors import InputError
from teamslam.msckf.settings.sources import ConfigError, coerce_settings
from teamslam.runtime.security import RobotCredentials, SecuritySection
from teamslam.textio import read_yaml

__all__ = [
    "RobotEntry",
    "TeamFile",
    "TeamFileError",
    "load_team_file",
    "security_payload",
    "write_team_file",
]


class TeamFileError(InputError):
    """A malformed team file; the message names the field."""


@dataclass
class RobotEntry:
    """One robot of the team file."""

    id: int
    listen: str
    neighbours: list[int]
    dataset: Path | None = None
    dataset_robot: int | None = None
    name: str = ""

    def __post_init__(self) -> None:
        if not self.name:
            self.name = f"robot-{self.id}"


@dataclass
class TeamFile:
    """A validated team file."""

    team: str
    dataset: Path | None
    robots: list[RobotEntry]
    sync: str = "lockstep"
    timeout_s: float = 5.0
    max_age_steps: int = 3
    checkpoint_every: int = 25
    message_loss: float = 0.0
    message_delay_ms: float = 0.0
    shared_memory: bool = True
    settings: dict = field(default_factory=dict)
    path: Path | None = None
    ros2: dict | None = None
    security: SecuritySection | None = None

    @property
    def n(self) -> int:
        """Number of robots."""
        return len(self.robots)

    def adjacency(self) -> np.ndarray:
        """Neighbour graph."""
        a = np.zeros((self.n, self.n), dtype=bool)
        for r in self.robots:
            a[r.id, r.neighbours] = True
        return a

    def dataset_of(self, robot: int) -> tuple[Path, int]:
        """Dataset directory and robot index within it for ``robot``."""
        entry = self.robots[robot]
        path = entry.dataset or self.dataset
        if path is None:
            raise TeamFileError(
                f"robot {robot} has no dataset (set 'dataset' at the top or per robot)"
            )
        return path, entry.dataset_robot if entry.dataset_robot is not None else robot


def _number(data: dict, key: str, default, kind, low=None, high=None):
    value = data.get(key, default)
    try:
        value = kind(value)
    except (TypeError, ValueError):
        raise TeamFileError(f"'{key}' must be a {kind.__name__}, got {value!r}") from None
    if (low is not None and value < low) or (high is not None and value > high):
        raise TeamFileError(f"'{key}' = {value} outside [{low}, {high}]")
    return value


def _mapping(data: dict, key: str) -> dict | None:
    value = data.get(key)
    if value is not None and not isinstance(value, dict):
        raise TeamFileError(f"'{key}' must be a mapping")
    return value


def load_team_file(path: str | Path) -> TeamFile:
    """Read and validate a team file; relative paths are relative to the file."""
    path = Path(path)
    data = read_yaml(path, TeamFileError)
    try:
        return _parse(data, path)
    except TeamFileError as exc:
        raise TeamFileError(f"{path}: {exc}") from None


def _parse(data, path: Path) -> TeamFile:
    if not isinstance(data, dict):
        raise TeamFileError("the team file must be a mapping")
    unknown = set(data) - {
        "team",
        "dataset",
        "sync",
        "timeout_s",
        "max_age_steps",
        "checkpoint_every",
        "message_loss",
        "message_delay_ms",
        "settings",
        "robots",
        "ros2",
        "security",
        "shared_memory",
    }
    if "filter" in unknown:
        raise TeamFileError(
            "'filter' is now 'settings', by group (settings: {filter: {window: 10}})"
        )
    if unknown:
        raise TeamFileError(f"unknown field(s): {', '.join(sorted(unknown))}")
    team = data.get("team")
    if not isinstance(team, str) or not team or "/" in team or "*" in team:
        raise TeamFileError("'team' must be a non-empty name without '/' or '*'")
    base = path.parent

    def as_path(value, where):
        if value is None:
            return None
        if not isinstance(value, str):
            raise TeamFileError(f"'{where}' must be a path")
        p = Path(value)
        return p if p.is_absolute() else base / p

    robots_raw = data.get("robots")
    if not isinstance(robots_raw, list) or len(robots_raw) < 1:
        raise TeamFileError("'robots' must be a non-empty list")
    robots = []
    for k, r in enumerate(robots_raw):
        if not isinstance(r, dict):
            raise TeamFileError(f"robots[{k}] must be a mapping")
        if r.get("id") != k:
            raise TeamFileError(f"robots[{k}].id must be {k} (robots are numbered 0..N-1 in order)")
        neighbours = r.get("neighbours", [])
        if not isinstance(neighbours, list) or not all(isinstance(j, int) for j in neighbours):
            raise TeamFileError(f"robots[{k}].neighbours must be a list of robot ids")
        listen = r.get("listen", f"tcp/127.0.0.1:{17400 + k}")
        if not isinstance(listen, str) or "/" not in listen:
            raise TeamFileError(f"robots[{k}].listen must be a Zenoh endpoint like tcp/HOST:PORT")
        name = r.get("name", f"robot-{k}")
        if not isinstance(name, str) or not name or any(c in name for c in "/\\*\0"):
            raise TeamFileError(f"robots[{k}].name must be a non-empty name without '/' or '*'")
        robots.append(
            RobotEntry(
                k,
                listen,
                sorted(set(neighbours)),
                as_path(r.get("dataset"), f"robots[{k}].dataset"),
                r.get("dataset_robot"),
                name,
            )
        )
    names = [r.name for r in robots]
    if len(set(names)) != len(names):
        raise TeamFileError("robot names must be distinct")
    n = len(robots)
    for r in robots:
        for j in r.neighbours:
            if not 0 <= j < n or j == r.id:
                raise TeamFileError(f"robots[{r.id}].neighbours names {j}, not another robot")
            if r.id not in robots[j].neighbours:
                raise TeamFileError(
                    f"link {r.id}–{j} is listed by robot {r.id} but not by robot {j}"
                )
    security = _security(data.get("security"), robots, as_path)
    if not isinstance(data.get("shared_memory", True), bool):
        raise TeamFileError("'shared_memory' must be true or false")
    sync = data.get("sync", "lockstep")
    if sync not in ("lockstep", "async"):
        raise TeamFileError("'sync' must be lockstep or async")
    settings = data.get("settings", {}) or {}
    if not isinstance(settings, dict):
        raise TeamFileError("'settings' must map groups of filter settings to values")
    try:
        settings = coerce_settings(settings, "settings")
    except ConfigError as exc:
        raise TeamFileError(str(exc)) from None
    return TeamFile(
        team=team,
        dataset=as_path(data.get("dataset"), "dataset"),
        robots=robots,
        sync=sync,
        timeout_s=_number(data, "timeout_s", 5.0, float, 0.0),
        max_age_steps=_number(data, "max_age_steps", 3, int, 0),
        checkpoint_every=_number(data, "checkpoint_every", 25, int, 0),
        message_loss=_number(data, "message_loss", 0.0, float, 0.0, 1.0),
        message_delay_ms=_number(data, "message_delay_ms", 0.0, float, 0.0),
        shared_memory=data.get("shared_memory", True),
        settings=settings,
        path=path,
        ros2=_mapping(data, "ros2"),
        security=security,
    )


def _security(raw, robots: list[RobotEntry], as_path) -> SecuritySection | None:
    """The ``security`` section, or None; endpoints must be ``tls/`` exactly when it is given."""
    plain = [r.id for r in robots if not r.listen.startswith("tls/")]
    if raw is None:
        tls = [r.id for r in robots if r.listen.startswith("tls/")]
        if tls:
            raise TeamFileError(
                f"robots {tls} listen on tls/ endpoints but the file has no 'security' section"
            )
        return None
    if not isinstance(raw, dict):
        raise TeamFileError("'security' must be a mapping")
    unknown = set(raw) - {"ca_certificate", "verify_name", "robots"}
    if unknown:
        raise TeamFileError(f"security: unknown field(s): {', '.join(sorted(unknown))}")
    if plain:
        raise TeamFileError(
            f"security: robots {plain} must listen on tls/HOST:PORT endpoints, not "
            + ", ".join(robots[i].listen for i in plain)
        )
    if not isinstance(raw.get("ca_certificate"), str):
        raise TeamFileError("security.ca_certificate must be the path of the team CA certificate")
    verify = raw.get("verify_name", True)
    if not isinstance(verify, bool):
        raise TeamFileError("security.verify_name must be true or false")
    entries = raw.get("robots")
    if not isinstance(entries, list):
        raise TeamFileError("security.robots must list each robot's id, key and certificate")
    creds: dict[int, RobotCredentials] = {}
    for k, e in enumerate(entries):
        if not isinstance(e, dict) or set(e) != {"id", "key", "certificate"}:
            raise TeamFileError(f"security.robots[{k}] must have exactly id, key and certificate")
        rid = e["id"]
        if not isinstance(rid, int) or not 0 <= rid < len(robots) or rid in creds:
            raise TeamFileError(f"security.robots[{k}].id {rid!r} is not a robot, or repeated")
        creds[rid] = RobotCredentials(
            as_path(e["key"], f"security.robots[{k}].key"),
            as_path(e["certificate"], f"security.robots[{k}].certificate"),
        )
    missing = sorted(set(range(len(robots))) - set(creds))
    if missing:
        raise TeamFileError(f"security.robots has no key and certificate for robots {missing}")
    return SecuritySection(as_path(raw["ca_certificate"], "security.ca_certificate"), creds, verify)


def security_payload(security: SecuritySection, base: Path) -> dict:
    """The ``security`` section as written to a team file in directory ``base``."""

    def rel(p: Path) -> str:
        p = Path(p).resolve()
        try:
            return str(p.relative_to(base.resolve()))
        except ValueError:
            return str(p)

    return {
        "ca_certificate": rel(security.ca_certificate),
        "verify_name": security.verify_name,
        "robots": [
            {"id": i, "key": rel(c.key), "certificate": rel(c.certificate)}
            for i, c in sorted(security.robots.items())
        ],
    }


def write_team_file(
    path: str | Path,
    team: str,
    dataset: str | Path,
    adjacency: np.ndarray,
    base_port: int = 17400,
    security: SecuritySection | None = None,
    host: str | list[str] = "127.0.0.1",
    **settings,
) -> Path:
    """Write a team file for a dataset and a neighbour graph.

    Robot ``i`` listens on ``host`` (or ``host[i]`` when a list) at port ``base_port + i``.
    With ``security`` the endpoints are ``tls/`` and the file gets its ``security`` section.
    """
    path = Path(path)
    adjacency = np.asarray(adjacency, dtype=bool)
    protocol = "tls" if security is not None else "tcp"
    hosts = [host] * adjacency.shape[0] if isinstance(host, str) else list(host)
    if len(hosts) != adjacency.shape[0]:
        raise TeamFileError(f"{len(hosts)} hosts for {adjacency.shape[0]} robots")
    payload = {
        "team": team,
        "dataset": str(Path(dataset).resolve()),
        **settings,
        "robots": [
            {
                "id": i,
                "listen": f"{protocol}/{hosts[i]}:{base_port + i}",
                "neighbours": [int(j) for j in np.flatnonzero(adjacency[i])],
            }
            for i in range(adjacency.shape[0])
        ],
    }
    if security is not None:
        payload["security"] = security_payload(security, path.parent)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(payload, sort_keys=False))
    return path
