"""Simulated stereo robot teams flying 3D Lissajous curves (distributed-MSCKF paper, §VI-B).

Each robot follows its own Lissajous curve through one shared arena, camera along the direction
of travel, seeing objects and geometric landmarks drawn around the trajectories; observations
are stereo projections with noise (pixels, or normalised coordinates with
``normalised_coordinates=True``), odometry the true relative pose perturbed on SE(3),
``δT = δT_true · exp(n)``. The team's sensor model records the true noise levels. Everything is
drawn from ``numpy.random.SeedSequence(seed)``: the same team in every process and platform.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial import cKDTree

from teamslam.datasets.model import (
    Calibration,
    FrameDetections,
    FrameObservations,
    RobotSequence,
    TeamDataset,
)
from teamslam.datasets.sensor_model import SensorModel, SensorNoise
from teamslam.errors import InputError
from teamslam.geometry import se3
from teamslam.geometry.camera import StereoCamera

__all__ = ["SimulationConfig", "lissajous_team"]

# body x forward, y left, z up  ->  optical x right, y down, z forward
T_CAM_BODY = np.array(
    [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)


@dataclass(frozen=True)
class SimulationConfig:
    """Every knob of the simulator, with defaults that give a well-posed problem.

    Attributes
    ----------
    robots, steps, objects, seed
        Team size, number of motion steps (each robot has ``steps + 1`` frames), number of
        objects in the map, random seed.
    landmarks
        Geometric landmarks in the map. A share ``background_fraction`` of them is spread
        uniformly over a box ``background_scale`` times the arena, so the view is never empty;
        the rest cluster around the paths.
    arena
        Half-extents ``(x, y, z)`` of the Lissajous curves, metres.
    step_length
        Approximate distance travelled per step, metres.
    image_size, focal, baseline
        Camera: ``(width, height)`` pixels, focal length (pixels), stereo baseline (m).
    min_depth, max_depth
        Depth range in which geometric features are tracked, metres.
    object_max_depth
        Range within which objects are detected.
    pixel_noise, object_pixel_noise
        Std of the stereo measurement noise of geometric features and of object box centres,
        in the units of the measurements (pixels, or normalised coordinates).
    normalised_coordinates
        Write measurements in normalised image coordinates (``K = I``) instead of pixels; the
        field of view is still the one of ``image_size`` and ``focal``.
    odometry_translation_noise, odometry_rotation_noise
        Per-axis std of the SE(3) odometry perturbation (m, rad), per step.
    object_spread, landmark_spread
        Std ``(x, y, z)`` of the Gaussians that scatter objects / landmarks around the paths.
    clutter, miss, classes
        An imperfect object detector. ``miss``: probability that a visible object is not
        detected in a frame. ``clutter``: false detections, per frame Poisson-distributed with
        mean ``clutter`` times the robot's mean true detections per frame (the share of false
        detections), each uniform in the image with a disparity of a depth uniform in
        ``[min_depth, object_max_depth]``. ``classes``: number of class labels (0: none); each
        object has one, drawn uniformly, and so has each false detection. When any of them is
        set, every robot also records its detections without ids
        (:class:`~teamslam.datasets.model.FrameDetections`, the truth of each: object id or
        -1), while its object observations with ids hold the true, detected objects only (an
        oracle's ids on the same detections). Drawn from generators of their own: the rest of
        the team is the same as without them.
    appearance, appearance_noise
        Simulated appearance (0: none): each object has a unit descriptor of ``appearance``
        dimensions drawn team-wide, and each detection of it carries a noisy copy, the
        descriptor plus isotropic noise of norm about ``appearance_noise`` (relative to the
        descriptor's unit norm), normalised; each false detection a random unit descriptor.
        Setting it records detections (as ``clutter``, ``miss`` and ``classes`` do), and each
        robot's own descriptor of every object it detected
        (:attr:`~teamslam.datasets.model.RobotSequence.object_appearance`: the object's plus
        noise of the same size, the robot's own, normalised).
    """

    robots: int = 5
    steps: int = 300
    objects: int = 210
    seed: int = 0
    landmarks: int = 1200
    background_fraction: float = 0.3
    background_scale: float = 1.6
    arena: tuple[float, float, float] = (40.0, 40.0, 4.0)
    step_length: float = 1.0
    image_size: tuple[int, int] = (640, 480)
    focal: float = 400.0
    baseline: float = 0.5
    min_depth: float = 1.0
    max_depth: float = 40.0
    object_max_depth: float = 25.0
    pixel_noise: float = 1.0
    object_pixel_noise: float = 2.0
    normalised_coordinates: bool = False
    odometry_translation_noise: float = 0.02
    odometry_rotation_noise: float = 0.004
    object_spread: tuple[float, float, float] = (5.0, 5.0, 1.5)
    landmark_spread: tuple[float, float, float] = (12.0, 12.0, 4.0)
    clutter: float = 0.0
    miss: float = 0.0
    classes: int = 0
    appearance: int = 0
    appearance_noise: float = 0.3

    def __post_init__(self) -> None:
        if (
            isinstance(self.appearance, bool)
            or not isinstance(self.appearance, int)
            or self.appearance < 0
        ):
            raise InputError("appearance must be an integer ≥ 0 (descriptor dimension; 0: none)")
        if not (np.isfinite(self.appearance_noise) and self.appearance_noise >= 0):
            raise InputError("appearance_noise must be a finite number ≥ 0")
        if not (np.isfinite(self.clutter) and self.clutter >= 0):
            raise InputError("clutter must be a finite number ≥ 0 (false per true detection)")
        if not 0.0 <= self.miss < 1.0:
            raise InputError("miss must be a probability in [0, 1)")
        if isinstance(self.classes, bool) or not isinstance(self.classes, int) or self.classes < 0:
            raise InputError("classes must be an integer ≥ 0 (0: no class labels)")
        if self.robots < 1 or self.steps < 1:
            raise InputError("robots and steps must be positive")
        if self.objects < 0 or self.landmarks < 0:
            raise InputError("objects and landmarks must be non-negative")
        if not 0.0 <= self.background_fraction <= 1.0:
            raise InputError("background_fraction must lie in [0, 1]")
        for name in (
            "pixel_noise",
            "object_pixel_noise",
            "odometry_translation_noise",
            "odometry_rotation_noise",
        ):
            if getattr(self, name) < 0 or not np.isfinite(getattr(self, name)):
                raise InputError(f"{name} must be a finite non-negative number")
        if not 0 < self.min_depth < self.max_depth:
            raise InputError("need 0 < min_depth < max_depth")
        if self.step_length <= 0 or self.focal <= 0 or self.baseline <= 0:
            raise InputError("step_length, focal and baseline must be positive")

    def camera(self) -> StereoCamera:
        """The stereo camera in pixels (its image bounds decide what is visible)."""
        w, h = self.image_size
        return StereoCamera.from_baseline(self.focal, self.focal, w / 2.0, h / 2.0, self.baseline)

    def measurement_camera(self) -> StereoCamera:
        """The camera the measurements are written in: :meth:`camera`, or ``K = I``."""
        if self.normalised_coordinates:
            return StereoCamera.from_baseline(1.0, 1.0, 0.0, 0.0, self.baseline)
        return self.camera()

    def sensor_model(self) -> SensorModel:
        """The generator's true noise as the team's sensor model.

        A noise-free team records tiny positive floors instead of zero (a filter needs a
        positive σ): 10⁻⁴ m and 10⁻⁵ rad per step, ``2.5·10⁻⁶ fx`` for measurements.
        """
        unit = self.measurement_camera().intrinsics[0, 0]
        floor = 2.5e-6 * unit
        noise = SensorNoise(
            odometry_std=(max(self.odometry_translation_noise, 1e-4),) * 3
            + (max(self.odometry_rotation_noise, 1e-5),) * 3,
            feature_std=max(self.pixel_noise, floor),
            object_std=max(self.object_pixel_noise, floor),
            object_depth_range=(self.min_depth, self.object_max_depth),
        )
        noise_free = 0.0 in (
            self.odometry_translation_noise,
            self.odometry_rotation_noise,
            self.pixel_noise,
            self.object_pixel_noise,
        )
        note = "true noise of the generator" + (" (zero noise floored)" if noise_free else "")
        return SensorModel(noise, origin="simulation", note=note)


def _lissajous(config: SimulationConfig, rng: np.random.Generator) -> np.ndarray:
    """Ground-truth body poses ``(steps + 1, 4, 4)`` along one robot's Lissajous curve."""
    base = np.array([1.0, 2.0, 3.0])
    freq = base * rng.uniform(0.85, 1.15, 3)
    phase = rng.uniform(0.0, 2.0 * np.pi, 3)
    amp = np.asarray(config.arena) * rng.uniform(0.8, 1.0, 3)
    # arc-length parametrisation on a fine grid so steps are ~step_length apart
    s_fine = np.linspace(0.0, 2.0 * np.pi, 20_000)
    p_fine = amp * np.sin(np.outer(s_fine, freq) + phase)
    seg = np.linalg.norm(np.diff(p_fine, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    length = arc[-1]
    targets = (np.arange(config.steps + 1) * config.step_length) % length
    s = np.interp(targets, arc, s_fine)
    position = amp * np.sin(np.outer(s, freq) + phase)
    velocity = amp * freq * np.cos(np.outer(s, freq) + phase)
    forward = velocity / np.linalg.norm(velocity, axis=1, keepdims=True)
    left = np.cross([0.0, 0.0, 1.0], forward)
    left /= np.linalg.norm(left, axis=1, keepdims=True)
    up = np.cross(forward, left)
    poses = np.tile(np.eye(4), (config.steps + 1, 1, 1))
    poses[:, :3, 0], poses[:, :3, 1], poses[:, :3, 2] = forward, left, up
    poses[:, :3, 3] = position
    return poses


def _scatter(
    centres: np.ndarray, count: int, spread: tuple[float, float, float], rng: np.random.Generator
) -> np.ndarray:
    pick = rng.integers(0, len(centres), count)
    return centres[pick] + rng.standard_normal((count, 3)) * np.asarray(spread)


def _observe(
    T_world_body: np.ndarray,
    points: np.ndarray,
    config: SimulationConfig,
    max_depth: float,
    noise_std: float,
    rng: np.random.Generator,
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per frame ``(point indices, noisy stereo measurements)`` of the visible points."""
    camera, output = config.camera(), config.measurement_camera()
    w, h = config.image_size
    tree = cKDTree(points) if len(points) else None
    reach = np.hypot(max_depth, np.hypot(w, h) / (2 * config.focal) * max_depth)
    T_cam_world = T_CAM_BODY @ se3.inverse(T_world_body)
    frames = []
    for k in range(len(T_world_body)):
        if tree is None:
            frames.append((np.zeros(0, np.int64), np.zeros((0, 4))))
            continue
        near = np.array(
            sorted(tree.query_ball_point(T_world_body[k, :3, 3], reach)), dtype=np.int64
        )
        p_cam = points[near] @ T_cam_world[k, :3, :3].T + T_cam_world[k, :3, 3]
        visible = camera.in_view(p_cam, w, h, config.min_depth, max_depth)
        idx = near[visible]
        z = output.project(p_cam[visible])
        if noise_std > 0:
            z = z + noise_std * rng.standard_normal(z.shape)
            keep = z[:, 0] - z[:, 2] > 0  # noisy disparity must stay positive
            idx, z = idx[keep], z[keep]
        frames.append((idx, z))
    return frames


def _tracks(
    frames: list[tuple[np.ndarray, np.ndarray]], first_id: int
) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[tuple[int, int]], int]:
    """Relabel landmark indices into track ids: a track lasts while the landmark stays visible."""
    out, pairs = [], []
    next_id = first_id
    prev_lm = np.zeros(0, np.int64)
    prev_tr = np.zeros(0, np.int64)
    for lm, z in frames:
        order = np.argsort(lm)
        lm, z = lm[order], z[order]
        tr = np.empty(lm.size, np.int64)
        pos = np.searchsorted(prev_lm, lm)
        pos_c = np.clip(pos, 0, max(prev_lm.size - 1, 0))
        cont = (
            (prev_lm.size > 0) & (prev_lm[pos_c] == lm) if prev_lm.size else np.zeros(lm.size, bool)
        )
        tr[cont] = prev_tr[pos_c[cont]]
        fresh = np.flatnonzero(~cont)
        tr[fresh] = next_id + np.arange(fresh.size)
        pairs.extend(
            zip((next_id + np.arange(fresh.size)).tolist(), lm[fresh].tolist(), strict=True)
        )
        next_id += fresh.size
        out.append((tr, z))
        prev_lm, prev_tr = lm, tr
    return out, pairs, next_id


def check_sensing_overrides(overrides: dict, simulator: str) -> None:
    """Refuse, in one line, an override of another route simulator that is a setting of the
    Lissajous arena rather than of sensing (team size, map, arena, steps, seed)."""
    for name in ("robots", "objects", "landmarks", "arena", "steps", "seed"):
        if name in overrides:
            raise InputError(f"{simulator} has no {name!r} setting of the Lissajous arena")


def noise_overrides(noise_free: bool) -> dict[str, float]:
    """The :class:`SimulationConfig` fields that zero every noise level (none unless asked)."""
    if not noise_free:
        return {}
    names = ("pixel_noise", "object_pixel_noise")
    names += ("odometry_translation_noise", "odometry_rotation_noise")
    return dict.fromkeys(names, 0.0)


def generators(
    seed: int, noise_seed: int | None, robots: int
) -> tuple[np.random.SeedSequence, np.random.Generator, list[np.random.Generator]]:
    """The seed sequence of the paths, the map's generator and each robot's noise generator
    (drawn from ``noise_seed`` instead of ``seed`` when given)."""
    path_seq, map_seq, noise_seq = np.random.SeedSequence(seed).spawn(3)
    if noise_seed is not None:
        noise_seq = np.random.SeedSequence([seed, noise_seed, 1])
    noise_rngs = [np.random.default_rng(s) for s in noise_seq.spawn(robots)]
    return path_seq, np.random.default_rng(map_seq), noise_rngs


def lissajous_team(
    robots: int = 5,
    steps: int = 300,
    objects: int = 210,
    seed: int = 0,
    noise_free: bool = False,
    noise_seed: int | None = None,
    **overrides,
) -> TeamDataset:
    """Simulate a team of stereo robots on Lissajous curves.

    Parameters
    ----------
    robots, steps, objects, seed
        Team size, motion steps per robot, objects in the map, random seed.
    noise_free
        Zero every noise level (pixel, object pixel, odometry): observations are exact
        projections and odometry composes to the true path.
    noise_seed
        Draw the noise from this seed instead of ``seed``: the same paths and map with a
        different noise realisation (Monte Carlo runs).
    **overrides
        Any other :class:`SimulationConfig` field.

    Returns
    -------
    TeamDataset
        With ground-truth objects, geometric landmarks and the landmark behind every track;
        ``metadata["simulation"]`` records the full configuration.
    """
    overrides.update(noise_overrides(noise_free))
    config = SimulationConfig(robots=robots, steps=steps, objects=objects, seed=seed, **overrides)
    traj_seq, map_rng, noise_rngs = generators(seed, noise_seed, robots)
    traj_rngs = [np.random.default_rng(s) for s in traj_seq.spawn(robots)]

    paths = [_lissajous(config, rng) for rng in traj_rngs]
    centres = np.concatenate([p[:, :3, 3] for p in paths])
    object_positions = _scatter(centres, config.objects, config.object_spread, map_rng)
    background = round(config.background_fraction * config.landmarks)
    half = np.asarray(config.arena) * config.background_scale
    landmark_positions = np.concatenate(
        [
            _scatter(centres, config.landmarks - background, config.landmark_spread, map_rng),
            map_rng.uniform(-half, half, (background, 3)),
        ]
    )
    return simulate_team(
        config,
        paths,
        object_positions,
        landmark_positions,
        noise_rngs,
        name=f"lissajous-{robots}r-{steps}s-seed{seed}",
        metadata={"source": "teamslam.sim.lissajous_team", "simulation": _jsonable(asdict(config))},
    )


def simulate_team(
    config: SimulationConfig,
    paths: list[np.ndarray],
    object_positions: np.ndarray,
    landmark_positions: np.ndarray,
    noise_rngs: list[np.random.Generator],
    name: str,
    metadata: dict,
) -> TeamDataset:
    """Sense a world along given paths: noisy odometry, feature tracks and object observations.

    Parameters
    ----------
    config
        Camera, depth ranges and noise levels (its path and map fields are not used).
    paths
        Per robot ``(steps + 1, 4, 4)`` true ``T_world_body``.
    object_positions, landmark_positions
        The world: ``(m, 3)`` objects (ids ``0 … m−1``) and geometric landmarks.
    noise_rngs
        One generator per robot for its odometry and measurement noise.
    name, metadata
        The dataset's name and metadata.
    """
    steps = paths[0].shape[0] - 1
    sequences = []
    track_pairs: list[tuple[int, int]] = []
    next_track = 0
    sigma = np.array([config.odometry_translation_noise] * 3 + [config.odometry_rotation_noise] * 3)
    for i, path in enumerate(paths):
        rng = noise_rngs[i]
        odo_true = se3.inverse(path[:-1]) @ path[1:]
        odometry = odo_true @ se3.exp(rng.standard_normal((steps, 6)) * sigma)
        feat_frames = _observe(
            path, landmark_positions, config, config.max_depth, config.pixel_noise, rng
        )
        obj_frames = _observe(
            path,
            object_positions,
            config,
            config.object_max_depth,
            config.object_pixel_noise,
            rng,
        )
        feat_frames, pairs, next_track = _tracks(feat_frames, next_track)
        track_pairs.extend(pairs)
        detections, classes, looks_ids, looks = None, None, None, None
        if config.clutter > 0 or config.miss > 0 or config.classes > 0 or config.appearance > 0:
            obj_frames, detections, classes = _detector(
                config, obj_frames, len(object_positions), i
            )
        if config.appearance > 0:
            looks_ids = np.unique(np.concatenate([idx for idx, _ in obj_frames])).astype(np.int64)
            looks = _object_appearance(config, looks_ids, len(object_positions), i)
        sequences.append(
            RobotSequence(
                T_world_body=path,
                odometry=odometry,
                features=FrameObservations.from_frames(feat_frames),
                objects=FrameObservations.from_frames(obj_frames),
                timestamps=np.arange(steps + 1, dtype=float),
                object_classes=classes,
                detections=detections,
                object_appearance_ids=looks_ids,
                object_appearance=looks,
            )
        )
    return TeamDataset(
        name=name,
        calibration=Calibration(
            config.measurement_camera(),
            T_CAM_BODY,
            None if config.normalised_coordinates else config.image_size,
        ),
        robots=sequences,
        object_ids=np.arange(len(object_positions)),
        object_positions=object_positions,
        landmark_ids=np.arange(len(landmark_positions)),
        landmark_positions=landmark_positions,
        track_landmarks=np.array(track_pairs, dtype=np.int64).reshape(-1, 2),
        metadata=metadata,
        sensor_model=config.sensor_model(),
    )


def _detector(
    config: SimulationConfig,
    frames: list[tuple[np.ndarray, np.ndarray]],
    objects: int,
    robot: int,
) -> tuple[list[tuple[np.ndarray, np.ndarray]], FrameDetections, np.ndarray | None]:
    """Misses, clutter and classes of robot ``robot``'s object detector.

    Returns the detected true objects (ids kept), every detection without ids (true ones
    then false ones shuffled within the frame) and the class rows of the objects.
    """
    rng = np.random.default_rng([config.seed, 25, robot])
    label_rng = np.random.default_rng([config.seed, 25])  # one class per object, team-wide
    object_class = label_rng.integers(0, max(config.classes, 1), objects)
    camera, output = config.camera(), config.measurement_camera()
    k = camera.intrinsics
    w, h = config.image_size
    kept = []
    for idx, z in frames:
        hit = rng.random(idx.size) >= config.miss
        kept.append((idx[hit], z[hit]))
    mean_true = np.mean([idx.size for idx, _ in kept]) if kept else 0.0
    rows, truth, counts = [], [], []
    for idx, z in kept:
        n_false = rng.poisson(config.clutter * mean_true) if config.clutter > 0 else 0
        u = rng.uniform(0.0, w, n_false)
        v = rng.uniform(0.0, h, n_false)
        depth = rng.uniform(config.min_depth, config.object_max_depth, n_false)
        p_cam = np.stack(
            [(u - k[0, 2]) / k[0, 0] * depth, (v - k[1, 2]) / k[1, 1] * depth, depth], axis=1
        )
        z_all = np.concatenate([z, output.project(p_cam).reshape(-1, 4)])
        t_all = np.concatenate([idx, np.full(n_false, -1, dtype=np.int64)])
        order = rng.permutation(t_all.size)
        rows.append(z_all[order])
        truth.append(t_all[order])
        counts.append(t_all.size)
    truth_all = np.concatenate(truth).astype(np.int64) if truth else np.zeros(0, np.int64)
    labels = None
    classes = None
    if config.classes > 0:
        false = truth_all < 0
        labels = np.where(false, 0, object_class[np.maximum(truth_all, 0)])
        labels[false] = rng.integers(0, config.classes, int(false.sum()))
        seen = np.unique(np.concatenate([idx for idx, _ in kept]).astype(np.int64))
        classes = np.column_stack([seen, object_class[seen]]).astype(np.int64)
    detections = FrameDetections(
        np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        np.concatenate(rows).reshape(-1, 4) if rows else np.zeros((0, 4)),
        labels,
        None,
        truth_all,
        appearance=_appearance(config, truth_all, objects, robot),
    )
    return kept, detections, classes


def _appearance(
    config: SimulationConfig, truth: np.ndarray, objects: int, robot: int
) -> np.ndarray | None:
    """Each detection's descriptor: its object's (team-wide) plus noise, normalised; a false
    detection's random. From generators of their own (nothing else drawn changes)."""
    dim = config.appearance
    if dim == 0:
        return None
    unit = _object_descriptors(config, objects)
    rng = np.random.default_rng([config.seed, 26, robot])
    noise = rng.standard_normal((truth.size, dim)) * (config.appearance_noise / np.sqrt(dim))
    base = rng.standard_normal((truth.size, dim))
    base /= np.linalg.norm(base, axis=1, keepdims=True)
    true = truth >= 0
    base[true] = unit[truth[true]]
    out = base + noise
    out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)
    return out.astype(np.float32)


def _object_descriptors(config: SimulationConfig, objects: int) -> np.ndarray:
    """Each object's team-wide unit descriptor."""
    unit = np.random.default_rng([config.seed, 26]).standard_normal((objects, config.appearance))
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    return unit


def _object_appearance(
    config: SimulationConfig, ids: np.ndarray, objects: int, robot: int
) -> np.ndarray:
    """Robot ``robot``'s descriptor of each object ``ids``: the object's plus the robot's own
    noise (as a detection's), normalised; from a generator of its own."""
    dim = config.appearance
    rng = np.random.default_rng([config.seed, 27, robot])
    noise = rng.standard_normal((ids.size, dim)) * (config.appearance_noise / np.sqrt(dim))
    out = _object_descriptors(config, objects)[ids] + noise
    out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)
    return out.astype(np.float32)


def _jsonable(d: dict) -> dict:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}
