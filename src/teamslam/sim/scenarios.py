"""Simulated teams whose sensors are unlike every built-in default.

Each scenario changes the camera's units, the measurement noise or the odometry noise, so that
a setting fitted to one dataset (a σ in pixels, a KITTI noise level) shows up as a failure:
normalised coordinates (``K = I``) with σ 0.005 and 0.02 (on a 1 m stereo baseline), a
700-pixel camera with σ 3 px, and
odometry three times noisier in rotation than the simulator's default — with and without
geometric features. The team's sensor model records the true noise, so a test can compare a
calibration with the truth; :func:`scenario_team` can drop it to pose the "no noise given
anywhere" problem.
"""

from __future__ import annotations

from dataclasses import replace

from teamslam.datasets.model import TeamDataset
from teamslam.errors import InputError
from teamslam.sim.lissajous import lissajous_team

__all__ = ["SENSOR_SCENARIOS", "scenario_team"]

#: Scenario name → :class:`~teamslam.sim.SimulationConfig` fields.
SENSOR_SCENARIOS: dict[str, dict] = {
    "normalised-0.005-objects": {
        "normalised_coordinates": True,
        "pixel_noise": 0.005,
        "object_pixel_noise": 0.005,
        "landmarks": 0,
    },
    "normalised-0.005-features": {
        "normalised_coordinates": True,
        "pixel_noise": 0.005,
        "object_pixel_noise": 0.005,
        "landmarks": 500,
    },
    "normalised-0.02-features": {
        # four times the noise at twice the baseline and closer objects: depth as precise as
        # σ 0.01 on a 0.5 m rig
        "normalised_coordinates": True,
        "pixel_noise": 0.02,
        "object_pixel_noise": 0.02,
        "baseline": 1.0,
        "max_depth": 25.0,
        "object_max_depth": 15.0,
        "landmarks": 500,
    },
    "pixels-700-3px-features": {
        "focal": 700.0,
        "image_size": (1280, 720),
        "pixel_noise": 3.0,
        "object_pixel_noise": 3.0,
        "landmarks": 500,
    },
    "odometry-3cm-0.01rad-objects": {
        "odometry_translation_noise": 0.03,
        "odometry_rotation_noise": 0.01,
        "landmarks": 0,
    },
}


def scenario_team(
    name: str,
    robots: int = 3,
    steps: int = 200,
    seed: int = 0,
    sensor_model: bool = True,
    appearance: int = 0,
) -> TeamDataset:
    """The team of scenario ``name``; without its sensor model when ``sensor_model`` is false;
    with simulated appearance of ``appearance`` dimensions when given (the rest unchanged)."""
    try:
        fields = SENSOR_SCENARIOS[name]
    except KeyError:
        raise InputError(
            f"unknown scenario {name!r}; scenarios: {', '.join(SENSOR_SCENARIOS)}"
        ) from None
    extra = {"appearance": appearance} if appearance else {}
    team = lissajous_team(robots=robots, steps=steps, seed=seed, **fields, **extra)
    team.name = f"{name}-{robots}r-{steps}s-seed{seed}"
    return team if sensor_model else replace(team, sensor_model=None)
