"""Where a run's settings come from, in one visible order.

Each setting ``group.name`` of :class:`~teamslam.msckf.settings.values.MsckfConfig` takes the value
of the last of these layers that gives it, and the layer is recorded as its *source*:

1. ``default`` — built in; noise levels scale with the camera (an angle times the focal length,
   so pixels for a pixel camera and normalised units when ``K = I``) and with the odometry's
   own step sizes — never a fixed pixel count, never chosen by a dataset's name or origin;
2. ``dataset`` — the dataset's sensor model (:mod:`teamslam.datasets.sensor_model`);
3. ``calibration`` — estimated from the data (:mod:`teamslam.msckf.calibration`): by default
   only for noise levels that neither the dataset, a file nor a flag gives;
4. ``file`` — a YAML config file: groups as mappings (``consensus: {rule: hybrid}``) or dotted
   keys (``consensus.rule: hybrid``);
5. ``flag`` — ``--set group.name=value`` and the dedicated command-line flags.

Unknown keys and bad values raise :class:`ConfigError` naming the key (with the closest names,
or the new name of a flat key of the past).
"""

from __future__ import annotations

import difflib
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from teamslam.datasets.model import TeamDataset
from teamslam.datasets.sensor_model import SensorNoise
from teamslam.errors import InputError
from teamslam.msckf.settings.values import GROUPS, MsckfConfig
from teamslam.textio import format_value, read_yaml

__all__ = [
    "CALIBRATED_KEYS",
    "OLD_KEYS",
    "SOURCES",
    "ConfigError",
    "EffectiveConfig",
    "calibration_start",
    "camera_defaults",
    "coerce_settings",
    "flatten_settings",
    "load_config_file",
    "parse_assignments",
]

log = logging.getLogger(__name__)

SOURCES = ("default", "dataset", "calibration", "file", "flag")
#: The noise levels a calibration estimates.
CALIBRATED_KEYS = (
    "filter.odometry_std",
    "filter.feature_std",
    "filter.object_std",
    "filter.object_size_share",
)
#: Default measurement noise as an angle (rad): σ = angle · focal length, in the camera's units.
DEFAULT_FEATURE_ANGLE = 1.5e-3
DEFAULT_OBJECT_ANGLE = 5e-3
#: Default odometry noise per step as a fraction of the median step (translation, rotation).
DEFAULT_ODOMETRY_FRACTION = 0.01


class ConfigError(InputError):
    """A setting that does not exist or has a value it cannot take; the message names it."""


#: The flat names of the settings before they were grouped → the name now (refused, named).
OLD_KEYS = {
    "window": "filter.window",
    "odometry_std": "filter.odometry_std",
    "feature_std": "filter.feature_std",
    "object_std": "filter.object_std",
    "min_track_length": "filter.min_track_length",
    "gate_probability": "filter.gate_probability",
    "use_geometric_features": "filter.use_geometric_features",
    "use_objects": "filter.use_objects",
    "initial_pose_std": "filter.initial_pose_std",
    "linearization": "filter.linearization",
    "debug": "filter.debug",
    "object_init_observations": "objects.init_observations",
    "object_min_depth": "objects.min_depth",
    "object_max_depth": "objects.max_depth",
    "object_init_max_relative_std": "objects.init_max_relative_std",
    "object_loss": "objects.loss",
    "object_loss_scale": "objects.loss_scale",
    "object_update_iterations": "objects.update_iterations",
    "object_retire_after": "objects.retire_after",
    "track_gate_probability": "tracking.gate_probability",
    "track_birth_probability": "tracking.birth_probability",
    "track_confirm_hits": "tracking.confirm_hits",
    "track_confirm_frames": "tracking.confirm_frames",
    "track_loop_closure": "tracking.loop_closure",
    "consensus_kl_threshold": "consensus.kl_threshold",
    "consensus_set": "consensus.set",
    "consensus_active_information": "consensus.active_information",
    "consensus_inactive_kl_threshold": "consensus.inactive_kl_threshold",
    "consensus_per_object": "consensus.per_object",
    "consensus_float32": "consensus.float32",
    "consensus_hybrid": "consensus.rule",
    "consensus_increments": "consensus.rule",
    "consensus_iterations": "consensus.iterations",
    "consensus_innovation_check": "consensus.innovation_check",
    "association": "association.mode",
    "association_interval": "association.interval",
    "association_revoke_probability": "association.revoke_probability",
}


def _unknown(key: str, where: str) -> ConfigError:
    """The error for a setting ``key`` that does not exist: the new name of an old one, or
    the closest names (difflib)."""
    if key in OLD_KEYS:
        new = OLD_KEYS[key]
        if new == "consensus.rule":
            return ConfigError(
                f"{where}: {key} was replaced by consensus.rule (average | hybrid | increments), "
                f"e.g. consensus.rule={key.removeprefix('consensus_')}"
            )
        return ConfigError(f"{where}: {key} is now {new}")
    keys = MsckfConfig.keys()
    group, dot, name = key.rpartition(".")
    if dot and group in GROUPS:  # a group that exists: the closest of its names
        pool = [k for k in keys if k.startswith(f"{group}.")]
    else:
        pool = list(keys)
    by_name: dict[str, list[str]] = {}
    for k in pool:
        by_name.setdefault(k.partition(".")[2], []).append(k)
    close = [k for n in difflib.get_close_matches(name, list(by_name), n=2) for k in by_name[n]]
    close = close or difflib.get_close_matches(key, pool, n=3)
    close = close[:3]
    named = f"{', '.join(close[:-1])} or {close[-1]}" if len(close) > 1 else "".join(close)
    hint = f"; did you mean {named}?" if close else ""
    return ConfigError(
        f"{where}: unknown setting {key!r}{hint} (`teamslam config show` lists them)"
    )


def flatten_settings(values: Mapping[str, Any], where: str) -> dict[str, Any]:
    """``{"group.name": value}`` of a mapping with nested groups (``{"consensus": {"rule":
    "hybrid"}}``) and/or dotted keys (``{"consensus.rule": "hybrid"}``); names checked."""
    out: dict[str, Any] = {}
    for key, value in values.items():
        key = str(key)
        if key in GROUPS and isinstance(value, Mapping):
            for name, inner in value.items():
                dotted = f"{key}.{name}"
                if MsckfConfig.field_of(dotted) is None:
                    raise _unknown(dotted, where)
                out[dotted] = inner
            continue
        if MsckfConfig.field_of(key) is None:
            if key in GROUPS and key not in OLD_KEYS:
                raise ConfigError(f"{where}: {key} is a group of settings: give it a mapping")
            raise _unknown(key, where)
        out[key] = value
    return out


def _setting_type(key: str) -> str:
    kind = MsckfConfig.field_of(key).type
    return kind if isinstance(kind, str) else kind.__name__


def coerce_settings(values: Mapping[str, Any], where: str) -> dict[str, Any]:
    """Check names and types of ``values`` (nested groups or dotted keys; ``where`` names their
    origin in errors); ``{"group.name": value}``."""
    out = {}
    for key, value in flatten_settings(values, where).items():
        kind = _setting_type(key)
        bad = ConfigError(f"{where}: {key} = {value!r} is not a valid {kind}")
        if kind == "bool":
            if not isinstance(value, bool):
                raise bad
        elif kind == "int":
            if isinstance(value, bool) or not isinstance(value, int):
                raise bad
        elif kind in ("float", "float | None"):
            if value is None and kind != "float":
                out[key] = value  # null: the setting's test is off
                continue
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
    """Read a YAML config file of settings — groups as mappings (``filter: {window: 8}``) or
    dotted keys (``filter.window: 8``) — checked."""
    data = read_yaml(path, ConfigError)
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected 'group: {{name: value}}' or 'group.name: value' lines")
    return coerce_settings(data, str(path))


def parse_assignments(assignments: Sequence[str]) -> dict[str, Any]:
    """``["group.name=value", …]`` → checked settings; values are read as YAML scalars or
    lists."""
    values = {}
    for text in assignments:
        key, sep, raw = text.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set {text!r}: expected group.name=value")
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
        "filter.odometry_std": (sigma_t,) * 3 + (sigma_r,) * 3,
        "filter.feature_std": DEFAULT_FEATURE_ANGLE * focal,
        "filter.object_std": DEFAULT_OBJECT_ANGLE * focal,
        "filter.object_size_share": 0.0,
        "objects.min_depth": 2.0 * baseline,
        "objects.max_depth": 100.0 * baseline,
    }


def calibration_start(dataset: TeamDataset, config: MsckfConfig) -> MsckfConfig:
    """``config`` with the noise levels a calibration estimates reset to the camera-scaled
    defaults, so that a calibration starts from the data's scale, not from a guess to check."""
    defaults = camera_defaults(dataset)
    return config.with_({key: defaults[key] for key in CALIBRATED_KEYS})


def _sensor_values(noise: SensorNoise) -> dict[str, Any]:
    """The settings a sensor model gives."""
    out: dict[str, Any] = {}
    if noise.odometry_std is not None:
        out["filter.odometry_std"] = tuple(noise.odometry_std)
    if noise.feature_std is not None:
        out["filter.feature_std"] = noise.feature_std
    if noise.object_std is not None:
        out["filter.object_std"] = noise.object_std
    if noise.object_size_share is not None:
        out["filter.object_size_share"] = noise.object_size_share
    if noise.object_depth_range is not None:
        out["objects.min_depth"], out["objects.max_depth"] = noise.object_depth_range
    return out


def _calibratable(dataset: TeamDataset, values: dict[str, Any]) -> tuple[str, ...]:
    """Noise levels the run will use on this data that a calibration estimates (the object
    depth range is not one of them: it comes from the dataset, a file, a flag or the
    camera-scaled default)."""
    objects = values.get("filter.use_objects", True)
    detections = [r.detections for r in dataset.robots if r.objects.ids.size == 0]
    boxes = bool(detections) and all(d is not None and d.sizes is not None for d in detections)
    used = {
        "filter.odometry_std": True,
        "filter.feature_std": values.get("filter.use_geometric_features", True)
        and any(r.features.ids.size for r in dataset.robots),
        "filter.object_std": objects and (any(r.objects.ids.size for r in dataset.robots) or boxes),
        "filter.object_size_share": objects and boxes,
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
        Setting name (``group.name``) → one of :data:`SOURCES`.
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

    def per_robot(self) -> dict[str, dict[str, Any]]:
        """Robot index (a string) → ``{"group.name": value}`` where its settings differ from
        the team's."""
        team = self.config.settings()
        return {
            str(i): {k: _plain(v) for k, v in c.settings().items() if v != team[k]}
            for i, c in enumerate(self.robots)
            if c != self.config
        }

    def to_json(self) -> dict:
        """``config`` (one mapping per group), ``config_sources`` (by ``group.name``) and, when
        they differ, ``config_per_robot``."""
        out: dict[str, Any] = {
            "config": self.config.to_json(),
            "config_sources": {k: self.sources.get(k, "default") for k in MsckfConfig.keys()},
        }
        differing = self.per_robot()
        if differing:
            out["config_per_robot"] = differing
        if self.calibration is not None:
            out["calibration"] = self.calibration.to_json()
        return out

    def rows(self) -> list[dict[str, Any]]:
        """One row per setting: ``key`` (``group.name``), ``value``, ``unit``, ``source``."""
        return [
            {
                "key": key,
                "value": _plain(value),
                "unit": MsckfConfig.unit(key),
                "source": self.sources.get(key, "default"),
            }
            for key, value in self.config.settings().items()
        ]

    def table(self) -> str:
        """One line per setting: ``group.name  value  unit  source``."""
        rows = self.rows()
        shown = [format_value(r["value"], 6) for r in rows]
        key_width = max(len(r["key"]) for r in rows)
        value_width = max(len(v) for v in shown)
        unit_width = max(len(r["unit"] or "-") for r in rows)
        lines = [
            f"{r['key']:<{key_width}}  {v:<{value_width}}  {r['unit'] or '-':<{unit_width}}  "
            f"{r['source']}"
            for r, v in zip(rows, shown, strict=True)
        ]
        for i, own in self.per_robot().items():
            lines.append(f"robot {i} (dataset): {own}")
        return "\n".join(lines)


def _plain(value: Any) -> Any:
    """A setting's value as plain JSON (tuples as lists)."""
    return list(value) if isinstance(value, tuple) else value
