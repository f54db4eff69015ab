"""A grid city: a stereo car team driving straight streets lined with regularly spaced objects.

Streets run along ``x = i·block_size`` and ``y = j·block_size`` (``i ≤ nx``, ``j ≤ ny``). Along
both kerbs of every street segment stand objects (parked cars, lamp posts, bins) every
``object_spacing`` metres, each jittered a little about its slot; the facades behind the
pavements carry the geometric landmarks. Each car starts at an intersection and drives its
lane (on the right of the centreline), choosing at every intersection one of the streets that do
not turn back, with rounded corners; routes wander through the whole grid, so cars drive streets
others drove and see the same objects. Sensing is the Lissajous simulator's
(:class:`~teamslam.sim.lissajous.SimulationConfig`: no occlusion) with a KITTI-like pixel camera
by default (700 px focal, 1241×376, 0.54 m baseline). Drawn from ``SeedSequence(seed)``.
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

__all__ = ["grid_city_team"]

#: the camera of a KITTI-like car unless overridden
CAMERA = {"focal": 700.0, "image_size": (1241, 376), "baseline": 0.54}
_HEADINGS = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])


def _kerb_objects(
    blocks: tuple[int, int],
    block_size: float,
    street_width: float,
    spacing: float,
    jitter: tuple[float, float, float],
    height: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Objects every ``spacing`` metres along both kerbs of every street segment at ``height``,
    jittered (std along, across, up)."""
    half = street_width / 2.0
    free = block_size - street_width  # kerb length between two crossings
    count = int(np.floor(free / spacing)) + 1 if free >= 0 else 0
    along = (free - (count - 1) * spacing) / 2.0 + np.arange(count) * spacing + half
    slots = []
    nx, ny = blocks
    for horizontal, lines, segments in ((True, ny + 1, nx), (False, nx + 1, ny)):
        for line in range(lines):
            for seg in range(segments):
                for side in (-1.0, 1.0):
                    a = seg * block_size + along
                    b = np.full(count, line * block_size + side * half)
                    slots.append(np.column_stack([a, b] if horizontal else [b, a]))
    xy = np.concatenate(slots) if slots else np.zeros((0, 2))
    along_axis = np.zeros_like(xy)
    n_h = (ny + 1) * nx * 2 * count
    along_axis[:n_h, 0] = 1.0
    along_axis[n_h:, 1] = 1.0
    across_axis = along_axis[:, ::-1]
    noise = rng.standard_normal((len(xy), 3)) * np.asarray(jitter)
    xy = xy + noise[:, :1] * along_axis + noise[:, 1:2] * across_axis
    return np.column_stack([xy, height + noise[:, 2]])


def _facade_landmarks(
    blocks: tuple[int, int],
    block_size: float,
    street_width: float,
    pavement: float,
    per_metre: float,
    height: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Points on the four facades of every block and of the ring of blocks around the grid,
    uniform along each facade and in height."""
    inset = street_width / 2.0 + pavement
    side = block_size - 2.0 * inset
    if side <= 0 or per_metre == 0:
        return np.zeros((0, 3))
    per_facade = rng.poisson(per_metre * side, (blocks[0] + 2, blocks[1] + 2, 4))
    points = []
    for bx in range(-1, blocks[0] + 1):  # the outer ring of buildings lines the outer streets
        for by in range(-1, blocks[1] + 1):
            x0, y0 = bx * block_size + inset, by * block_size + inset
            x1, y1 = x0 + side, y0 + side
            for f, n in enumerate(per_facade[bx + 1, by + 1]):
                t = rng.uniform(0.0, side, n)
                if f == 0:
                    xy = np.column_stack([x0 + t, np.full(n, y0)])
                elif f == 1:
                    xy = np.column_stack([x0 + t, np.full(n, y1)])
                elif f == 2:
                    xy = np.column_stack([np.full(n, x0), y0 + t])
                else:
                    xy = np.column_stack([np.full(n, x1), y0 + t])
                points.append(np.column_stack([xy, rng.uniform(0.0, height, n)]))
    return np.concatenate(points)


def _route(blocks: tuple[int, int], length: float, rng: np.random.Generator) -> np.ndarray:
    """Intersections ``(k, 2)`` (grid units) of a random walk without U-turns of at least
    ``length`` legs."""
    nx, ny = blocks
    node = np.array([rng.integers(0, nx + 1), rng.integers(0, ny + 1)])
    nodes = [node.copy()]
    heading = -1
    while len(nodes) < length + 3:
        options = [
            h
            for h in range(4)
            if (heading < 0 or h != (heading + 2) % 4)
            and 0 <= node[0] + _HEADINGS[h, 0] <= nx
            and 0 <= node[1] + _HEADINGS[h, 1] <= ny
        ]
        heading = int(options[rng.integers(0, len(options))])
        node = node + _HEADINGS[heading].astype(int)
        nodes.append(node.copy())
    return np.array(nodes, dtype=float)


def _drive(
    nodes: np.ndarray, radius: float, lane: float, step: float, steps: int, spacing: float = 0.05
) -> np.ndarray | None:
    """``(steps + 1, 4, 4)`` poses ``step`` metres apart along the lane ``lane`` metres to the
    right of the polyline ``nodes`` (metres), corners rounded with arcs of ``radius``; None
    when the lane is shorter than the drive."""
    points = [nodes[0]]
    for k in range(1, len(nodes) - 1):
        d_in = nodes[k] - nodes[k - 1]
        d_out = nodes[k + 1] - nodes[k]
        d_in, d_out = d_in / np.linalg.norm(d_in), d_out / np.linalg.norm(d_out)
        if np.allclose(d_in, d_out):
            points.append(nodes[k])
            continue
        start = nodes[k] - radius * d_in
        turn = np.sign(d_in[0] * d_out[1] - d_in[1] * d_out[0])  # +1 left, -1 right
        normal = turn * np.array([-d_in[1], d_in[0]])
        centre = start + radius * normal
        a0 = np.arctan2(*(start - centre)[::-1])
        # as fine as the resampling below, so the lane's offset of the arc is an arc too
        n = int(np.ceil(radius * np.pi / 2 / spacing)) + 1
        angles = a0 + turn * np.linspace(0.0, np.pi / 2, n)
        points.extend(centre + radius * np.column_stack([np.cos(angles), np.sin(angles)]))
    points.append(nodes[-1])
    poly = np.array(points)
    seg = np.linalg.norm(np.diff(poly, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-9])
    poly = poly[keep]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poly, axis=0), axis=1))])
    s = np.arange(0.0, arc[-1], spacing)
    centre = np.column_stack([np.interp(s, arc, poly[:, k]) for k in range(2)])
    tangent = np.gradient(centre, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    right = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    lane_xy = centre + lane * right
    lane_arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(lane_xy, axis=0), axis=1))])
    targets = np.arange(steps + 1) * step
    if targets[-1] > lane_arc[-1]:
        return None
    xy = np.column_stack([np.interp(targets, lane_arc, lane_xy[:, k]) for k in range(2)])
    yaw = np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))
    heading = np.interp(targets, lane_arc, yaw)
    poses = np.tile(np.eye(4), (steps + 1, 1, 1))
    c, s_ = np.cos(heading), np.sin(heading)
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = c, -s_, s_, c
    poses[:, :2, 3] = xy
    return poses


def grid_city_team(
    robots: int = 4,
    steps: int = 400,
    seed: int = 0,
    noise_free: bool = False,
    noise_seed: int | None = None,
    blocks: tuple[int, int] = (3, 3),
    block_size: float = 60.0,
    street_width: float = 12.0,
    pavement: float = 3.0,
    object_spacing: float = 8.0,
    object_height: float = 0.9,
    object_jitter: tuple[float, float, float] = (0.3, 0.15, 0.15),
    landmarks_per_metre: float = 1.5,
    facade_height: float = 12.0,
    lane: float = 2.0,
    camera_height: float = 1.6,
    turn_radius: float = 6.0,
    **overrides,
) -> TeamDataset:
    """Simulate a car team driving the streets of a grid city lined with regular objects.

    Parameters
    ----------
    robots, steps, seed
        Team size, motion steps per car (``step_length`` metres each, 1 by default), seed.
    noise_free, noise_seed
        As in :func:`~teamslam.sim.lissajous.lissajous_team`.
    blocks
        Blocks ``(nx, ny)``: ``nx + 1`` streets one way, ``ny + 1`` the other.
    block_size
        Distance between neighbouring parallel streets' centrelines (metres).
    street_width, pavement
        Kerb to kerb width of a street, and the pavement between kerb and facade (metres).
    object_spacing, object_height, object_jitter
        Distance between neighbouring objects along a kerb, the height of their centres, and
        the std ``(along, across, up)`` of each object's offset from its slot (metres).
    landmarks_per_metre, facade_height
        Geometric landmarks per metre of facade, uniform in height up to ``facade_height``.
    lane, camera_height
        The car's lane (metres right of the centreline) and its camera's height.
    turn_radius
        Radius of the centreline's arc at a turn (metres).
    **overrides
        Sensing fields of :class:`~teamslam.sim.lissajous.SimulationConfig` (camera, depth
        ranges, noise levels, ``step_length``, the detector's ``miss``, ``clutter``,
        ``classes``, ``appearance``); the camera defaults to :data:`CAMERA`.

    Returns
    -------
    TeamDataset
        With ground truth; ``metadata["simulation"]`` records every setting.
    """
    check_sensing_overrides(overrides, "grid_city_team")
    nx, ny = (int(b) for b in blocks) if len(blocks) == 2 else (0, 0)
    if len(blocks) != 2 or nx < 1 or ny < 1 or (nx, ny) != tuple(blocks):
        raise InputError(f"blocks must be two positive integers (nx, ny), got {blocks!r}")
    for name, value in (
        ("block_size", block_size),
        ("street_width", street_width),
        ("object_spacing", object_spacing),
        ("turn_radius", turn_radius),
        ("facade_height", facade_height),
    ):
        if not (np.isfinite(value) and value > 0):
            raise InputError(f"{name} must be a positive number, got {value}")
    for name, value in (
        ("pavement", pavement),
        ("object_height", object_height),
        ("landmarks_per_metre", landmarks_per_metre),
        ("camera_height", camera_height),
        ("lane", lane),
    ):
        if not (np.isfinite(value) and value >= 0):
            raise InputError(f"{name} must be a finite number ≥ 0, got {value}")
    if len(object_jitter) != 3 or not all(np.isfinite(j) and j >= 0 for j in object_jitter):
        raise InputError(f"object_jitter must be three numbers ≥ 0, got {object_jitter!r}")
    if street_width >= block_size:
        raise InputError("street_width must be smaller than block_size")
    if lane >= street_width / 2.0:
        raise InputError("lane must lie inside the street (lane < street_width / 2)")
    if not lane < turn_radius <= block_size / 2.0:
        raise InputError("turn_radius must exceed lane and fit the corner (≤ block_size / 2)")
    overrides = {**CAMERA, **overrides, **noise_overrides(noise_free)}
    config = SimulationConfig(robots=robots, steps=steps, objects=0, seed=seed, **overrides)
    route_seq, map_rng, noise_rngs = generators(seed, noise_seed, robots)

    paths = []
    for seq in route_seq.spawn(robots):
        legs = (steps * config.step_length + 2 * block_size) / block_size
        poses = None
        while poses is None:  # rounded corners shorten a walk: draw a longer one from the start
            nodes = _route((nx, ny), legs, np.random.default_rng(seq))
            poses = _drive(nodes * block_size, turn_radius, lane, config.step_length, steps)
            legs *= 2
        poses[:, 2, 3] = camera_height
        paths.append(poses)

    object_positions = _kerb_objects(
        (nx, ny), block_size, street_width, object_spacing, object_jitter, object_height, map_rng
    )
    landmark_positions = _facade_landmarks(
        (nx, ny), block_size, street_width, pavement, landmarks_per_metre, facade_height, map_rng
    )
    settings = _jsonable(asdict(config))
    settings.update(
        objects=len(object_positions),
        landmarks=len(landmark_positions),
        route="grid",
        blocks=[nx, ny],
        block_size=block_size,
        street_width=street_width,
        pavement=pavement,
        object_spacing=object_spacing,
        object_height=object_height,
        object_jitter=list(object_jitter),
        landmarks_per_metre=landmarks_per_metre,
        facade_height=facade_height,
        lane=lane,
        camera_height=camera_height,
        turn_radius=turn_radius,
    )
    return simulate_team(
        config,
        paths,
        object_positions,
        landmark_positions,
        noise_rngs,
        name=f"grid-city-{robots}r-{steps}s-seed{seed}",
        metadata={"source": "teamslam.sim.grid_city_team", "simulation": settings},
    )
