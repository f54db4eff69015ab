"""Textured objects standing in a rendered world: yawed boxes, vertical cylinders and cones.

Objects belong to classes (:data:`SHAPE_CLASSES`: a shape kind, a size range, a texture family
and a colour range); instances of a class differ in size, colour and texture, and a share of
them are look-alikes of another instance of their class (the same texture and size, a colour a
few percent off). :func:`place_objects` stands them on the floor away from the robots' paths and
from each other; :func:`intersect` gives, exactly and vectorised over rays, where a ray first
meets one object, with the surface normal and texture coordinates (metres) of that point.

An object's reference point (``centres``) is the centre of its axis-aligned bounding box in its
own frame: half its height above the floor, on its axis.
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass

import numpy as np

__all__ = [
    "BOX",
    "CONE",
    "CYLINDER",
    "SHAPE_CLASSES",
    "ShapeClass",
    "Shapes",
    "draw_instances",
    "intersect",
    "place",
    "shape_texture",
]

BOX, CYLINDER, CONE = 0, 1, 2
_KIND_NAMES = {BOX: "box", CYLINDER: "cylinder", CONE: "cone"}


@dataclass(frozen=True)
class ShapeClass:
    """One class of objects.

    Attributes
    ----------
    name, kind
        Class name; shape kind (:data:`BOX`, :data:`CYLINDER` or :data:`CONE`).
    size_low, size_high
        Ranges of ``(half length, half width, height)`` for boxes and ``(radius, radius,
        height)`` for cylinders and cones, metres (the second entry unused for round shapes).
    texture
        Texture family: ``planks``, ``panels``, ``bands``, ``speckle`` or ``stripes``.
    hue, saturation, value
        Ranges of the colour (HSV, each in ``[0, 1]``).
    """

    name: str
    kind: int
    size_low: tuple[float, float, float]
    size_high: tuple[float, float, float]
    texture: str
    hue: tuple[float, float]
    saturation: tuple[float, float]
    value: tuple[float, float]

    @property
    def kind_name(self) -> str:
        """``box``, ``cylinder`` or ``cone``."""
        return _KIND_NAMES[self.kind]


SHAPE_CLASSES: tuple[ShapeClass, ...] = (
    ShapeClass(
        "crate",
        BOX,
        (0.2, 0.2, 0.4),
        (0.35, 0.3, 0.7),
        "planks",
        (0.04, 0.12),
        (0.4, 0.7),
        (0.5, 0.85),
    ),
    ShapeClass(
        "cabinet",
        BOX,
        (0.2, 0.15, 1.2),
        (0.3, 0.25, 1.7),
        "panels",
        (0.5, 0.7),
        (0.1, 0.5),
        (0.45, 0.9),
    ),
    ShapeClass(
        "barrel",
        CYLINDER,
        (0.25, 0.25, 0.8),
        (0.33, 0.33, 1.1),
        "bands",
        (0.0, 1.0),
        (0.5, 0.9),
        (0.45, 0.9),
    ),
    ShapeClass(
        "bollard",
        CYLINDER,
        (0.08, 0.08, 0.9),
        (0.13, 0.13, 1.3),
        "speckle",
        (0.12, 0.2),
        (0.6, 0.95),
        (0.6, 0.95),
    ),
    ShapeClass(
        "cone",
        CONE,
        (0.18, 0.18, 0.5),
        (0.28, 0.28, 0.85),
        "stripes",
        (0.0, 0.08),
        (0.7, 1.0),
        (0.7, 1.0),
    ),
)


@dataclass
class Shapes:
    """The objects of a world (arrays indexed by object).

    Attributes
    ----------
    ids, classes, kinds
        ``(K,)`` object ids, class indices into :data:`SHAPE_CLASSES`, shape kinds.
    centres
        ``(K, 3)`` world reference points: the centre of each object's bounding box.
    sizes
        ``(K, 3)`` ``(half length, half width, height)`` for boxes, ``(radius, radius, height)``
        for cylinders and cones (metres).
    yaws
        ``(K,)`` rotation of boxes about the vertical axis (rad; 0 for round shapes).
    colours
        ``(K, 3)`` BGR colour in ``[0, 1]``.
    textures
        ``(K,)`` texture index of each object (assigned by the renderer).
    lookalike_of
        ``(K,)`` the object a look-alike copies (index), ``-1`` for an original.
    """

    ids: np.ndarray
    classes: np.ndarray
    kinds: np.ndarray
    centres: np.ndarray
    sizes: np.ndarray
    yaws: np.ndarray
    colours: np.ndarray
    textures: np.ndarray
    lookalike_of: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)

    @classmethod
    def empty(cls) -> Shapes:
        """No object."""
        z = np.zeros(0)
        return cls(
            np.zeros(0, np.int64),
            np.zeros(0, np.int64),
            np.zeros(0, np.int64),
            np.zeros((0, 3)),
            np.zeros((0, 3)),
            z,
            np.zeros((0, 3)),
            np.zeros(0, np.int64),
            np.full(0, -1, np.int64),
        )

    def footprint_radius(self) -> np.ndarray:
        """``(K,)`` radius of each object's footprint on the floor (metres)."""
        return np.where(
            self.kinds == BOX, np.hypot(self.sizes[:, 0], self.sizes[:, 1]), self.sizes[:, 0]
        )

    def bounding_corners(self) -> np.ndarray:
        """``(K, 8, 3)`` world corners of each object's (yawed) bounding box."""
        sx = np.array([-1, 1, 1, -1, -1, 1, 1, -1], float)
        sy = np.array([-1, -1, 1, 1, -1, -1, 1, 1], float)
        sz = np.array([-1, -1, -1, -1, 1, 1, 1, 1], float) * 0.5
        local = np.stack(
            [
                sx[None] * self.sizes[:, 0:1],
                sy[None] * self.sizes[:, 1:2],
                sz[None] * self.sizes[:, 2:3],
            ],
            axis=2,
        )
        c, s = np.cos(self.yaws)[:, None], np.sin(self.yaws)[:, None]
        x = c * local[..., 0] - s * local[..., 1]
        y = s * local[..., 0] + c * local[..., 1]
        return np.stack([x, y, local[..., 2]], axis=2) + self.centres[:, None, :]


def _hsv_to_bgr(h: float, s: float, v: float) -> np.ndarray:
    r, g, b = colorsys.hsv_to_rgb(h % 1.0, s, v)
    return np.array([b, g, r])


def draw_instances(
    rng: np.random.Generator, count: int, lookalikes: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Classes, sizes, colours and look-alike sources (``-1``: an original) of ``count``
    instances.

    Classes cycle through :data:`SHAPE_CLASSES` in a shuffled order; with probability
    ``lookalikes`` an instance copies an earlier original of its class (its texture and size,
    its colour moved by at most 3 % per channel).
    """
    n_cls = len(SHAPE_CLASSES)
    classes = np.array([rng.permutation(n_cls) for _ in range(-(-count // n_cls))]).ravel()
    classes = classes[:count].astype(np.int64)
    sizes = np.zeros((count, 3))
    colours = np.zeros((count, 3))
    source = np.full(count, -1, np.int64)
    for j, c in enumerate(classes):
        cls = SHAPE_CLASSES[c]
        earlier = np.flatnonzero((classes[:j] == c) & (source[:j] < 0))
        if earlier.size and rng.random() < lookalikes:
            o = int(rng.choice(earlier))
            source[j] = o
            sizes[j] = sizes[o]
            colours[j] = np.clip(colours[o] + rng.uniform(-0.03, 0.03, 3), 0.0, 1.0)
            continue
        size = rng.uniform(cls.size_low, cls.size_high)
        if cls.kind != BOX:
            size[1] = size[0]
        sizes[j] = size
        colours[j] = _hsv_to_bgr(
            rng.uniform(*cls.hue), rng.uniform(*cls.saturation), rng.uniform(*cls.value)
        )
    return classes, sizes, colours, source


def shape_texture(family: str, seed: int, n: int, texel: float) -> np.ndarray:
    """An ``n × n`` grey texture in ``[0, 1]`` of a family (columns ``a``, rows ``b`` metres
    down from the object's top), drawn from ``seed`` (anything ``default_rng`` takes)."""
    rng = np.random.default_rng(seed)
    rows = np.arange(n)[:, None] * texel
    cols = np.arange(n)[None, :] * texel
    grain = _smooth_noise(rng, n, 0.12)
    if family == "planks":
        width = rng.uniform(0.08, 0.16)
        index = np.floor(rows / width).astype(int)
        albedo = rng.uniform(0.55, 1.0, index.max() + 1)[index]
        seam = (rows - index * width) < 0.008
        out = np.where(seam, 0.25, albedo + 0.12 * grain)
    elif family == "panels":
        w, h = rng.uniform(0.2, 0.4), rng.uniform(0.3, 0.6)
        edge = ((cols % w) < 0.012) | ((rows % h) < 0.012)
        out = np.where(edge, 0.35, 0.85 + 0.06 * grain)
    elif family == "bands":
        period = rng.uniform(0.15, 0.35)
        band = (rows % period) < rng.uniform(0.02, 0.06)
        out = np.where(band, 0.4, 0.9 + 0.08 * grain)
    elif family == "speckle":
        out = 0.8 + 0.18 * np.tanh(2.0 * _smooth_noise(rng, n, 0.3))
    elif family == "stripes":
        top, height = rng.uniform(0.1, 0.2), rng.uniform(0.08, 0.14)
        stripe = (rows > top) & (rows < top + height)
        out = np.where(stripe, 1.0, 0.7 + 0.08 * grain) + 0.0 * cols
    else:  # pragma: no cover - the classes above name only these
        raise ValueError(family)
    return np.clip(out, 0.05, 1.0)


def _smooth_noise(rng: np.random.Generator, n: int, cutoff: float) -> np.ndarray:
    f = np.hypot(np.fft.fftfreq(n)[:, None], np.fft.rfftfreq(n)[None, :])
    spectrum = np.fft.rfft2(rng.standard_normal((n, n))) * np.exp(-((f / cutoff) ** 2))
    out = np.fft.irfft2(spectrum, s=(n, n))
    return (out - out.mean()) / out.std()


def place(
    rng: np.random.Generator,
    footprints: np.ndarray,
    candidate,
    paths_xy: np.ndarray,
    clearance: float,
    clear=None,
) -> np.ndarray:
    """Floor positions ``(K, 2)`` for objects of footprint radii ``footprints``: object ``j``
    at a proposal ``candidate(rng, j, radius) -> (x, y)`` kept when at least ``clearance``
    beyond its footprint from every path point, not overlapping an object placed before, and
    ``clear(p, radius)`` (when given; NaN when no proposal out of 400 fits)."""
    out = np.full((len(footprints), 2), np.nan)
    for j, r in enumerate(footprints):
        for _ in range(400):
            p = np.asarray(candidate(rng, j, r))
            if clear is not None and not clear(p, r):
                continue
            if np.min(np.linalg.norm(paths_xy - p, axis=1)) < r + clearance:
                continue
            placed = np.isfinite(out[:j, 0])
            gaps = np.linalg.norm(out[:j][placed] - p, axis=1) - footprints[:j][placed] - r
            if gaps.size and gaps.min() < 0.05:
                continue
            out[j] = p
            break
    return out


# -- exact ray intersection ----------------------------------------------------------------


def intersect(
    shapes: Shapes, j: int, origin: np.ndarray, d: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where rays ``origin + t · d`` (``d`` ``(N, 3)``) first meet object ``j`` from outside.

    Returns
    -------
    t
        ``(N,)`` ray parameter of the hit (``inf`` where the ray misses).
    normal
        ``(N, 3)`` outward unit normal of the surface there (world frame).
    a, b
        ``(N,)`` texture coordinates (metres): ``a`` around or along the object, ``b`` down
        from its top (on top faces, the two horizontal axes).
    """
    kind = shapes.kinds[j]
    c = shapes.centres[j]
    base = np.array([c[0], c[1], c[2] - shapes.sizes[j, 2] / 2])
    p = origin - base  # the object's frame: origin on the floor below its axis
    yaw = shapes.yaws[j]
    cy, sy = np.cos(yaw), np.sin(yaw)
    rot = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])  # object -> world
    p = rot.T @ p
    dl = d @ rot
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if kind == BOX:
            t, n, a, b = _box(p, dl, shapes.sizes[j])
        elif kind == CYLINDER:
            t, n, a, b = _round(p, dl, shapes.sizes[j, 0], shapes.sizes[j, 2], cone=False)
        else:
            t, n, a, b = _round(p, dl, shapes.sizes[j, 0], shapes.sizes[j, 2], cone=True)
    return t, n @ rot.T, a, b


def _box(p, d, size):
    half = np.array([size[0], size[1], size[2] / 2])
    q = p - np.array([0.0, 0.0, half[2]])
    t1 = (-half - q) / d
    t2 = (half - q) / d
    lo, hi = np.fmin(t1, t2), np.fmax(t1, t2)
    axis = np.argmax(lo, axis=1)
    rows = np.arange(len(d))
    t_near = lo[rows, axis]
    t_far = hi.min(axis=1)
    hit = (t_near <= t_far) & (t_near > 0)
    t = np.where(hit, t_near, np.inf)
    n = np.zeros_like(d)
    n[rows, axis] = -np.sign(d[rows, axis])
    x = q + np.where(hit, t, 0.0)[:, None] * d
    # sides: a along the face (to the right seen from outside), b down from the top
    side_a = np.where(axis == 0, x[:, 1] * n[:, 0], -x[:, 0] * n[:, 1])
    a = np.where(axis == 2, x[:, 0] + half[0], side_a + half[0] + half[1])
    b = np.where(axis == 2, x[:, 1] + half[1], half[2] - x[:, 2])
    return t, n, a, b


def _round(p, d, radius, height, cone):
    k = radius / height if cone else 0.0
    w0 = height - p[2]
    A = d[:, 0] ** 2 + d[:, 1] ** 2 - k * k * d[:, 2] ** 2
    B = 2.0 * (p[0] * d[:, 0] + p[1] * d[:, 1] + k * k * w0 * d[:, 2])
    C = p[0] ** 2 + p[1] ** 2 - (k * w0) ** 2 if cone else p[0] ** 2 + p[1] ** 2 - radius**2
    disc = B * B - 4.0 * A * C
    root = np.sqrt(np.maximum(disc, 0.0))
    q = -0.5 * (B + np.copysign(root, B))
    r1, r2 = q / A, C / q
    linear = np.abs(A) < 1e-12 * (d * d).sum(axis=1)
    r1 = np.where(linear, -C / B, r1)
    r2 = np.where(linear, np.inf, r2)
    best = np.full(len(d), np.inf)
    for r in (r1, r2):
        z = p[2] + r * d[:, 2]
        ok = (disc >= 0) & (r > 0) & (z >= 0) & (z <= height) & np.isfinite(r)
        best = np.where(ok & (r < best), r, best)
    side = np.isfinite(best)
    caps = (0.0,) if cone else (0.0, height)
    for zc in caps:
        tc = (zc - p[2]) / d[:, 2]
        xc, yc = p[0] + tc * d[:, 0], p[1] + tc * d[:, 1]
        ok = (tc > 0) & (xc * xc + yc * yc <= radius * radius) & (tc < best)
        best = np.where(ok, tc, best)
        side &= ~ok
    hit = np.isfinite(best)
    x = p + np.where(hit, best, 0.0)[:, None] * d
    rho = np.hypot(x[:, 0], x[:, 1])
    n = np.zeros_like(d)
    n[:, 2] = np.where(x[:, 2] > height / 2, 1.0, -1.0)
    radial = np.column_stack([x[:, 0], x[:, 1], k * rho])
    radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-300)
    n = np.where(side[:, None], radial, n)
    angle = np.arctan2(x[:, 1], x[:, 0]) + np.pi
    a = np.where(side, radius * angle, x[:, 0] + radius)
    slant = np.sqrt(1.0 + k * k)
    b = np.where(side, (height - x[:, 2]) * slant, x[:, 1] + radius)
    return best, n, a, b
