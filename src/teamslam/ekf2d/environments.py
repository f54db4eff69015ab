"""Planar simulation environments of the FEJ multi-robot EKF paper (§4.1), and their files.

An environment is, per robot, a closed loop of waypoints (one per step), the true features
(20, 60 or 100; the larger sets extend the smaller), the number of loops, the sensing range and
the noise levels (:func:`environment`): **1**, two wide loops overlapping in a lens,
σ_u = 0.3 m, σ_φ = 2°; **2**, an outer loop with an 8 inside it, σ_u = 0.2 m, σ_φ = 3°; both
σ_obs = 0.5 m / 0.6 m, 5 loops, 15 m range. Each has many layouts (the loops' wobble and the
features' places drawn anew), shaped as the published files are: where the robots start, how
far the features lie from the paths, how evenly they cover them. Files: teamslam's JSON
(:func:`save_environment`, :func:`load_environment`) and the published MATLAB pairs
(:func:`load_matlab_environment`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from teamslam.errors import InputError

__all__ = [
    "PlanarEnvironment",
    "PlanarEnvironmentError",
    "environment",
    "load_environment",
    "load_matlab_environment",
    "save_environment",
]

FORMAT = "teamslam-planar-environment"
VERSION = 1


class PlanarEnvironmentError(InputError):
    """A malformed environment file or definition."""


@dataclass
class PlanarEnvironment:
    """Waypoint loops, true features and noise levels of a planar multi-robot simulation.

    Attributes
    ----------
    name
        A short name.
    waypoints
        Per robot, ``(K_i, 2)`` waypoints of one loop; step ``k`` is at waypoint ``k mod K_i``.
    features
        ``(F, 2)`` true feature positions (ids ``0..F-1``).
    loops
        Number of loops every robot drives.
    sensor_range
        Features closer than this are observed.
    odometry_std
        Per robot ``(σ_u, σ_φ)``: position noise per axis (m) and heading noise (rad) per step.
    observation_std
        Per robot ``σ_obs`` (m) per axis.
    """

    name: str
    waypoints: list[np.ndarray]
    features: np.ndarray
    loops: int = 5
    sensor_range: float = 15.0
    odometry_std: list[tuple[float, float]] = field(default_factory=list)
    observation_std: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.waypoints = [np.asarray(w, dtype=float).reshape(-1, 2) for w in self.waypoints]
        self.features = np.asarray(self.features, dtype=float).reshape(-1, 2)
        if len(self.waypoints) < 2:
            raise PlanarEnvironmentError("an environment needs waypoints for at least 2 robots")
        for i, w in enumerate(self.waypoints):
            if len(w) < 3 or not np.all(np.isfinite(w)):
                raise PlanarEnvironmentError(f"robot {i + 1}: need ≥ 3 finite waypoints")
            if np.any(np.linalg.norm(np.diff(np.vstack([w, w[:1]]), axis=0), axis=1) == 0):
                raise PlanarEnvironmentError(f"robot {i + 1}: consecutive waypoints coincide")
        if not np.all(np.isfinite(self.features)):
            raise PlanarEnvironmentError("features contain NaN or infinite values")
        if self.loops < 1 or self.sensor_range <= 0:
            raise PlanarEnvironmentError("loops and sensor_range must be positive")
        n = len(self.waypoints)
        if not self.odometry_std:
            self.odometry_std = [(0.3, np.deg2rad(2.0))] * n
        if not self.observation_std:
            self.observation_std = [0.5] + [0.6] * (n - 1)
        if len(self.odometry_std) != n or len(self.observation_std) != n:
            raise PlanarEnvironmentError("noise levels must be given for every robot")

    @property
    def n_robots(self) -> int:
        """Number of robots."""
        return len(self.waypoints)

    @property
    def steps(self) -> int:
        """Motion steps: ``loops`` times the longest loop."""
        return self.loops * max(len(w) for w in self.waypoints)

    def odometry_covs(self) -> np.ndarray:
        """``(N, 3, 3)`` odometry noise covariances."""
        return np.array([np.diag([su**2, su**2, sp**2]) for su, sp in self.odometry_std])

    def observation_covs(self) -> np.ndarray:
        """``(N, 2, 2)`` observation noise covariances."""
        return np.array([s**2 * np.eye(2) for s in self.observation_std])


#: Distance between the robots' first waypoints in environment 1 (the published file's)
START_SEPARATION = 18.8
#: Distance between the robots' first waypoints in environment 2 (the published file's)
START_SEPARATION_2 = 4.8
#: Range of the features' distances from the paths, per environment (the published files':
#: none on the path itself; environment 1 from about 0.6 m, environment 2 about 2.5–4.5 m)
FEATURE_BAND = {1: (0.6, 2.5), 2: (2.5, 4.5)}
#: Radial wobble of the loops (m, per waypoint): drawn by hand, not by compass
WOBBLE = 0.3


def _ellipse(
    axes: tuple[float, float],
    count: int,
    start_angle: float,
    direction: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """``count`` waypoints of an ellipse about the origin, from ``start_angle`` in
    ``direction`` (+1 counter-clockwise), each but the first moved radially by
    ``WOBBLE`` · N(0, 1) metres."""
    a, b = axes
    angle = start_angle + direction * 2.0 * np.pi * np.arange(count) / count
    scale = 1.0 + WOBBLE * rng.standard_normal(count) / (0.5 * (a + b))
    scale[0] = 1.0
    return np.column_stack([a * scale * np.cos(angle), b * scale * np.sin(angle)])


def _along(
    paths: list[np.ndarray], count: int, band: tuple[float, float], rng: np.random.Generator
) -> np.ndarray:
    """``count`` features spread evenly along the closed ``paths``' total length (one in each
    of ``count`` equal stretches, at a random place in it), each beside the path at a distance
    drawn uniformly from ``band``, on a random side."""
    a = np.concatenate(paths)
    b = np.concatenate([np.roll(p, -1, axis=0) for p in paths])
    lengths = np.linalg.norm(b - a, axis=1)
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    where = (np.arange(count) + rng.uniform(size=count)) * cumulative[-1] / count
    k = np.clip(np.searchsorted(cumulative, where, side="right") - 1, 0, len(a) - 1)
    tangent = (b[k] - a[k]) / lengths[k, None]
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]])
    offset = rng.choice([-1.0, 1.0], size=count) * rng.uniform(*band, size=count)
    point = a[k] + ((where - cumulative[k]) / lengths[k])[:, None] * (b[k] - a[k])
    return point + offset[:, None] * normal


def _features(
    paths: list[np.ndarray],
    first: np.ndarray,
    band: tuple[float, float],
    rng: np.random.Generator,
    private_start: float | None = None,
) -> np.ndarray:
    """100 features: ``first`` (those both robots see at step 0), then layers of 18, 40 and 40
    spread along the paths (:func:`_along`), so the 20-, 60- and 100-feature sets each cover
    the loops evenly and the larger extend the smaller. With ``private_start`` (a sensing
    range) no feature after ``first`` lies within that range of both robots' first waypoints
    (those are drawn again): at step 0 the robots share exactly ``first``."""
    starts = np.array([p[0] for p in paths])
    layers = [np.asarray(first, dtype=float)]
    for count in (20 - len(first), 40, 40):
        layer = _along(paths, count, band, rng)
        while private_start is not None:
            near = np.linalg.norm(layer[:, None] - starts[None], axis=-1) < private_start
            shared = np.all(near, axis=1)
            if not shared.any():
                break
            layer[shared] = _along(paths, count, band, rng)[shared]
        layers.append(layer)
    return np.vstack(layers)


def environment(number: int, features: int = 20, layout: int = 0) -> PlanarEnvironment:
    """Environment 1 or 2 of the paper with 20, 60 or 100 features (generated, deterministic).

    Parameters
    ----------
    number
        1 or 2: the paper's two kinds of environment.
    features
        20, 60 or 100; the larger sets extend the smaller ones of the same layout.
    layout
        Which layout of that kind: the loops' wobble and the features' places are drawn from
        this seed. Layout 0 is the one the tables use; others are new environments of the same
        kind.
    """
    if features not in (20, 60, 100):
        raise PlanarEnvironmentError(f"feature count must be 20, 60 or 100, got {features}")
    if layout < 0:
        raise PlanarEnvironmentError(f"layout must be non-negative, got {layout}")
    rng = np.random.default_rng(1000 + number if layout == 0 else [1000 + number, layout])
    if number == 1:
        # two wide loops drawn by hand (ellipses of the published file's extent, 27.9 × 18.5 m
        # and 25.8 × 18.7 m) overlapping in a lens; as in the published environment the robots
        # start at the loops' innermost points, START_SEPARATION apart, heading the same way,
        # and share exactly two features at step 0, 3.8 m apart on the line between them:
        # robot 2's heading relative to robot 1 is then poorly known at the start, which is
        # what makes the standard EKF's inconsistency show
        wp1 = _ellipse((27.9, 18.5), 63, np.pi / 2, -1.0, rng)  # top of loop 1, clockwise
        wp2 = _ellipse((25.8, 18.7), 63, -np.pi / 2, +1.0, rng)  # bottom of loop 2
        wp2 = wp2 + np.array([0.0, wp1[0, 1] - START_SEPARATION - wp2[0, 1]])
        along = (wp2[0] - wp1[0]) / np.linalg.norm(wp2[0] - wp1[0])
        middle = 0.5 * (wp1[0] + wp2[0])
        first = np.array([middle - 1.9 * along, middle + 1.9 * along])
        feats = _features([wp1, wp2], first, FEATURE_BAND[1], rng, private_start=15.0)
        return PlanarEnvironment(
            "env1",
            [wp1, wp2],
            feats[:features],
            5,
            15.0,
            [(0.3, np.deg2rad(2.0))] * 2,
            [0.5, 0.6],
        )
    if number == 2:
        # an outer loop (radius 39 m, 40 waypoints) and an 8 inside it (17 m wide, 40
        # waypoints); both robots start at the top, START_SEPARATION_2 apart, heading east
        outer = _ellipse((39.0, 39.0), 40, np.pi / 2, -1.0, rng)
        height = outer[0, 1] - START_SEPARATION_2
        t = 2.0 * np.pi * np.arange(40) / 40
        eight = np.column_stack([17.0 * np.sin(2.0 * t), height * np.cos(t)])
        eight[1:] *= 1.0 + WOBBLE * rng.standard_normal((39, 1)) / height
        start = 0.5 * (outer[0] + eight[0])
        first = start + rng.uniform(-4, 4, (2, 2))  # at least two shared at step 0
        feats = _features([outer, eight], first, FEATURE_BAND[2], rng)
        return PlanarEnvironment(
            "env2",
            [outer, eight],
            feats[:features],
            5,
            15.0,
            [(0.2, np.deg2rad(3.0))] * 2,
            [0.5, 0.6],
        )
    raise PlanarEnvironmentError(f"unknown environment {number}; choose 1 or 2")


def save_environment(env: PlanarEnvironment, path: str | Path) -> None:
    """Write an environment as JSON."""
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "name": env.name,
        "waypoints": [w.tolist() for w in env.waypoints],
        "features": env.features.tolist(),
        "loops": env.loops,
        "sensor_range": env.sensor_range,
        "odometry_std": [list(s) for s in env.odometry_std],
        "observation_std": list(env.observation_std),
    }
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(payload, indent=1) + "\n")
    tmp.replace(path)


def load_environment(path: str | Path) -> PlanarEnvironment:
    """Read an environment written by :func:`save_environment` (validated)."""
    path = Path(path)
    try:
        payload = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PlanarEnvironmentError(f"{path}: cannot read environment ({exc})") from None
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise PlanarEnvironmentError(f"{path}: not a {FORMAT} file")
    if payload.get("version") != VERSION:
        raise PlanarEnvironmentError(f"{path}: unsupported version {payload.get('version')!r}")
    try:
        return PlanarEnvironment(
            str(payload.get("name", path.stem)),
            [np.asarray(w, dtype=float) for w in payload["waypoints"]],
            np.asarray(payload["features"], dtype=float),
            int(payload.get("loops", 5)),
            float(payload.get("sensor_range", 15.0)),
            [tuple(s) for s in payload.get("odometry_std", [])],
            list(payload.get("observation_std", [])),
        )
    except KeyError as exc:
        raise PlanarEnvironmentError(f"{path}: field {exc} is missing") from None
    except (TypeError, ValueError) as exc:
        raise PlanarEnvironmentError(f"{path}: {exc}") from None


def load_matlab_environment(
    paths: list[str | Path],
    loops: int = 5,
    sensor_range: float = 15.0,
    name: str | None = None,
    odometry_std: list[tuple[float, float]] | None = None,
    observation_std: list[float] | None = None,
) -> PlanarEnvironment:
    """Read the published MATLAB environment files, merging the variables of all of them.

    Needs ``wp1``, ``wp2`` (2×K waypoints; further ``wp3``… are further robots) and ``lm``
    (2×F features) among the files' variables. Noise levels default to environment 1's.
    """
    import scipy.io

    merged: dict[str, np.ndarray] = {}
    for p in paths:
        p = Path(p)
        try:
            data = scipy.io.loadmat(p)
        except (OSError, ValueError, NotImplementedError, TypeError) as exc:
            raise PlanarEnvironmentError(f"{p}: cannot read MATLAB file ({exc})") from None
        merged.update({k: v for k, v in data.items() if not k.startswith("__")})
    if "lm" not in merged:
        raise PlanarEnvironmentError("no file holds the features 'lm' (2×F)")
    robots = []
    k = 1
    while f"wp{k}" in merged:
        robots.append(merged[f"wp{k}"])
        k += 1
    if len(robots) < 2:
        raise PlanarEnvironmentError("need waypoints 'wp1' and 'wp2' (2×K each)")

    def as_points(arr: np.ndarray, what: str) -> np.ndarray:
        arr = np.asarray(arr, dtype=float)
        if arr.ndim != 2 or arr.shape[0] != 2:
            raise PlanarEnvironmentError(f"'{what}' must be 2×K, got {arr.shape}")
        return arr.T

    return PlanarEnvironment(
        name or "matlab-environment",
        [as_points(w, f"wp{i + 1}") for i, w in enumerate(robots)],
        as_points(merged["lm"], "lm"),
        loops,
        sensor_range,
        odometry_std or [],
        observation_std or [],
    )
