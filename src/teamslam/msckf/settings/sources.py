"""Where a run's settings come from, in one visible order.

Each setting of :class:`~teamslam.msckf.settings.values.MsckfConfig` takes the value of the last of
these
layers that gives it, and the layer is recorded as its *source*:

1. ``default`` — built in; noise levels scale with the camera (an angle times the focal length,
   so pixels for a pixel camera and normalised units when ``K = I``) and with the odometry's
   own step sizes — never a fixed pixel count, never chosen by a dataset's name or origin;
2. ``dataset`` — the dataset's sensor model (:mod:`teamslam.datasets.sensor_model`);
3. ``calibration`` — estimated from the data (:mod:`teamslam.msckf.calibration`): by default
   only for noise levels that neither the dataset, a file nor a flag gives;
4. ``file`` — a YAML config file of ``key: value`` lines;
5. ``flag`` — ``--set key=value`` and the dedicated command-line flags.

Unknown keys and bad values raise :class:`ConfigError` naming the key.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from teamslam.datasets.model import TeamDataset
from teamslam.datasets.sensor_model import SensorNoise
from teamslam.errors import InputError
from teamslam.msckf.settings.values import MsckfConfig
from teamslam.textio import format_value, read_yaml

__all__ = [
    "CALIBRATED_KEYS",
    "SOURCES",
    "ConfigError",
    "EffectiveConfig",
    "calibration_start",
    "camera_defaults",
    "coerce_settings",
    "load_config_file",
    "parse_assignments",
]

log = logging.getLogger(__name__)

SOURCES = ("default", "dataset", "calibration", "file", "flag")
#: The noise levels a calibration estimates.
CALIBRATED_KEYS = ("odometry_std", "feature_std", "object_std")
#: Default measurement noise as an angle (rad): σ = angle · focal length, in the camera's units.
DEFAULT_FEATURE_ANGLE = 1.5e-3
DEFAULT_OBJECT_ANGLE = 5e-3
#: Default odometry noise per step as a fraction of the median step (translation, rotation).
DEFAULT_ODOMETRY_FRACTION = 0.01


class ConfigError(InputError):
    """A setting that does not exist or has a value it cannot take; the message names it."""


_FIELD_TYPES = {f.name: f.type for f in fields(MsckfConfig)}


def coerce_settings(values: dict[str, Any], where: str) -> dict[str, Any]:
    """Check names and types of ``values`` (``where`` names their origin in errors)."""
    out = {}
    for key, value in values.items():
        kind = _FIELD_TYPES.get(key)
        if kind is None:
            known = ", ".join(MsckfConfig.field_names())
            raise ConfigError(f"{where}: unknown setting {key!r} (settings: {known})")
        bad = ConfigError(f"{where}: {key} = {value!r} is not a valid {kind}")
        if kind == "bool":
            if not isinstance(value, bool):
                raise bad
        elif kind == "int":
            if isinstance(value, bool) or not isinstance(value, int):
                raise bad
        elif kind == "float":
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise bad
            value = float(value)
        elif kind == "str":
            if not isinstance(value, str):
                raise bad
        else:  # the odometry σ: six numbers
            if (
                not isinstance(value, list | tuple)
                or len(value) != 6
                or any(isinstance(v, bool) or not isinstance(v, int | float) for v in value)
            ):
                raise ConfigError(
                    f"{where}: {key} must be a list of six numbers "
                    f"[x, y, z (m), rx, ry, rz (rad)], got {value!r}"
                )
            value = tuple(float(v) for v in value)
        out[key] = value
    return out


def load_config_file(path: str | Path) -> dict[str, Any]:
    """Read a YAML config file of ``setting: value`` lines, checked."""
    data = read_yaml(path, ConfigError)
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected 'setting: value' lines")
    return coerce_settings(data, str(path))


def parse_assignments(assignments: list[str]) -> dict[str, Any]:
    """``["key=value", …]`` → checked settings; values are read as YAML scalars or lists."""
    values = {}
    for text in assignments:
        key, sep, raw = text.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set {text!r}: expected key=value")
        try:
            values[key.strip()] = yaml.safe_load(raw)
        except yaml.YAMLError:
            raise ConfigError(f"--set {key.strip()}: cannot read the value {raw!r}") from None
    return coerce_settings(values, "--set")


def camera_defaults(dataset: TeamDataset) -> dict[str, Any]:
    """Last-resort noise levels that scale with the data's own units.

    * measurement σ = an angle (1.5 mrad for features, 5 mrad for object box centres) times the
      mean focal length of ``K``;
    * odometry σ per axis = 1% of the median step's translation (at least 1 mm) and rotation
      angle (at least 1 mrad per metre of the step, and 0.1 mrad);
    * object depth range = 2 to 100 stereo baselines (disparity down to 1% of the focal length).
    """
    camera = dataset.calibration.camera
    focal = float(np.mean(np.diag(camera.intrinsics)[:2]))
    odometry = np.concatenate([r.odometry for r in dataset.robots])
    if odometry.shape[0]:
        translation = float(np.median(np.linalg.norm(odometry[:, :3, 3], axis=1)))
        cos = np.clip((np.trace(odometry[:, :3, :3], axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        rotation = float(np.median(np.arccos(cos)))
    else:
        translation = rotation = 0.0
    sigma_t = max(DEFAULT_ODOMETRY_FRACTION * translation, 1e-3)
    # a robot driving straight turns little, but its odometry's heading still errs: at least
    # 1 mrad per metre of the median step
    sigma_r = max(DEFAULT_ODOMETRY_FRACTION * rotation, 1e-3 * translation, 1e-4)
    baseline = camera.baseline
    return {
        "odometry_std": (sigma_t,) * 3 + (sigma_r,) * 3,
        "feature_std": DEFAULT_FEATURE_ANGLE * focal,
        "object_std": DEFAULT_OBJECT_ANGLE * focal,
        "object_min_depth": 2.0 * baseline,
        "object_max_depth": 100.0 * baseline,
    }


def calibration_start(dataset: TeamDataset, config: MsckfConfig) -> MsckfConfig:
    """``config`` with the noise levels a calibration estimates reset to the camera-scaled
    defaults, so that a calibration starts from the data's scale, not from a guess to check."""
    defaults = camera_defaults(dataset)
    return config.with_(**{key: defaults[key] for key in CALIBRATED_KEYS})


def _sensor_values(noise: SensorNoise) -> dict[str, Any]:
    """The settings a sensor model gives."""
    out: dict[str, Any] = {}
    if noise.odometry_std is not None:
        out["odometry_std"] = tuple(noise.odometry_std)
    if noise.feature_std is not None:
        out["feature_std"] = noise.feature_std
    if noise.object_std is not None:
        out["object_std"] = noise.object_std
    if noise.object_depth_range is not None:
        out["object_min_depth"], out["object_max_depth"] = noise.object_depth_range
    return out


def _calibratable(dataset: TeamDataset, values: dict[str, Any]) -> tuple[str, ...]:
    """Noise levels the run will use on this data that a calibration estimates (the object
    depth range is not one of them: it comes from the dataset, a file, a flag or the
    camera-scaled default)."""
    used = {
        "odometry_std": True,
        "feature_std": values.get("use_geometric_features", True)
        and any(r.features.ids.size for r in dataset.robots),
        "object_std": values.get("use_objects", True)
        and any(r.objects.ids.size for r in dataset.robots),
    }
    return tuple(k for k in CALIBRATED_KEYS if used[k])


@dataclass
class EffectiveConfig:
    """The settings a run uses, where each came from, and the calibration if one ran.

    Attributes
    ----------
    config
        Team-wide settings.
    sources
        Setting name → one of :data:`SOURCES`.
    robots
        Per-robot settings (differ from ``config`` only where the sensor model has per-robot
        values that no file or flag overrides).
    calibration
        The :class:`~teamslam.msckf.calibration.CalibrationResult`, when calibration ran.
    """

    config: MsckfConfig
    sources: dict[str, str]
    robots: list[MsckfConfig] = field(default_factory=list)
    calibration: Any = None

    def to_json(self) -> dict:
        """``config``, ``config_sources`` and, when they differ, ``config_per_robot``."""
        out: dict[str, Any] = {
            "config": self.config.to_json(),
            "config_sources": dict(self.sources),
        }
        differing = {
            str(i): {k: v for k, v in c.to_json().items() if v != out["config"][k]}
            for i, c in enumerate(self.robots)
            if c != self.config
        }
        if differing:
            out["config_per_robot"] = differing
        if self.calibration is not None:
            out["calibration"] = self.calibration.to_json()
        return out

    def table(self) -> str:
        """One line per setting: name, value, source."""
        data = self.config.to_json()
        width = max(len(k) for k in data)
        lines = []
        for key, value in data.items():
            shown = format_value(value, 6)
            lines.append(f"{key:<{width}}  {shown:<48} {self.sources.get(key, 'default')}")
        for i, c in enumerate(self.robots):
            if c != self.config:
                own = {k: v for k, v in c.to_json().items() if v != data[k]}
                lines.append(f"robot {i} (dataset): {own}")
        return "\n".join(lines)
