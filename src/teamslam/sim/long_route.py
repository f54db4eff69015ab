"""A long mission: a stereo robot team driving side by side along a long, winding route.

The route never comes back on itself, so the team keeps discovering new objects and leaving old
ones behind (unlike the Lissajous arena). Robot ``i`` drives its own lane, ``lane_spacing``
metres to the side and ``stagger`` metres behind the robot before it; objects and landmarks are
scattered along the route at ``objects_per_metre`` and ``landmarks_per_metre``. Sensing is the
Lissajous simulator's (:class:`~teamslam.sim.lissajous.SimulationConfig`). Drawn from
``numpy.random.SeedSequence(seed)``.
"""

from __future__ import annotations

from dataclasses import asdict

import numpy as np

from teamslam.datasets.model import TeamDataset
from teamslam.errors import InputError
from teamslam.sim.lissajous import (
    SimulationConfig,
    _jsonable,
    check_sensing_overrides,
    generators,
    noise_overrides,
    simulate_team,
)

__all__ = ["long_route_team"]

_WAVELENGTHS = (400.0, 97.0)  # metres, incommensurate: the route never repeats
_AMPLITUDES = (30.0, 6.0)  # metres
_HEIGHT = (0.5, 150.0)  # amplitude and wavelength of the vertical wave, metres


def _centreline(length: float, phase: np.ndarray, spacing: float = 0.05) -> tuple:
    """Arc length, positions and unit tangents of the route on a fine grid."""
    x = np.arange(-60.0, length + 60.0, spacing)
    waves = zip(_AMPLITUDES, _WAVELENGTHS, phase[:2], strict=True)
    y = sum(a * np.sin(2 * np.pi * x / w + p) for a, w, p in waves)
    z = _HEIGHT[0] * np.sin(2 * np.pi * x / _HEIGHT[1] + phase[-1])
    points = np.column_stack([x, y, z])
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)]) - 60.0  # arc 0 near x = 0
    tangent = np.gradient(points, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    return arc, points, tangent


def _at(arc: np.ndarray, values: np.ndarray, s: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(s, arc, values[:, k]) for k in range(values.shape[1])])


def _frames(tangent: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    forward = tangent / np.linalg.norm(tangent, axis=1, keepdims=True)
    left = np.cross([0.0, 0.0, 1.0], forward)
    left /= np.linalg.norm(left, axis=1, keepdims=True)
    return forward, left, np.cross(forward, left)


def long_route_team(
    robots: int = 3,
    steps: int = 5000,
    seed: int = 0,
    noise_free: bool = False,
    noise_seed: int | None = None,
    objects_per_metre: float = 1.2,
    landmarks_per_metre: float = 4.5,
    lane_spacing: float = 4.0,
    stagger: float = 3.0,
    object_spread: tuple[float, float] = (8.0, 1.5),
    landmark_spread: tuple[float, float] = (14.0, 4.0),
    **overrides,
) -> TeamDataset:
    """Simulate a team on a long non-repeating route through a world of objects.

    Parameters
    ----------
    robots, steps, seed
        Team size, motion steps per robot (``step_length`` metres each, 1 by default), seed.
    noise_free, noise_seed
        As in :func:`~teamslam.sim.lissajous.lissajous_team`.
    objects_per_metre, landmarks_per_metre
        Density of objects and geometric landmarks along the route (per metre of route): a
        5,000-step route at the defaults holds about 6,100 objects.
    lane_spacing, stagger
        Sideways distance between neighbouring robots' lanes and how far each drives behind
        the one before it (metres).
    object_spread, landmark_spread
        Std (sideways, vertical) of the scatter of objects and landmarks about the centreline.
    **overrides
        Sensing fields of :class:`~teamslam.sim.lissajous.SimulationConfig` (camera, depth
        ranges, noise levels, ``step_length``).

    Returns
    -------
    TeamDataset
        With ground truth; ``metadata["simulation"]`` records every setting.
    """
    check_sensing_overrides(overrides, "long_route_team")
    if objects_per_metre < 0 or landmarks_per_metre < 0:
        raise InputError("objects_per_metre and landmarks_per_metre must be non-negative")
    if lane_spacing < 0 or stagger < 0:
        raise InputError("lane_spacing and stagger must be non-negative")
    overrides.update(noise_overrides(noise_free))
    config = SimulationConfig(robots=robots, steps=steps, objects=0, seed=seed, **overrides)
    route_seq, map_rng, noise_rngs = generators(seed, noise_seed, robots)
    phase = np.random.default_rng(route_seq).uniform(0.0, 2 * np.pi, 3)

    travel = steps * config.step_length + stagger * (robots - 1)
    length = travel + config.max_depth  # the world reaches one view beyond the last pose
    arc, centre, tangent = _centreline(length, phase)
    paths = []
    for i in range(robots):
        s = (robots - 1 - i) * stagger + np.arange(steps + 1) * config.step_length
        forward, left, up = _frames(_at(arc, tangent, s))
        lane = (i - (robots - 1) / 2) * lane_spacing
        poses = np.tile(np.eye(4), (steps + 1, 1, 1))
        poses[:, :3, 0], poses[:, :3, 1], poses[:, :3, 2] = forward, left, up
        poses[:, :3, 3] = _at(arc, centre, s) + lane * left
        paths.append(poses)

    def scatter(count: int, spread: tuple[float, float]) -> np.ndarray:
        s = np.sort(map_rng.uniform(0.0, length, count))
        _, left, up = _frames(_at(arc, tangent, s))
        side, height = map_rng.standard_normal((2, count)) * np.asarray(spread)[:, None]
        return _at(arc, centre, s) + side[:, None] * left + height[:, None] * up

    object_positions = scatter(round(objects_per_metre * length), object_spread)
    landmark_positions = scatter(round(landmarks_per_metre * length), landmark_spread)
    settings = _jsonable(asdict(config))
    settings.update(
        objects=len(object_positions),
        landmarks=len(landmark_positions),
        route="long",
        objects_per_metre=objects_per_metre,
        landmarks_per_metre=landmarks_per_metre,
        lane_spacing=lane_spacing,
        stagger=stagger,
        object_spread=list(object_spread),
        landmark_spread=list(landmark_spread),
    )
    return simulate_team(
        config,
        paths,
        object_positions,
        landmark_positions,
        noise_rngs,
        name=f"long-route-{robots}r-{steps}s-seed{seed}",
        metadata={"source": "teamslam.sim.long_route_team", "simulation": settings},
    )
