"""The team file (``team.yaml``): who the robots are, what they run on, whom they talk to.

:func:`load_team_file` reads the team's name, dataset, synchronisation (``lockstep`` or ``async``
with its timeout or maximum age), checkpoints, injected loss and delay, the ``settings`` and
optional ``ros2`` and ``security`` sections, and per robot its id, endpoint, name, neighbours
and optional dataset. Loading validates everything and names the first problem; the
``settings`` are checked for every robot again before a launch. Consensus weights are
not fixed by the file: they are the Metropolis–Hastings weights of the links that worked
(:func:`teamslam.graph.metropolis_weight`). Field by field: the docs' reference page
*Team file*.
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
    max_age_s: float | None = None
    max_age_quantile: float | None = 0.95
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


def _endpoint_key(endpoint: str) -> str:
    """What an endpoint binds: ``HOST:PORT`` whatever the protocol (``tcp/`` and ``tls/`` on
    one port collide), ``localhost`` as ``127.0.0.1``."""
    address = endpoint.split("/", 1)[1].strip().lower()
    host, _, port = address.rpartition(":")
    return f"{'127.0.0.1' if host == 'localhost' else host}:{port}"


def _check_id(robots_raw: list, k: int) -> None:
    """``robots[k].id`` must be ``k``; else say what it holds and why that is wrong."""
    rid = robots_raw[k].get("id")
    if rid == k and not isinstance(rid, bool):
        return
    if rid is None:
        raise TeamFileError(f"robots[{k}].id is missing (robots are numbered 0..N-1 in order)")
    earlier = [
        j for j in range(k) if isinstance(robots_raw[j], dict) and robots_raw[j].get("id") == rid
    ]
    if earlier:
        raise TeamFileError(
            f"robots[{k}].id is {rid!r}, the id of robots[{earlier[0]}] too; ids must be distinct, "
            f"0..N-1 in order (this one {k})"
        )
    raise TeamFileError(
        f"robots[{k}].id is {rid!r}; robots are numbered 0..N-1 in order, so this one is {k}"
    )


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
        "max_age_s",
        "max_age_quantile",
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
        _check_id(robots_raw, k)
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
    for field_name, key in (("name", str), ("listen", _endpoint_key)):
        first: dict[str, int] = {}
        for r in robots:
            value = getattr(r, field_name)
            if key(value) in first:
                raise TeamFileError(
                    f"robots[{r.id}].{field_name} {value} is robots[{first[key(value)]}]'s too; "
                    f"each robot needs its own {'endpoint' if field_name == 'listen' else 'name'}"
                )
            first[key(value)] = r.id
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
        max_age_s=_max_age_s(data),
        max_age_quantile=_max_age_quantile(data),
        checkpoint_every=_number(data, "checkpoint_every", 25, int, 0),
        message_loss=_number(data, "message_loss", 0.0, float, 0.0, 1.0),
        message_delay_ms=_number(data, "message_delay_ms", 0.0, float, 0.0),
        shared_memory=data.get("shared_memory", True),
        settings=settings,
        path=path,
        ros2=_mapping(data, "ros2"),
        security=security,
    )


def _max_age_s(data: dict) -> float | None:
    """``max_age_s``: seconds of frame stamps (live asynchronous robots), or ``None``."""
    if data.get("max_age_s") is None:
        return None
    value = _number(data, "max_age_s", None, float, 0.0)
    if not np.isfinite(value):
        raise TeamFileError(f"'max_age_s' must be finite seconds, got {value}")
    return value


def _max_age_quantile(data: dict) -> float | None:
    """``max_age_quantile``: the share of a neighbour's message lags its age limit covers
    (live asynchronous robots; :class:`~teamslam.msckf.consensus.messages.MessageLags`), or
    ``None`` (null: ``max_age_steps`` of the robot's own steps alone)."""
    if "max_age_quantile" in data and data["max_age_quantile"] is None:
        return None
    value = _number(data, "max_age_quantile", 0.95, float)
    if not 0.0 < value < 1.0:
        raise TeamFileError(f"'max_age_quantile' must be a probability in (0, 1), got {value}")
    return value


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
