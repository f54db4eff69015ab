"""The sensor model of a team dataset: how noisy its odometry and its stereo measurements are.

A versioned ``"sensor_model"`` section of the dataset manifest: its ``origin`` and ``note``,
team-wide ``odometry_std`` (six per-axis σ per step, metres then radians, right perturbation
``δT_measured = δT_true · exp(n)``), ``feature_std`` and ``object_std`` (σ per stereo coordinate
in the units of ``K``), ``object_size_share`` (how a detector box centre's σ grows with the
box, :mod:`teamslam.msckf.filter.box_noise`), ``object_depth_range`` (metres), and optional
per-robot overrides. Any
field may be ``null`` (unknown): the filter then takes it from calibration or a camera-scaled
default. Layout and conventions: the concept page *Calibration*
(``docs/concepts/calibration.md``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace

import numpy as np

from teamslam.datasets.model import DatasetError

__all__ = ["SENSOR_MODEL_VERSION", "SensorModel", "SensorNoise"]

SENSOR_MODEL_VERSION = 1
ORIGINS = ("simulation", "params file", "calibration", "user")


def _positive(value, where: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise DatasetError(f"{where} must be a number, got {value!r}") from None
    if not (np.isfinite(number) and number > 0):
        raise DatasetError(f"{where} must be a positive finite number, got {value!r}")
    return number


@dataclass(frozen=True)
class SensorNoise:
    """Noise of one robot's sensors (``None``: unknown).

    Attributes
    ----------
    odometry_std
        Six per-axis standard deviations of the odometry noise per step: translation
        ``(x, y, z)`` in metres, then rotation ``(x, y, z)`` in radians, body frame.
    feature_std, object_std
        Standard deviation of each stereo coordinate of geometric features and of object box
        centres, in the units of the camera intrinsics.
    object_depth_range
        ``(min, max)`` distance in metres at which objects are detected and initialised.
    object_size_share
        Share of a detector box's size (width for ``u``, height for ``v``) added in quadrature
        to ``object_std`` (≥ 0).
    """

    odometry_std: tuple[float, ...] | None = None
    feature_std: float | None = None
    object_std: float | None = None
    object_depth_range: tuple[float, float] | None = None
    object_size_share: float | None = None

    def __post_init__(self) -> None:
        self.check("sensor_model")

    def check(self, where: str) -> None:
        """Raise :class:`DatasetError` naming ``where`` and the field of the first problem."""
        if self.odometry_std is not None:
            values = self.odometry_std
            if isinstance(values, str) or not hasattr(values, "__len__") or len(values) != 6:
                raise DatasetError(f"{where}.odometry_std must be six numbers")
            object.__setattr__(
                self,
                "odometry_std",
                tuple(_positive(v, f"{where}.odometry_std[{i}]") for i, v in enumerate(values)),
            )
        for name in ("feature_std", "object_std"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _positive(value, f"{where}.{name}"))
        if self.object_size_share is not None:
            share = self.object_size_share
            if share != 0:
                share = _positive(share, f"{where}.object_size_share")
            object.__setattr__(self, "object_size_share", float(share))
        if self.object_depth_range is not None:
            rng = self.object_depth_range
            if isinstance(rng, str) or not hasattr(rng, "__len__") or len(rng) != 2:
                raise DatasetError(f"{where}.object_depth_range must be [min, max]")
            low = _positive(rng[0], f"{where}.object_depth_range[0]")
            high = _positive(rng[1], f"{where}.object_depth_range[1]")
            if not low < high:
                raise DatasetError(f"{where}.object_depth_range must have min < max")
            object.__setattr__(self, "object_depth_range", (low, high))

    def merged(self, other: SensorNoise) -> SensorNoise:
        """These values where ``other`` has none, ``other``'s where it has them."""
        return replace(
            self,
            **{
                f.name: getattr(other, f.name)
                for f in fields(other)
                if getattr(other, f.name) is not None
            },
        )

    def to_json(self) -> dict:
        """Plain JSON (only known fields)."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if value is not None:
                out[f.name] = list(value) if isinstance(value, tuple) else value
        return out

    @classmethod
    def from_json(cls, data, where: str) -> SensorNoise:
        """Parse and validate; unknown keys are errors."""
        if not isinstance(data, Mapping):
            raise DatasetError(f"{where} must be a mapping")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise DatasetError(f"{where}: unknown field {unknown[0]!r}")
        noise = cls.__new__(cls)
        for f in fields(cls):
            object.__setattr__(noise, f.name, data.get(f.name))
        noise.check(where)
        return noise


@dataclass(frozen=True)
class SensorModel:
    """A team's sensor model: team-wide values, optional per-robot values, and where they came from.

    Attributes
    ----------
    team
        Values shared by every robot.
    robots
        Per-robot values (robot index → :class:`SensorNoise`) that override ``team``.
    origin
        ``simulation`` (the generator's true values), ``params file`` (a publisher's parameter
        file, converted), ``calibration`` (estimated from the data by ``teamslam calibrate``)
        or ``user``.
    note
        Free text: the file, the method, the conversion.
    """

    team: SensorNoise
    robots: dict[int, SensorNoise] = field(default_factory=dict)
    origin: str = "user"
    note: str = ""

    def __post_init__(self) -> None:
        if self.origin not in ORIGINS:
            raise DatasetError(f"sensor_model.origin must be one of {', '.join(ORIGINS)}")
        for key in self.robots:
            if not isinstance(key, int) or key < 0:
                raise DatasetError(f"sensor_model.robots: {key!r} is not a robot index")

    def for_robot(self, robot: int) -> SensorNoise:
        """The values that apply to robot ``robot``."""
        own = self.robots.get(robot)
        return self.team if own is None else self.team.merged(own)

    def to_json(self) -> dict:
        """The manifest section."""
        out = {
            "version": SENSOR_MODEL_VERSION,
            "origin": self.origin,
            "note": self.note,
            **self.team.to_json(),
        }
        if self.robots:
            out["robots"] = {str(k): v.to_json() for k, v in sorted(self.robots.items())}
        return out

    @classmethod
    def from_json(cls, data, where: str = "sensor_model", robots: int | None = None) -> SensorModel:
        """Parse and validate the manifest section (``robots``: team size, to check indices)."""
        if not isinstance(data, Mapping):
            raise DatasetError(f"{where} must be a mapping")
        version = data.get("version")
        if version != SENSOR_MODEL_VERSION:
            raise DatasetError(
                f"{where}: unsupported version {version!r} "
                f"(this teamslam reads version {SENSOR_MODEL_VERSION})"
            )
        origin = data.get("origin", "user")
        if origin not in ORIGINS:
            raise DatasetError(f"{where}.origin must be one of {', '.join(ORIGINS)}")
        note = data.get("note", "")
        if not isinstance(note, str):
            raise DatasetError(f"{where}.note must be text")
        team = {k: v for k, v in data.items() if k not in ("version", "origin", "note", "robots")}
        per_robot = {}
        raw = data.get("robots") or {}
        if not isinstance(raw, Mapping):
            raise DatasetError(f"{where}.robots must map robot indices to values")
        for key, value in raw.items():
            try:
                index = int(key)
            except (TypeError, ValueError):
                raise DatasetError(f"{where}.robots: {key!r} is not a robot index") from None
            if index < 0 or (robots is not None and index >= robots):
                raise DatasetError(f"{where}.robots: no robot {index} in this team")
            per_robot[index] = SensorNoise.from_json(value, f"{where}.robots[{index}]")
        return cls(SensorNoise.from_json(team, where), per_robot, origin, note)
