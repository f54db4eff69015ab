"""A run's settings, built once: defaults < the dataset's sensor model < calibration from
the data < a config file < flags (:mod:`teamslam.msckf.settings.sources` holds each layer;
this module puts them in order and runs the calibration, which needs the filter)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from teamslam.datasets.model import TeamDataset
from teamslam.errors import InputError
from teamslam.msckf.settings.sources import (
    ConfigError,
    EffectiveConfig,
    _calibratable,
    _sensor_values,
    camera_defaults,
    coerce_settings,
)
from teamslam.msckf.settings.values import MsckfConfig

__all__ = ["config_for", "resolve_config", "team_configs"]


def resolve_config(
    dataset: TeamDataset,
    file_values: dict[str, Any] | None = None,
    flag_values: dict[str, Any] | None = None,
    calibrate: str = "auto",
    calibration_frames: int | None = None,
) -> EffectiveConfig:
    """The effective settings of a run on ``dataset`` (see the module docstring).

    Parameters
    ----------
    dataset
        The team data (its sensor model, camera and odometry scale).
    file_values, flag_values
        Checked settings from a config file and from flags (:func:`coerce_settings`).
    calibrate
        ``auto``: calibrate the noise levels that no dataset, file or flag gives;
        ``always``: calibrate every noise level a file or flag does not give (calibration then
        wins over the dataset's sensor model); ``never``: use the defaults for missing ones.
    calibration_frames
        Frames per robot the calibration uses (``None``: its default budget).
    """
    if calibrate not in ("auto", "always", "never"):
        raise ConfigError(f"calibrate must be auto, always or never, got {calibrate!r}")
    file_values = dict(file_values or {})
    flag_values = dict(flag_values or {})
    values: dict[str, Any] = MsckfConfig().to_json()
    sources = dict.fromkeys(values, "default")
    values.update(camera_defaults(dataset))
    model = dataset.sensor_model
    from_dataset = _sensor_values(model.team) if model is not None else {}
    layers = [("dataset", from_dataset), ("file", file_values), ("flag", flag_values)]
    for name, layer in layers:
        values.update(layer)
        sources.update(dict.fromkeys(layer, name))
    relevant = _calibratable(dataset, values)
    explicit = set(file_values) | set(flag_values)
    if dataset.object_id_scope != "global":
        # no shared ids: the robots find their common objects themselves
        if values.get("association", "oracle") == "oracle" and "association" in explicit:
            raise ConfigError(
                f"association=oracle needs team-wide object ids; this dataset's object ids are "
                f"{dataset.object_id_scope!r} (use association=own)"
            )
        if "association" not in explicit:
            values["association"] = "own"
            sources["association"] = "dataset"
    if calibrate == "always":
        wanted = [k for k in relevant if k not in explicit]
    elif calibrate == "auto":
        wanted = [k for k in relevant if sources[k] == "default"]
    else:
        wanted = []
    try:
        config = MsckfConfig(**values)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"settings: {exc}") from None
    calibration = None
    if wanted:
        from teamslam.msckf.calibration import calibrate as run_calibration

        calibration = run_calibration(dataset, config, frames=calibration_frames)
        estimated = _sensor_values(calibration.sensor_model.team)
        changes = {key: estimated[key] for key in wanted if key in estimated}
        sources.update(dict.fromkeys(changes, "calibration"))
        config = config.with_(**changes)
    robots = []
    for i in range(dataset.n_robots):
        own = model.robots.get(i) if model is not None else None
        if own is None:
            robots.append(config)
            continue
        changes = {
            k: v for k, v in _sensor_values(own).items() if sources[k] in ("dataset", "default")
        }
        try:
            robots.append(config.with_(**changes))
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"sensor_model.robots[{i}]: {exc}") from None
    return EffectiveConfig(config, sources, robots, calibration)


def config_for(dataset: TeamDataset, calibrate: str = "auto", **settings: Any) -> MsckfConfig:
    """Team-wide settings for ``dataset`` with ``settings`` on top (as flags would be).

    The Python counterpart of ``teamslam run DATASET --set key=value …``: the dataset's sensor
    model, a calibration from the data for noise levels it lacks (``calibrate``, see
    :func:`resolve_config`), then ``settings``.
    """
    return resolve_config(
        dataset, flag_values=coerce_settings(settings, "config_for"), calibrate=calibrate
    ).config


def team_configs(dataset, config: MsckfConfig | Sequence[MsckfConfig] | None) -> list[MsckfConfig]:
    """One config per robot: ``config`` as given (one for all, or one each), or by default
    :func:`resolve_config` — the dataset's sensor model, or a calibration from the data."""
    n = dataset.n_robots
    if config is None:
        return resolve_config(dataset).robots
    if isinstance(config, MsckfConfig):
        return [config] * n
    configs = list(config)
    if len(configs) != n:
        raise InputError(f"{len(configs)} configs for a team of {n} robots")
    return configs
