"""Planar simulation environments of the FEJ multi-robot EKF paper (§4.1), and their files.

An environment is, per robot, a closed loop of waypoints (one per step), the true features
(20, 60 or 100; the larger sets extend the smaller), the number of loops, the sensing range and
the noise levels (:func:`environment`): **1**, two intersecting near-circular loops,
σ_u = 0.3 m, σ_φ = 2°; **2**, an outer loop with an 8 inside it, σ_u = 0.2 m, σ_φ = 3°; both
σ_obs = 0.5 m / 0.6 m, 5 loops, 15 m range. Files: teamslam's JSON (:func:`save_environment`,
:func:`load_environment`) and the published MATLAB pairs (:func:`load_matlab_environment`).
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


def _loop(centre, radius, count, start_angle, direction=1.0, wobble=0.0, rng=None) -> np.ndarray:
    angle = start_angle + direction * 2.0 * np.pi * np.arange(count) / count
    r = radius + (wobble * rng.standard_normal(count) if rng is not None and wobble else 0.0)
    return np.column_stack([centre[0] + r * np.cos(angle), centre[1] + r * np.sin(angle)])


def _features_along(
    paths: list[np.ndarray],
    count: int,
    spread: float,
    first: np.ndarray,
    rng: np.random.Generator,
    private_start: float | None = None,
) -> np.ndarray:
    """``count`` features near the paths.

    ``first`` are the first features (those both robots see at step 0); the next 18 are spread
    evenly along the loops, so every step of every robot sees some feature; the rest are
    scattered at random along the paths. Larger sets therefore extend smaller ones. With
    ``private_start`` (a sensing range), no feature after ``first`` lies within that range of
    both robots' first waypoints (those are left out and others drawn along the paths): at step
    0 the robots share exactly ``first``.
    """
    even = []
    per_path = 9
    for path in paths:
        idx = (np.arange(per_path) * len(path)) // per_path + len(path) // (2 * per_path)
        even.append(path[idx] + rng.uniform(-spread, spread, (per_path, 2)))
    even = np.concatenate(even)[:18]
    pts = np.concatenate(paths)
    extra = pts[rng.integers(0, len(pts), 80)] + rng.uniform(-spread, spread, (80, 2))
    rest = np.vstack([even, extra])
    if private_start is not None:
        starts = np.array([path[0] for path in paths])

        def private(points: np.ndarray) -> np.ndarray:
            near = np.linalg.norm(points[:, None] - starts[None], axis=-1) < private_start
            return points[~np.all(near, axis=1)]

        rest = private(rest)
        while len(first) + len(rest) < count:  # refill what step 0 left out, along the paths
            more = pts[rng.integers(0, len(pts), 20)] + rng.uniform(-spread, spread, (20, 2))
            rest = np.vstack([rest, private(more)])
    return np.vstack([first, rest])[:count]


#: Distance between the robots' first waypoints in environment 1 (the published file's)
START_SEPARATION = 18.8


def _lens_starts(wp1, circle2, wp2, circle1, separation: float) -> tuple[int, int]:
    """Indices of a waypoint of loop 1 inside circle 2 and one of loop 2 inside circle 1 whose
    distance is closest to ``separation`` (the robots start inside the loops' overlap)."""
    inside1 = np.linalg.norm(wp1 - circle2[0], axis=1) < circle2[1]
    inside2 = np.linalg.norm(wp2 - circle1[0], axis=1) < circle1[1]
    gap = np.abs(np.linalg.norm(wp1[:, None] - wp2[None], axis=-1) - separation)
    gap[~inside1] = np.inf
    gap[:, ~inside2] = np.inf
    i, j = np.unravel_index(np.argmin(gap), gap.shape)
    return int(i), int(j)


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
        # two hand-drawn-like circles (radii 23.5 m and 22 m, centres 16 m apart); as in the
        # published environment, the robots start on either side of the loops' overlap
        # START_SEPARATION apart and share exactly two features at step 0, 3.8 m apart on the
        # line between them: robot 2's heading relative to robot 1 is then poorly known at the
        # start, which is what makes the standard EKF's inconsistency show
        r1, r2, d = 23.5, 22.0, 8.0
        c1, c2 = np.array([0.0, -d]), np.array([0.0, d])
        wp1 = _loop(c1, r1, 63, 0.0, +1.0, 0.3, rng)
        wp2 = _loop(c2, r2, 63, 0.0, -1.0, 0.3, rng)
        i, j = _lens_starts(wp1, (c2, r2), wp2, (c1, r1), START_SEPARATION)
        wp1, wp2 = np.roll(wp1, -i, axis=0), np.roll(wp2, -j, axis=0)
        along = (wp2[0] - wp1[0]) / np.linalg.norm(wp2[0] - wp1[0])
        middle = 0.5 * (wp1[0] + wp2[0])
        first = np.array([middle - 1.9 * along, middle + 1.9 * along])
        feats = _features_along([wp1, wp2], 100, 2.5, first, rng, private_start=15.0)
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
        # an outer loop (radius 39 m, 40 waypoints) and an 8 inside it (40 waypoints)
        outer = _loop((0.0, 0.0), 39.0, 40, -np.pi / 2, +1.0, 0.0, None)
        t = -np.pi / 2 + 2.0 * np.pi * np.arange(40) / 40
        eight = np.column_stack([16.0 * np.sin(2.0 * t), 31.0 * np.sin(t)])
        start = 0.5 * (outer[0] + eight[0])
        feats = _features_along([outer, eight], 100, 2.5, start + rng.uniform(-4, 4, (2, 2)), rng)
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
