"""A rendered team: stereo images of a textured room with ArUco markers, and their exact truth.

A closed room (or a long street, ``layout="street"``) with procedural textures generated from
the seed (nothing licensed is shipped), ArUco markers on the walls (a marker's id is its object
id) and optionally coloured, textured objects of several classes standing on the floor
(:mod:`teamslam.sim.shapes`), rendered by a vectorised ray caster (OpenCV's pixel-centre
convention, trilinear mip-mapping) with vignetting, a right-camera gain and offset, sensor noise
and JPEG compression. Images are grey without objects and BGR colour with them.
:meth:`TexturedRoom.cast` gives the exact 3D point behind any pixel, and
:meth:`TexturedRoom.render_ids` which object each pixel shows. :func:`render_team` writes per
robot the left and right images, ``camera.yaml``, ``timestamps.txt``, ``groundtruth.tum`` and
``odometry.tum``, plus ``markers.txt``, ``render.json`` and, with objects, ``objects.txt`` and
``classes.txt`` (and a simulated detector's boxes, :mod:`teamslam.sim.detector`).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from teamslam.datasets.trajectory import write_tum
from teamslam.errors import InputError
from teamslam.frontend._cv import require_cv2
from teamslam.geometry import se3
from teamslam.geometry.camera import StereoCamera
from teamslam.sim.detector import DetectorConfig, detect, write_truth, write_yolo
from teamslam.sim.shapes import (
    BOX,
    SHAPE_CLASSES,
    Shapes,
    draw_instances,
    intersect,
    place,
    shape_texture,
)

__all__ = [
    "T_CAM_BODY",
    "RenderConfig",
    "RenderedTeam",
    "TexturedRoom",
    "apply_effects",
    "render_size",
    "render_stereo",
    "render_team",
    "robot_paths",
    "street_loop_length",
    "write_camera_file",
]

# body x forward, y left, z up  ->  optical x right, y down, z forward
T_CAM_BODY = np.array(
    [[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)

_ARUCO_DICTIONARIES = {
    "4x4_250": "DICT_4X4_250",
    "5x5_250": "DICT_5X5_250",
    "6x6_250": "DICT_6X6_250",
    "apriltag_36h11": "DICT_APRILTAG_36h11",
}


@dataclass(frozen=True)
class RenderConfig:
    """Every setting of the rendered world, the robots and the cameras.

    Attributes
    ----------
    robots, steps, seed
        Team size, motion steps per robot (``steps + 1`` frames), random seed.
    room
        Room extent ``(x, y, z)`` in metres; the room spans ``[0, x] × [0, y] × [0, z]``.
    texel
        Size of one texel of the surface textures at full resolution, metres.
    markers_per_wall, marker_size, marker_heights
        Markers on each wall (0: none), their side (black border included, metres), and the
        heights of their centres (cycled).
    dictionary
        ArUco dictionary: ``4x4_250``, ``5x5_250``, ``6x6_250`` or ``apriltag_36h11``.
    image_size, focal, baseline
        ``(width, height)`` pixels, focal length (pixels; principal point at the image
        centre), stereo baseline (m).
    camera_height, step_length, rate
        Height of the camera above the floor (m), distance per step (m), frames per second.
    wall_margin
        Closest distance of a path to a wall, metres.
    odometry_translation_noise, odometry_rotation_noise
        Per-axis std of the SE(3) odometry noise per step (m, rad).
    vignetting
        Share of the cos⁴ fall-off applied (0: none, 1: the full natural fall-off).
    right_gain, right_offset
        Gain and offset (grey levels) of the right camera relative to the left.
    pixel_noise
        Std of the sensor noise, grey levels.
    jpeg_quality
        JPEG quality the images pass through (``None``: no compression).
    layout
        ``room``: the closed room ``room`` that robots circle in; ``street``: a street
        ``street`` long and wide (the height of ``room``) that robots drive round in a loop,
        up one lane and down the other, spread evenly along the loop, so each robot reaches
        what the robot ahead of it mapped earlier.
    street
        Length (x) and width (y) of the street, metres.
    street_rooms
        Rooms the street is split into, in sequence, by cross walls (at equal spacing) with a
        doorway each that both lanes pass through; the walls hide the rooms from each other.
    doorway
        Width and height of the doorways, metres (centred on the street's axis).
    objects
        ``none`` or ``shapes``: textured objects of the classes of
        :data:`teamslam.sim.shapes.SHAPE_CLASSES` (images then in colour).
    object_count
        Number of objects (``None``: one per metre of street, 12 in the room).
    lookalikes
        Probability that an object copies an earlier one of its class (nearly the same colour,
        the same texture and size).
    object_clearance
        Closest distance between an object's footprint and a robot's path, metres.
    """

    robots: int = 3
    steps: int = 200
    seed: int = 0
    room: tuple[float, float, float] = (16.0, 12.0, 3.0)
    texel: float = 0.01
    markers_per_wall: int = 5
    marker_size: float = 0.5
    marker_heights: tuple[float, ...] = (1.2, 1.8)
    dictionary: str = "4x4_250"
    image_size: tuple[int, int] = (640, 480)
    focal: float = 420.0
    baseline: float = 0.2
    camera_height: float = 1.0
    step_length: float = 0.08
    rate: float = 10.0
    wall_margin: float = 2.0
    odometry_translation_noise: float = 0.004
    odometry_rotation_noise: float = 0.002
    vignetting: float = 0.5
    right_gain: float = 0.9
    right_offset: float = 6.0
    pixel_noise: float = 1.0
    jpeg_quality: int | None = 75
    layout: str = "room"
    street: tuple[float, float] = (20.0, 6.0)
    street_rooms: int = 3
    doorway: tuple[float, float] = (3.0, 2.2)
    objects: str = "none"
    object_count: int | None = None
    lookalikes: float = 0.25
    object_clearance: float = 0.6

    def __post_init__(self) -> None:
        if self.robots < 1 or self.steps < 1:
            raise InputError("robots and steps must be positive")
        if self.layout not in ("room", "street"):
            raise InputError(f"layout {self.layout!r} unknown; use room or street")
        if min(self.room) <= 0 or 2 * self.wall_margin >= min(self.room[:2]):
            raise InputError("room must be positive and wider than twice wall_margin")
        if self.layout == "street":
            length, width = self.street
            if width < 3.0 or length < 2 * self.wall_margin + 0.25 * width + 1.0:
                raise InputError(
                    "street must be at least 3 m wide and 1 m longer than its turns "
                    "(2 wall_margin + a quarter of its width)"
                )
        if self.layout == "street":
            length, width = self.street
            lane = 0.12 * width
            if self.street_rooms < 1 or length / self.street_rooms < self.wall_margin + lane + 0.5:
                raise InputError(
                    "street_rooms must be ≥ 1, and each room longer than the turns at the "
                    "street's ends (wall_margin + 0.12 width + 0.5 m)"
                )
            door_w, door_h = self.doorway
            if not 2 * lane + 0.5 <= door_w <= width or not self.camera_height < door_h:
                raise InputError(
                    "doorway must be wider than both lanes (0.24 width + 0.5 m), at most the "
                    "street's width, and higher than the camera"
                )
        if self.markers_per_wall < 0:
            raise InputError("markers_per_wall must be ≥ 0")
        if self.objects not in ("none", "shapes"):
            raise InputError(f"objects {self.objects!r} unknown; use none or shapes")
        if self.object_count is not None and self.object_count < 0:
            raise InputError("object_count must be ≥ 0")
        if not 0.0 <= self.lookalikes <= 1.0 or self.object_clearance < 0:
            raise InputError("lookalikes must lie in [0, 1], object_clearance be ≥ 0")
        if self.dictionary not in _ARUCO_DICTIONARIES:
            raise InputError(
                f"dictionary {self.dictionary!r} unknown; use one of "
                + ", ".join(_ARUCO_DICTIONARIES)
            )
        if self.focal <= 0 or self.baseline <= 0 or min(self.image_size) < 16:
            raise InputError("focal and baseline must be positive, images at least 16 px")
        if not 0 < self.camera_height < self.room[2]:
            raise InputError("camera_height must lie between floor and ceiling")
        if self.jpeg_quality is not None and not 1 <= self.jpeg_quality <= 100:
            raise InputError("jpeg_quality must lie in 1..100")

    @property
    def extent(self) -> tuple[float, float, float]:
        """The world's box ``(x, y, z)``, metres: the room, or the street and the room's
        height."""
        if self.layout == "street":
            return (float(self.street[0]), float(self.street[1]), self.room[2])
        return self.room

    @property
    def partitions(self) -> np.ndarray:
        """``(P,)`` x of the street's cross walls (none in the room)."""
        if self.layout != "street":
            return np.zeros(0)
        return self.street[0] * np.arange(1, self.street_rooms) / self.street_rooms

    @property
    def shape_count(self) -> int:
        """Number of objects rendered."""
        if self.objects == "none":
            return 0
        if self.object_count is not None:
            return self.object_count
        return round(self.street[0]) if self.layout == "street" else 12

    def camera(self) -> StereoCamera:
        """The rectified stereo camera (pixels)."""
        w, h = self.image_size
        return StereoCamera.from_baseline(
            self.focal, self.focal, (w - 1) / 2.0, (h - 1) / 2.0, self.baseline
        )


def _fractal_noise(rng: np.random.Generator, n: int, beta: float, cutoff: float) -> np.ndarray:
    """Tileable ``n × n`` noise with a ``1/f^beta`` spectrum, band-limited at ``cutoff`` cycles
    per texel; zero mean, unit std."""
    f = np.fft.fftfreq(n)
    fr = np.fft.rfftfreq(n)
    radius = np.hypot(f[:, None], fr[None, :])
    radius[0, 0] = 1.0
    gain = radius**-beta * np.exp(-((radius / cutoff) ** 2))
    gain[0, 0] = 0.0
    spectrum = np.fft.rfft2(rng.standard_normal((n, n))) * gain
    out = np.fft.irfft2(spectrum, s=(n, n))
    return (out - out.mean()) / out.std()


def _gravel(rng: np.random.Generator, n: int) -> np.ndarray:
    noise = _fractal_noise(rng, n, 1.0, 0.12)
    return 0.5 + 0.3 * np.tanh(1.5 * noise)


def _bricks(rng: np.random.Generator, n: int, texel: float) -> np.ndarray:
    """Bricks ``0.5 × 0.25`` m (rows staggered), mortar 1.5 cm, per-brick albedo and grain."""
    rows = np.arange(n) * texel
    brick_h, brick_w, mortar = 0.25, 0.5, 0.015
    row_index = np.floor(rows / brick_h).astype(int)
    y_in = rows - row_index * brick_h
    cols = np.arange(n) * texel
    shift = (row_index % 2)[:, None] * brick_w / 2
    x = cols[None, :] + shift
    col_index = np.floor(x / brick_w).astype(int)
    x_in = x - col_index * brick_w
    n_rows = int(np.ceil(n * texel / brick_h)) + 1
    n_cols = int(np.ceil(n * texel / brick_w)) + 2
    albedo = rng.uniform(0.35, 0.8, (n_rows, n_cols))
    brick = albedo[row_index[:, None] % n_rows, col_index % n_cols]
    is_mortar = (y_in[:, None] < mortar) | (x_in < mortar)
    grain = 0.12 * np.tanh(_fractal_noise(rng, n, 1.0, 0.15))
    return np.where(is_mortar, 0.2 + 0.5 * grain, brick + grain)


@dataclass
class _MipTextures:
    """Square power-of-two textures with their mip pyramids, stored flat for vector lookups."""

    data: np.ndarray = field(default_factory=lambda: np.zeros(0, np.float32))
    offsets: list[np.ndarray] = field(default_factory=list)
    sizes: list[np.ndarray] = field(default_factory=list)
    texels: list[float] = field(default_factory=list)

    def add(self, image: np.ndarray, texel: float) -> int:
        levels = [np.asarray(image, dtype=np.float32)]
        while levels[-1].shape[0] > 4:
            a = levels[-1]
            levels.append(0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2]))
        start = self.data.size
        offs, sizes = [], []
        for lv in levels:
            offs.append(start)
            sizes.append(lv.shape[0])
            start += lv.size
        self.data = np.concatenate([self.data, *[lv.ravel() for lv in levels]])
        self.offsets.append(np.array(offs, np.int64))
        self.sizes.append(np.array(sizes, np.int64))
        self.texels.append(texel)
        return len(self.texels) - 1

    def finish(self) -> None:
        depth = max(len(o) for o in self.offsets)
        self._off = np.zeros((len(self.offsets), depth), np.int64)
        self._size = np.ones((len(self.offsets), depth), np.int64)
        self._levels = np.array([len(o) for o in self.offsets])
        for i, (o, s) in enumerate(zip(self.offsets, self.sizes, strict=True)):
            self._off[i, : len(o)], self._size[i, : len(s)] = o, s
            self._off[i, len(o) :], self._size[i, len(s) :] = o[-1], s[-1]
        # 32-bit texel indices while they fit: the lookups are memory-bound
        index = np.int32 if self.data.size < 2**31 else np.int64
        self._off, self._size = self._off.astype(index), self._size.astype(index)
        self._texel = np.array(self.texels)
        self._scale = np.exp2(-np.arange(depth)).astype(np.float32)

    def sample(self, tex: np.ndarray, a: np.ndarray, b: np.ndarray, footprint: np.ndarray):
        """Trilinear sample of textures ``tex`` at surface coordinates ``(a, b)`` (metres,
        ``a`` along columns, ``b`` along rows) for a pixel footprint (metres); wraps."""
        inv_texel = (1.0 / self._texel[tex]).astype(np.float32)
        x0, y0 = a * inv_texel, b * inv_texel
        level = np.log2(np.maximum(footprint * inv_texel, np.float32(1.0)))
        top = self._levels[tex] - 1
        level = np.minimum(level, top)
        l0 = level.astype(np.int32)
        l1 = np.minimum(l0 + 1, top)
        w = level - l0
        return (1 - w) * self._bilinear(tex, l0, x0, y0) + w * self._bilinear(tex, l1, x0, y0)

    def _bilinear(self, tex, level, x0, y0):
        scale = self._scale[level]
        mask = self._size[tex, level] - 1  # sizes are powers of two: wrap with a bit mask
        off = self._off[tex, level]
        x = x0 * scale - np.float32(0.5)
        y = y0 * scale - np.float32(0.5)
        xf, yf = np.floor(x), np.floor(y)
        fx, fy = x - xf, y - yf
        xi, yi = xf.astype(mask.dtype) & mask, yf.astype(mask.dtype) & mask
        xj, yj = (xi + 1) & mask, (yi + 1) & mask
        row_i = off + yi * (mask + 1)
        row_j = off + yj * (mask + 1)
        d = self.data
        a, b = np.take(d, row_i + xi), np.take(d, row_i + xj)
        c, e = np.take(d, row_j + xi), np.take(d, row_j + xj)
        top = a + fx * (b - a)
        bottom = c + fx * (e - c)
        return top + fy * (bottom - top)


class TexturedRoom:
    """The rendered world: a textured room (or street) with ArUco markers on its walls and
    optionally textured objects on its floor.

    Surfaces: 0 floor, 1 ceiling, 2 wall ``x = 0``, 3 wall ``x = X``, 4 wall ``y = 0``,
    5 wall ``y = Y``. Each surface has an origin and two in-plane axes (``a`` along texture
    columns, ``b`` along rows); on walls ``a`` points to the right and ``b`` down as seen from
    inside the room, so markers read correctly (not mirrored).

    Attributes
    ----------
    marker_ids, marker_centres, marker_corners
        ``(M,)`` ids, ``(M, 3)`` world centres and ``(M, 4, 3)`` world corners in ArUco's
        order (top-left, top-right, bottom-right, bottom-left) of the black square.
    shapes
        The objects (:class:`teamslam.sim.shapes.Shapes`; ids follow the markers' ids).

    Parameters
    ----------
    config
        The world's settings.
    shapes
        Objects to stand in the world instead of those ``config`` places (their textures are
        drawn here; ``textures`` is overwritten).
    """

    def __init__(self, config: RenderConfig, shapes: Shapes | None = None) -> None:
        cv2 = require_cv2("rendering images")
        self.config = config
        rng = np.random.default_rng(np.random.SeedSequence([config.seed, 29]))
        X, Y, Z = config.extent
        self.size = np.array(config.extent)
        # origin, a axis, b axis, per surface
        self._frames = np.array(
            [
                [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
                [[0, 0, Z], [1, 0, 0], [0, 1, 0]],
                [[0, 0, Z], [0, 1, 0], [0, 0, -1]],
                [[X, Y, Z], [0, -1, 0], [0, 0, -1]],
                [[X, 0, Z], [-1, 0, 0], [0, 0, -1]],
                [[0, Y, Z], [1, 0, 0], [0, 0, -1]],
            ],
            dtype=float,
        )
        n = 1024
        self._textures = _MipTextures()
        self._textures.add(_gravel(rng, n), config.texel)
        self._textures.add(0.15 + 0.7 * _gravel(rng, n), config.texel)
        for _ in range(4):
            self._textures.add(_bricks(rng, n, config.texel), config.texel)
        # markers
        dictionary = cv2.aruco.getPredefinedDictionary(
            getattr(cv2.aruco, _ARUCO_DICTIONARIES[config.dictionary])
        )
        bits = dictionary.markerSize + 2
        cell = 32
        ids, centres, surface, ab, corners = [], [], [], [], []
        marker_tex = []
        next_id = 0
        for wall in range(2, 6):
            length = Y if wall in (2, 3) else X
            for j in range(config.markers_per_wall):
                a = length * (j + 0.5) / config.markers_per_wall
                height = config.marker_heights[(j + wall) % len(config.marker_heights)]
                b = Z - height
                img = cv2.aruco.generateImageMarker(dictionary, next_id, bits * cell)
                quad = np.pad(img, cell, constant_values=255).astype(np.float32)
                quad = cv2.resize(quad, (256, 256), interpolation=cv2.INTER_AREA)
                quad = 0.05 + 0.9 * quad / 255.0
                texel = config.marker_size * (bits + 2) / bits / 256
                marker_tex.append(self._textures.add(quad, texel))
                o, ax, bx = self._frames[wall]
                centre = o + a * ax + b * bx
                h = config.marker_size / 2
                corners.append(
                    [
                        centre - h * ax - h * bx,
                        centre + h * ax - h * bx,
                        centre + h * ax + h * bx,
                        centre - h * ax + h * bx,
                    ]
                )
                ids.append(next_id)
                centres.append(centre)
                surface.append(wall)
                ab.append((a, b))
                next_id += 1
        if shapes is None:
            shapes = _place_shapes(config, next_id)
        self.shapes = shapes
        self._add_shape_textures(config)
        self._textures.finish()
        self.marker_ids = np.array(ids, np.int64)
        self.marker_centres = np.array(centres).reshape(-1, 3)
        self.marker_corners = np.array(corners).reshape(-1, 4, 3)
        self._marker_surface = np.array(surface, np.int64)
        self._marker_ab = np.array(ab).reshape(-1, 2)
        self._marker_tex = np.array(marker_tex, np.int64)
        self._marker_half = config.marker_size * (bits + 2) / bits / 2
        self._per_wall = config.markers_per_wall
        self._marker_at = np.zeros((6, max(self._per_wall, 1)), np.int64)
        for m, wall in enumerate(surface):
            self._marker_at[wall, m % self._per_wall] = m
        self._wall_length = np.array([X, X, Y, Y, X, X], np.float32)
        self._marker_ab32 = self._marker_ab.astype(np.float32)
        # the street's cross walls: surfaces 6, 7, …, textured with the walls' bricks
        self.partitions = config.partitions
        self._door = (Y / 2, config.doorway[0] / 2, config.doorway[1])
        cross = [[[x, 0, Z], [0, 1, 0], [0, 0, -1]] for x in self.partitions]
        self._frames = np.concatenate([self._frames, np.reshape(cross, (-1, 3, 3))])
        self._surface_tex = np.concatenate(
            [np.arange(6), 2 + np.arange(len(self.partitions)) % 4]
        ).astype(np.int64)
        self._frames32 = self._frames.astype(np.float32)
        self._normals = np.cross(self._frames[:, 1], self._frames[:, 2]).astype(np.float32)
        self._ray_cache = None

    # -- geometry ------------------------------------------------------------------------
    def _intersect(self, origin: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distances ``t`` (along ``d``) to the first wall hit and the surface index."""
        ts = []
        for axis in range(3):
            di = d[:, axis]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.where(di > 0, (self.size[axis] - origin[axis]) / di, -origin[axis] / di)
            ts.append(np.where(di == 0, np.inf, t))
        t_all = np.stack(ts, axis=1)
        axis = np.argmin(t_all, axis=1)
        t = t_all[np.arange(len(axis)), axis]
        positive = d[np.arange(len(axis)), axis] > 0
        # axis 2 -> floor (0) / ceiling (1); axis 0 -> walls 2/3; axis 1 -> walls 4/5
        surface = np.choose(axis, [2, 4, 0]) + positive
        return t, surface

    def _cross_walls(self, origin, d, t, surface):
        """``t`` and ``surface`` where a ray meets a cross wall (outside its doorway) first."""
        centre, half_width, height = self._door
        for i, x in enumerate(self.partitions):
            with np.errstate(divide="ignore", invalid="ignore"):
                ti = (x - origin[0]) / d[:, 0]
                y = origin[1] + ti * d[:, 1]
                z = origin[2] + ti * d[:, 2]
            door = (np.abs(y - centre) < half_width) & (z < height)
            closer = (ti > 0) & (ti < t) & ~door
            t = np.where(closer, ti, t)
            surface = np.where(closer, 6 + i, surface)
        return t, surface

    def _rays(self, T_world_cam: np.ndarray, K: np.ndarray, uv: np.ndarray) -> np.ndarray:
        pix = np.column_stack([uv, np.ones(len(uv))])
        d_cam = np.linalg.solve(K, pix.T).T  # z = 1: t is the depth
        return d_cam @ T_world_cam[:3, :3].T

    def cast(self, T_world_cam: np.ndarray, K: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """The world points seen at pixels ``uv`` ``(N, 2)`` by a camera at ``T_world_cam``."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        origin = T_world_cam[:3, 3]
        d = self._rays(T_world_cam, K, uv)
        t, surface = self._intersect(origin, d)
        t, _ = self._cross_walls(origin, d, t, surface)
        for j in range(len(self.shapes)):
            t = np.minimum(t, intersect(self.shapes, j, origin, d)[0])
        return origin + t[:, None] * d

    def render(self, T_world_cam: np.ndarray, K: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """The albedo image seen from ``T_world_cam``, float32 in [0, 1]: ``(height, width)``
        grey without objects, ``(height, width, 3)`` BGR with them."""
        return self.render_ids(T_world_cam, K, size)[0]

    def render_ids(
        self, T_world_cam: np.ndarray, K: np.ndarray, size: tuple[int, int]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The albedo image (as :meth:`render`), which object each pixel shows and how many
        pixels each object would cover unoccluded.

        Returns
        -------
        image
            As :meth:`render`.
        ids
            ``(height, width)`` int32: the index into :attr:`shapes` of the object a pixel
            shows, ``-1`` for the room.
        silhouette
            ``(K,)`` pixels of the image each object covers when the other objects are ignored.
        """
        w, h = size
        key = (w, h, *np.asarray(K, float).ravel().tolist())
        if self._ray_cache is None or self._ray_cache[0] != key:
            jj, ii = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
            d_cam = self._rays(np.eye(4), K, np.column_stack([jj.ravel(), ii.ravel()]))
            self._ray_cache = (key, d_cam, np.linalg.norm(d_cam, axis=1).astype(np.float32))
        _, d_cam, d_norm = self._ray_cache
        origin = T_world_cam[:3, 3]
        d = d_cam @ T_world_cam[:3, :3].T
        t, surface = self._intersect(origin, d)
        if len(self.partitions):
            t, surface = self._cross_walls(origin, d, t, surface)
        p = (origin + t[:, None] * d).astype(np.float32)
        frames = self._frames32[surface]
        rel = p - frames[:, 0]
        a = np.einsum("ij,ij->i", rel, frames[:, 1])
        b = np.einsum("ij,ij->i", rel, frames[:, 2])
        dist = t.astype(np.float32) * d_norm
        cos_inc = np.abs(np.einsum("ij,ij->i", d.astype(np.float32), self._normals[surface]))
        cos_inc /= d_norm
        footprint = dist / np.float32(K[0, 0]) / np.sqrt(np.maximum(cos_inc, np.float32(0.05)))
        tex = surface.copy() if not len(self.partitions) else self._surface_tex[surface]
        if self._per_wall > 0:
            # markers: evenly spaced along each wall, so the candidate marker is found
            # arithmetically
            wall = np.flatnonzero((surface >= 2) & (surface < 6))
            sw = surface[wall]
            slot = np.clip(
                (a[wall] / self._wall_length[sw] * self._per_wall).astype(np.int64),
                0,
                self._per_wall - 1,
            )
            m = self._marker_at[sw, slot]
            da = a[wall] - self._marker_ab32[m, 0]
            db = b[wall] - self._marker_ab32[m, 1]
            half = np.float32(self._marker_half)
            hit = (np.abs(da) < half) & (np.abs(db) < half)
            idx = wall[hit]
            tex[idx] = self._marker_tex[m[hit]]
            a[idx] = da[hit] + half
            b[idx] = db[hit] + half
        image = self._textures.sample(tex, a, b, footprint)
        ids = np.full(w * h, -1, np.int32)
        silhouette = np.zeros(len(self.shapes), np.int64)
        if not len(self.shapes):
            return image.reshape(h, w), ids.reshape(h, w), silhouette
        # objects: each tested only on the pixels inside its projected bounding box
        normal = np.zeros((w * h, 3))
        a_obj, b_obj = np.zeros(w * h), np.zeros(w * h)
        t_obj = t.copy()
        for j, sel in self._object_pixels(T_world_cam, K, w, h):
            tj, nj, aj, bj = intersect(self.shapes, j, origin, d[sel])
            silhouette[j] = np.count_nonzero(np.isfinite(tj))
            closer = tj < t_obj[sel]
            px = sel[closer]
            t_obj[px], ids[px], normal[px] = tj[closer], j, nj[closer]
            a_obj[px], b_obj[px] = aj[closer], bj[closer]
        colour = np.repeat(image[:, None], 3, axis=1)
        px = np.flatnonzero(ids >= 0)
        obj = ids[px]
        dist = (t_obj[px] * d_norm[px]).astype(np.float32)
        cos_inc = np.abs(np.einsum("ij,ij->i", d[px], normal[px])).astype(np.float32)
        cos_inc /= d_norm[px]
        footprint = dist / np.float32(K[0, 0]) / np.sqrt(np.maximum(cos_inc, np.float32(0.05)))
        grey = self._textures.sample(
            self.shapes.textures[obj],
            a_obj[px].astype(np.float32),
            b_obj[px].astype(np.float32),
            footprint,
        )
        shade = 0.6 + 0.4 * np.maximum(normal[px] @ _LIGHT, 0.0)
        colour[px] = (grey * shade)[:, None] * self.shapes.colours[obj]
        return colour.reshape(h, w, 3).astype(np.float32), ids.reshape(h, w), silhouette

    def _object_pixels(self, T_world_cam: np.ndarray, K: np.ndarray, w: int, h: int):
        """``(object index, flat pixel indices)`` of each object that may be in view: the
        pixels inside the projection of its bounding box (every pixel when the box crosses
        the camera's plane)."""
        R, o = T_world_cam[:3, :3], T_world_cam[:3, 3]
        corners = (self._shape_corners - o) @ R  # camera frame
        depth = corners[..., 2]
        every = np.arange(w * h)
        for j in range(len(self.shapes)):
            if np.all(depth[j] <= 1e-9):
                continue
            if np.any(depth[j] <= 1e-9):
                yield j, every
                continue
            uv = corners[j] @ np.asarray(K, float).T
            u, v = uv[:, 0] / uv[:, 2], uv[:, 1] / uv[:, 2]
            c0, c1 = max(int(np.floor(u.min())) - 1, 0), min(int(np.ceil(u.max())) + 1, w - 1)
            r0, r1 = max(int(np.floor(v.min())) - 1, 0), min(int(np.ceil(v.max())) + 1, h - 1)
            if c0 > c1 or r0 > r1:
                continue
            yield j, (np.arange(r0, r1 + 1)[:, None] * w + np.arange(c0, c1 + 1)).ravel()

    def _add_shape_textures(self, config: RenderConfig) -> None:
        """One texture per distinct texture seed (look-alikes share their original's)."""
        shapes = self.shapes
        shapes.textures = np.zeros(len(shapes), np.int64)
        made: dict[tuple[int, int], int] = {}
        for j in range(len(shapes)):
            source = j if shapes.lookalike_of[j] < 0 else int(shapes.lookalike_of[j])
            key = (int(shapes.classes[j]), source)
            if key not in made:
                family = SHAPE_CLASSES[shapes.classes[j]].texture
                seed = [config.seed, 35, source]
                made[key] = self._textures.add(
                    shape_texture(family, np.random.SeedSequence(seed), 256, _SHAPE_TEXEL),
                    _SHAPE_TEXEL,
                )
            shapes.textures[j] = made[key]
        self._shape_corners = shapes.bounding_corners()


_LIGHT = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
_SHAPE_TEXEL = 0.005


def _place_shapes(config: RenderConfig, first_id: int) -> Shapes:
    """The objects ``config`` asks for, standing on the floor clear of the robots' paths."""
    count = config.shape_count
    if count == 0:
        return Shapes.empty()
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 34]))
    classes, sizes, colours, source = draw_instances(rng, count, config.lookalikes)
    kinds = np.array([SHAPE_CLASSES[c].kind for c in classes], np.int64)
    yaws = np.where(kinds == BOX, rng.uniform(0, np.pi, count), 0.0)
    shapes = Shapes(
        ids=first_id + np.arange(count, dtype=np.int64),
        classes=classes,
        kinds=kinds,
        centres=np.zeros((count, 3)),
        sizes=sizes,
        yaws=yaws,
        colours=colours,
        textures=np.zeros(count, np.int64),
        lookalike_of=source,
    )
    X, Y, _ = config.extent
    # clear of the robots' whole loops, not only of the part driven: a longer or shorter
    # drive keeps the same world
    whole = replace(
        config, steps=max(config.steps, int(2 * np.pi * max(X, Y) / config.step_length))
    )
    paths_xy = np.concatenate([p[:, :2, 3] for p in robot_paths(whole)])
    edge = 0.1  # closest gap to a wall
    slots = (rng.permutation(count) + 0.5) / count * X  # street: spaced along its length

    def candidate(rng: np.random.Generator, j: int, r: float) -> tuple[float, float]:
        if config.layout == "street":
            x = float(np.clip(slots[j] + rng.normal(0.0, 0.4), r + edge, X - r - edge))
        else:
            x = rng.uniform(r + edge, X - r - edge)
        return x, rng.uniform(r + edge, Y - r - edge)

    def clear(p: np.ndarray, r: float) -> bool:
        return bool(np.all(np.abs(p[0] - config.partitions) > r + edge))

    xy = place(rng, shapes.footprint_radius(), candidate, paths_xy, config.object_clearance, clear)
    shapes.centres = np.column_stack([xy, sizes[:, 2] / 2])
    keep = np.flatnonzero(np.isfinite(xy[:, 0]))
    new_index = np.full(count + 1, -1, np.int64)  # the last entry maps -1 to -1
    new_index[keep] = np.arange(len(keep))
    return Shapes(
        ids=first_id + np.arange(len(keep), dtype=np.int64),
        classes=classes[keep],
        kinds=kinds[keep],
        centres=shapes.centres[keep],
        sizes=sizes[keep],
        yaws=yaws[keep],
        colours=colours[keep],
        textures=np.zeros(len(keep), np.int64),
        lookalike_of=new_index[source[keep]],
    )


def apply_effects(
    albedo: np.ndarray,
    K: np.ndarray,
    config: RenderConfig,
    right: bool,
    rng: np.random.Generator,
) -> np.ndarray:
    """Turn an albedo image (grey ``(h, w)`` or BGR ``(h, w, 3)``) into a camera's 8-bit image
    of the same shape: vignetting, gain/offset (right camera), sensor noise (independent per
    channel), JPEG compression."""
    h, w = albedo.shape[:2]
    x = (np.arange(w) - K[0, 2]) / K[0, 0]
    y = (np.arange(h) - K[1, 2]) / K[1, 1]
    cos4 = 1.0 / (1.0 + x[None, :] ** 2 + y[:, None] ** 2) ** 2
    vignette = 1.0 - config.vignetting * (1.0 - cos4)
    if albedo.ndim == 3:
        vignette = vignette[:, :, None]
    grey = 235.0 * albedo * vignette
    if right:
        grey = config.right_gain * grey + config.right_offset
    if config.pixel_noise > 0:
        grey = grey + config.pixel_noise * rng.standard_normal(grey.shape)
    img = np.clip(np.rint(grey), 0, 255).astype(np.uint8)
    if config.jpeg_quality is not None:
        cv2 = require_cv2("rendering images")
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(config.jpeg_quality)])
        if not ok:  # pragma: no cover - OpenCV always encodes an 8-bit image
            raise InputError("JPEG encoding failed")
        img = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE if img.ndim == 2 else cv2.IMREAD_COLOR)
    return img


def robot_paths(config: RenderConfig) -> list[np.ndarray]:
    """Per robot ``(steps + 1, 4, 4)`` true ``T_world_body`` at the camera height, heading along
    the path, with a little pitch and roll. Room: wavy ellipses around the room's centre.
    Street: one loop (up the lane ``y = W/2 - l``, a half turn of radius ``l = 0.12 W``, down
    the lane ``y = W/2 + l``, a half turn back) that robot ``k`` starts ``k / robots`` of the
    way round, so each robot follows the one ahead of it and the lanes' robots meet head-on."""
    if config.layout == "street":
        return _street_paths(config)
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 30]))
    X, Y, _ = config.room
    half = np.array([X / 2 - config.wall_margin, Y / 2 - config.wall_margin])
    paths = []
    for _ in range(config.robots):
        axes = half * rng.uniform(0.55, 0.9, 2) / 1.08  # the wobble below reaches 8 %
        centre = np.array([X / 2, Y / 2]) + (half - 1.08 * axes) * rng.uniform(-1, 1, 2)
        sense = rng.choice([-1.0, 1.0])
        phase = rng.uniform(0, 2 * np.pi)
        wobble_phase = rng.uniform(0, 2 * np.pi)
        s_fine = np.linspace(0.0, 2.0 * np.pi, 20_000)

        def xy(s, axes=axes, centre=centre, sense=sense, phase=phase, wp=wobble_phase):
            r = 1.0 + 0.08 * np.sin(3 * s + wp)
            ang = sense * s + phase
            return centre + (axes * r[:, None]) * np.column_stack([np.cos(ang), np.sin(ang)])

        p_fine = xy(s_fine)
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p_fine, axis=0), axis=1))])
        targets = (np.arange(config.steps + 1) * config.step_length) % arc[-1]
        s = np.interp(targets, arc, s_fine)
        ds = 1e-4
        pos = xy(s)
        vel = (xy(s + ds) - xy(s - ds)) / (2 * ds)
        yaw = np.arctan2(vel[:, 1], vel[:, 0])
        pitch = 0.03 * np.sin(2.3 * s + phase)
        roll = 0.02 * np.sin(3.1 * s + wobble_phase)
        paths.append(_poses(pos, yaw, pitch, roll, config.camera_height))
    return paths


def _poses(pos, yaw, pitch, roll, height) -> np.ndarray:
    """``T_world_body`` from planar positions, yaw, pitch and roll (``R = Rz Ry Rx``)."""
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    n = len(yaw)
    rz = np.zeros((n, 3, 3))
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1], rz[:, 2, 2] = cy, -sy, sy, cy, 1
    ry = np.zeros((n, 3, 3))
    ry[:, 0, 0], ry[:, 0, 2], ry[:, 2, 0], ry[:, 2, 2], ry[:, 1, 1] = cp, sp, -sp, cp, 1
    rx = np.zeros((n, 3, 3))
    rx[:, 1, 1], rx[:, 1, 2], rx[:, 2, 1], rx[:, 2, 2], rx[:, 0, 0] = cr, -sr, sr, cr, 1
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = rz @ ry @ rx
    poses[:, :2, 3] = pos
    poses[:, 2, 3] = height
    return poses


def street_loop(config: RenderConfig, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(N, 2)`` and headings ``(N,)`` at arc lengths ``s`` (metres, wrapped) along
    the street's loop (see :func:`robot_paths`)."""
    length, width = config.street
    lane = 0.12 * width
    x0, x1 = config.wall_margin + lane, length - config.wall_margin - lane
    straight, turn = x1 - x0, np.pi * lane
    s = np.asarray(s, float) % (2 * (straight + turn))
    pos = np.zeros((len(s), 2))
    heading = np.zeros(len(s))
    up = s < straight
    pos[up] = np.column_stack([x0 + s[up], np.full(up.sum(), width / 2 - lane)])
    far = (s >= straight) & (s < straight + turn)
    ang = (s[far] - straight) / lane
    pos[far] = np.column_stack([x1 + lane * np.sin(ang), width / 2 - lane * np.cos(ang)])
    heading[far] = ang
    down = (s >= straight + turn) & (s < 2 * straight + turn)
    pos[down] = np.column_stack(
        [x1 - (s[down] - straight - turn), np.full(down.sum(), width / 2 + lane)]
    )
    heading[down] = np.pi
    near = s >= 2 * straight + turn
    ang = (s[near] - 2 * straight - turn) / lane
    pos[near] = np.column_stack([x0 - lane * np.sin(ang), width / 2 + lane * np.cos(ang)])
    heading[near] = np.pi + ang
    return pos, heading


def street_loop_length(config: RenderConfig) -> float:
    """Length of the street's loop (:func:`street_loop`), metres."""
    length, width = config.street
    lane = 0.12 * width
    return float(2 * (length - 2 * config.wall_margin - 2 * lane) + 2 * np.pi * lane)


def _street_paths(config: RenderConfig) -> list[np.ndarray]:
    lane = 0.12 * config.street[1]
    loop = street_loop_length(config)
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 30]))
    paths = []
    for k in range(config.robots):
        s = k * loop / config.robots + np.arange(config.steps + 1) * config.step_length
        pos, yaw = street_loop(config, s)
        phase, wobble_phase = rng.uniform(0, 2 * np.pi, 2)
        pitch = 0.03 * np.sin(2.3 * s / lane + phase)
        roll = 0.02 * np.sin(3.1 * s / lane + wobble_phase)
        paths.append(_poses(pos, yaw, pitch, roll, config.camera_height))
    return paths


def write_camera_file(
    path: str | Path,
    camera: StereoCamera,
    image_size: tuple[int, int],
    T_cam_body: np.ndarray | None = None,
    distortion: tuple[np.ndarray, np.ndarray] | None = None,
    intrinsics_right: np.ndarray | None = None,
) -> None:
    """Write a stereo camera file (YAML) that :func:`teamslam.frontend.load_camera` reads.

    Keys: ``image_width``, ``image_height``, ``left`` / ``right`` (``K`` 3×3 and
    ``distortion``, OpenCV's ``k1 k2 p1 p2 [k3]``), ``T_left_right`` (pose of the right camera
    in the left camera frame, 4×4), optional ``T_cam_body`` (4×4).
    """
    import yaml

    d_left, d_right = distortion if distortion is not None else (np.zeros(5), np.zeros(5))
    k_right = camera.intrinsics if intrinsics_right is None else intrinsics_right
    data = {
        "image_width": int(image_size[0]),
        "image_height": int(image_size[1]),
        "left": {"K": camera.intrinsics.tolist(), "distortion": np.asarray(d_left).tolist()},
        "right": {"K": np.asarray(k_right).tolist(), "distortion": np.asarray(d_right).tolist()},
        "T_left_right": camera.T_left_right.tolist(),
    }
    if T_cam_body is not None:
        data["T_cam_body"] = np.asarray(T_cam_body).tolist()
    Path(path).write_text(yaml.safe_dump(data, sort_keys=False))


@dataclass
class RenderedTeam:
    """What :func:`render_team` wrote, with the exact truth.

    Attributes
    ----------
    directory
        The output directory (``None`` when nothing was written).
    room
        The world (for :meth:`TexturedRoom.cast`).
    paths, odometry
        Per robot true ``T_world_body`` ``(steps + 1, 4, 4)`` and noisy odometry
        ``(steps, 4, 4)`` (``T_{k+1} ≈ T_k · odometry[k]``).
    timestamps
        ``(steps + 1,)`` seconds.
    robot_dirs
        Per robot, the folder with ``left/``, ``right/``, ``camera.yaml``, …
    """

    directory: Path | None
    room: TexturedRoom
    paths: list[np.ndarray]
    odometry: list[np.ndarray]
    timestamps: np.ndarray
    robot_dirs: list[Path] = field(default_factory=list)

    @property
    def config(self) -> RenderConfig:
        """The configuration rendered."""
        return self.room.config

    def T_world_cam(self, robot: int, frame: int) -> np.ndarray:
        """True left-camera pose of ``robot`` at ``frame``."""
        return self.paths[robot][frame] @ se3.inverse(T_CAM_BODY)

    def project(self, robot: int, frame: int, points_world: np.ndarray) -> np.ndarray:
        """Exact stereo projections ``(N, 4)`` of world points in ``robot``'s frame ``frame``."""
        T_cam_world = se3.inverse(self.T_world_cam(robot, frame))
        p = np.asarray(points_world, dtype=float) @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
        return self.config.camera().project(p)

    def points_behind(self, robot: int, frame: int, uv_left: np.ndarray) -> np.ndarray:
        """The world points ``(N, 3)`` seen at left-image pixels ``uv_left`` (exact)."""
        K = self.config.camera().intrinsics
        return self.room.cast(self.T_world_cam(robot, frame), K, uv_left)

    def visible_markers(self, robot: int, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Markers wholly inside both images, in front of the camera and, in a world with
        objects or cross walls, not hidden by them (the centre and the corners, 10 % inwards,
        seen in both images): ``(ids, z (M, 4) true stereo centres, side (M,) shortest
        projected side in pixels over both images)``."""
        room, camera = self.room, self.config.camera()
        w, h = self.config.image_size
        corners = self.project(robot, frame, room.marker_corners.reshape(-1, 3)).reshape(-1, 4, 4)
        T_cam_world = se3.inverse(self.T_world_cam(robot, frame))
        depth = room.marker_corners.reshape(-1, 3) @ T_cam_world[2, :3] + T_cam_world[2, 3]
        front = (depth.reshape(-1, 4) > 0.1).all(axis=1)
        u, v = corners[..., 0::2], corners[..., 1::2]
        inside = ((u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)).all(axis=(1, 2))
        sides = []
        for cam in (0, 2):
            c = corners[..., cam : cam + 2]
            sides.append(np.linalg.norm(c - np.roll(c, 1, axis=1), axis=2).min(axis=1))
        side = np.minimum(*sides)
        keep = front & inside
        if len(room.shapes) or len(room.partitions):
            keep[keep] = self._unhidden(robot, frame, np.flatnonzero(keep))
        z = self.project(robot, frame, room.marker_centres)
        del camera
        return room.marker_ids[keep], z[keep], side[keep]

    def _unhidden(self, robot: int, frame: int, markers: np.ndarray) -> np.ndarray:
        """Whether each marker's centre and corners (10 % inwards) are seen in both images."""
        room = self.room
        centres = room.marker_centres[markers]
        points = centres[:, None] + 0.9 * (room.marker_corners[markers] - centres[:, None])
        points = np.concatenate([centres[:, None], points], axis=1).reshape(-1, 3)
        z = self.project(robot, frame, points)
        K = self.config.camera().intrinsics
        T_left = self.T_world_cam(robot, frame)
        T_right = T_left @ self.config.camera().T_left_right
        seen = np.ones(len(points), bool)
        for T, uv in ((T_left, z[:, :2]), (T_right, z[:, 2:])):
            seen &= np.linalg.norm(room.cast(T, K, uv) - points, axis=1) < 1e-6
        return seen.reshape(len(markers), 5).all(axis=1)


def render_stereo(
    room: TexturedRoom, T_world_cam: np.ndarray, rng: np.random.Generator, ids: bool = False
) -> tuple[np.ndarray, ...]:
    """The left and right 8-bit images of the rig whose left camera is at ``T_world_cam``; with
    ``ids`` also each image's object ids and silhouettes (:meth:`TexturedRoom.render_ids`):
    ``(left, right, ids_left, ids_right, silhouette_left, silhouette_right)``."""
    config = room.config
    camera = config.camera()
    K = camera.intrinsics
    albedo_l, ids_l, sil_l = room.render_ids(T_world_cam, K, config.image_size)
    left = apply_effects(albedo_l, K, config, False, rng)
    T_world_right = T_world_cam @ camera.T_left_right
    albedo_r, ids_r, sil_r = room.render_ids(T_world_right, K, config.image_size)
    right = apply_effects(albedo_r, K, config, True, rng)
    if ids:
        return left, right, ids_l, ids_r, sil_l, sil_r
    return left, right


def render_team(
    config: RenderConfig,
    out: str | Path | None = None,
    progress: bool = False,
    detector: DetectorConfig | None = None,
) -> RenderedTeam:
    """Render a team's stereo images (and write them as folders when ``out`` is given).

    Parameters
    ----------
    config
        World, team and camera settings.
    out
        Output directory (created); ``None`` renders nothing and returns only the truth.
    progress
        Show a progress bar.
    detector
        With objects in the world, also run this simulated detector on every left and right
        image and write per robot ``detections/`` and ``detections_right/`` (YOLO text,
        :func:`teamslam.sim.detector.write_yolo`) and, for evaluation, ``detections_truth/``
        and ``detections_right_truth/`` (the object id each box shows, ``-1`` for a false
        box, line by line).

    Returns
    -------
    RenderedTeam
        Paths, noisy odometry, timestamps and the world with its markers and objects.
    """
    cv2 = require_cv2("rendering images")
    from tqdm import tqdm

    room = TexturedRoom(config)
    if detector is not None and not len(room.shapes):
        raise InputError("the simulated detector needs objects (objects='shapes')")
    paths = robot_paths(config)
    timestamps = np.arange(config.steps + 1) / config.rate
    noise = np.random.SeedSequence([config.seed, 31]).spawn(config.robots)
    sigma = np.array([config.odometry_translation_noise] * 3 + [config.odometry_rotation_noise] * 3)
    odometry = []
    for i, path in enumerate(paths):
        rng = np.random.default_rng(noise[i])
        odo_true = se3.inverse(path[:-1]) @ path[1:]
        odometry.append(odo_true @ se3.exp(rng.standard_normal((config.steps, 6)) * sigma))
    team = RenderedTeam(None, room, paths, odometry, timestamps)
    if out is None:
        return team
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    camera = config.camera()
    (out / "render.json").write_text(json.dumps(_jsonable(asdict(config)), indent=2) + "\n")
    rows = np.column_stack([room.marker_ids, room.marker_centres])
    np.savetxt(out / "markers.txt", rows, fmt=["%d", "%.9f", "%.9f", "%.9f"], header="id x y z")
    if len(room.shapes):
        _write_objects(out, room.shapes)
    bar = tqdm(total=config.robots * (config.steps + 1), desc="rendering", disable=not progress)
    for i, path in enumerate(paths):
        rdir = out / f"robot_{i}"
        (rdir / "left").mkdir(parents=True, exist_ok=True)
        (rdir / "right").mkdir(parents=True, exist_ok=True)
        write_camera_file(rdir / "camera.yaml", camera, config.image_size, T_CAM_BODY)
        np.savetxt(rdir / "timestamps.txt", timestamps, fmt="%.6f")
        write_tum(rdir / "groundtruth.tum", path, timestamps)
        dead_reckoned = np.tile(path[0], (config.steps + 1, 1, 1))
        for k in range(config.steps):
            dead_reckoned[k + 1] = dead_reckoned[k] @ odometry[i][k]
        write_tum(rdir / "odometry.tum", dead_reckoned, timestamps)
        rng = np.random.default_rng(np.random.SeedSequence([config.seed, 32, i]))
        det_rng = np.random.default_rng(np.random.SeedSequence([config.seed, 33, i]))
        folders = ("detections", "detections_right", "detections_truth", "detections_right_truth")
        if detector is not None:
            for name in folders:
                (rdir / name).mkdir(exist_ok=True)
        for k in range(config.steps + 1):
            images = render_stereo(room, team.T_world_cam(i, k), rng, ids=detector is not None)
            cv2.imwrite(str(rdir / "left" / f"{k:06d}.png"), images[0])
            cv2.imwrite(str(rdir / "right" / f"{k:06d}.png"), images[1])
            if detector is not None:
                for side, suffix in ((0, ""), (1, "_right")):
                    found = detect(
                        detector,
                        images[2 + side],
                        images[4 + side],
                        room.shapes.classes,
                        len(SHAPE_CLASSES),
                        det_rng,
                    )
                    write_yolo(
                        rdir / f"detections{suffix}" / f"{k:06d}.txt",
                        found.detections,
                        config.image_size,
                    )
                    ids = np.where(found.truth >= 0, room.shapes.ids[found.truth], -1)
                    write_truth(rdir / f"detections{suffix}_truth" / f"{k:06d}.txt", ids)
            bar.update()
        team.robot_dirs.append(rdir)
    bar.close()
    team.directory = out
    return team


def _write_objects(out: Path, shapes: Shapes) -> None:
    """``objects.txt`` (``id class x y z``: each object's reference point, the centre of its
    bounding box) and ``classes.txt`` (``class name kind``)."""
    rows = np.column_stack([shapes.ids, shapes.classes, shapes.centres])
    np.savetxt(
        out / "objects.txt", rows, fmt=["%d", "%d", "%.9f", "%.9f", "%.9f"], header="id class x y z"
    )
    lines = [f"{c} {cls.name} {cls.kind_name}" for c, cls in enumerate(SHAPE_CLASSES)]
    (out / "classes.txt").write_text("# class name kind\n" + "\n".join(lines) + "\n")


def _jsonable(d: dict) -> dict:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def render_size(width: int | None) -> dict:
    """:class:`RenderConfig` fields for images ``width`` pixels wide (4:3, the same field of
    view; markers grown in small images so they stay detectable, ≥ 25 px); ``{}`` for ``None``.
    """
    if width is None:
        return {}
    default = RenderConfig()
    scale = width / default.image_size[0]
    return {
        "image_size": (width, round(default.image_size[1] * scale)),
        "focal": default.focal * scale,
        "marker_size": default.marker_size * max(1.0, 1.0 / scale) ** 0.85,
    }
