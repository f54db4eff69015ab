"""A run's settings, built by one function: :func:`build_settings` — defaults < the dataset's
sensor model < calibration from the data < a config file < flags
(:mod:`teamslam.msckf.settings.sources` holds each layer; this module puts them in order and runs
the calibration, which needs the filter). :func:`config_for` and :func:`team_configs` call it."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
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
    load_config_file,
    parse_assignments,
)
from teamslam.msckf.settings.values import MsckfConfig

__all__ = ["build_settings", "config_for", "team_configs"]

Settings = Mapping[str, Any] | Sequence[str]


def _layer(values: str | Path | Settings | None, where: str) -> dict[str, Any]:
    """Checked ``{"group.name": value}`` of one layer given as a YAML file, a mapping (nested
    groups or dotted keys) or ``["group.name=value", …]``."""
    if values is None:
        return {}
    if isinstance(values, str | Path):
        return load_config_file(values)
    if isinstance(values, Mapping):
        return coerce_settings(values, where)
    return parse_assignments(list(values))


def build_settings(
    dataset: TeamDataset,
    file: str | Path | Settings | None = None,
    flags: Settings | None = None,
    calibrate: str = "auto",
    calibration_frames: int | None = None,
) -> EffectiveConfig:
    """The effective settings of a run on ``dataset``, and the source of each.

    Parameters
    ----------
    dataset
        The team data (its sensor model, camera and odometry scale).
    file
        The config file's layer: a YAML file, or its settings already read (a mapping, e.g. a
        team file's ``filter`` section).
    flags
        The flags' layer, on top: ``{"group.name": value}`` (or nested groups) or
        ``["group.name=value", …]`` (as ``--set``).
    calibrate
        ``auto``: calibrate the noise levels that no dataset, file or flag gives;
        ``always``: calibrate every noise level a file or flag does not give (calibration then
        wins over the dataset's sensor model); ``never``: use the defaults for missing ones.
    calibration_frames
        Frames per robot the calibration uses (``None``: its default budget).

    Raises
    ------
    ConfigError
        A setting that does not exist (named, with the closest names) or a value it cannot
        take.
    """
    if calibrate not in ("auto", "always", "never"):
        raise ConfigError(f"calibrate must be auto, always or never, got {calibrate!r}")
    file_values = _layer(file, "config file")
    flag_values = _layer(flags, "settings")
    values: dict[str, Any] = MsckfConfig().settings()
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
        if values["association.mode"] == "oracle" and "association.mode" in explicit:
            raise ConfigError(
                f"association.mode=oracle needs team-wide object ids; this dataset's object ids "
                f"are {dataset.object_id_scope!r} (use association.mode=own)"
            )
        if "association.mode" not in explicit:
            values["association.mode"] = "own"
            sources["association.mode"] = "dataset"
    if calibrate == "always":
        wanted = [k for k in relevant if k not in explicit]
    elif calibrate == "auto":
        wanted = [k for k in relevant if sources[k] == "default"]
    else:
        wanted = []
    try:
        config = MsckfConfig.from_settings(values)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"settings: {exc}") from None
    calibration = None
    if wanted:
        from teamslam.msckf.calibration import calibrate as run_calibration

        calibration = run_calibration(dataset, config, frames=calibration_frames)
        estimated = _sensor_values(calibration.sensor_model.team)
        changes = {key: estimated[key] for key in wanted if key in estimated}
        sources.update(dict.fromkeys(changes, "calibration"))
        config = config.with_(changes)
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
            robots.append(config.with_(changes))
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"sensor_model.robots[{i}]: {exc}") from None
    return EffectiveConfig(config, sources, robots, calibration)


def config_for(
    dataset: TeamDataset, settings: Settings | None = None, calibrate: str = "auto"
) -> MsckfConfig:
    """Team-wide settings for ``dataset`` with ``settings`` on top, as flags
    (:func:`build_settings`): the Python counterpart of ``teamslam run DATASET --set
    group.name=value …``, e.g. ``config_for(team, {"filter.window": 8})``."""
    return build_settings(dataset, flags=settings, calibrate=calibrate).config


def team_configs(dataset, config: MsckfConfig | Sequence[MsckfConfig] | None) -> list[MsckfConfig]:
    """One config per robot: ``config`` as given (one for all, or one each), or by default
    :func:`build_settings` — the dataset's sensor model, or a calibration from the data."""
    n = dataset.n_robots
    if config is None:
        return build_settings(dataset).robots
    if isinstance(config, MsckfConfig):
        return [config] * n
    configs = list(config)
    if len(configs) != n:
        raise InputError(f"{len(configs)} configs for a team of {n} robots")
    return configs
