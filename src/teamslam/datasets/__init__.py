"""Team datasets: the data model, teamslam's own format, the published-data importer, exports.

* :mod:`~teamslam.datasets.model` — :class:`TeamDataset`, :class:`RobotSequence`,
  :class:`FrameObservations`, :class:`Calibration`;
* :mod:`~teamslam.datasets.sensor_model` — :class:`SensorModel`, the noise of a team's sensors;
* :mod:`~teamslam.datasets.storage` — :func:`save_dataset` / :func:`load_dataset` (JSON
  manifest + compressed ``.npz``, validated, no pickle);
* :mod:`~teamslam.datasets.reference` — :func:`import_reference` for the distributed-MSCKF
  paper's published files, through a restricted unpickler;
* :mod:`~teamslam.datasets.trajectory` — TUM and KITTI trajectory files;
* :mod:`~teamslam.datasets.stats` — :func:`dataset_info`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from teamslam._lazy import attach

__all__ = [
    "FORMAT_VERSION",
    "Calibration",
    "DatasetError",
    "FrameObservations",
    "RobotSequence",
    "SensorModel",
    "SensorNoise",
    "TeamDataset",
    "UnsafePickleError",
    "dataset_info",
    "export_reference",
    "format_info",
    "ground_truth_noise",
    "import_reference",
    "load_dataset",
    "read_kitti",
    "read_reference_params",
    "read_tum",
    "safe_unpickle",
    "save_dataset",
    "write_kitti",
    "write_tum",
]

__getattr__, __dir__ = attach(
    __name__,
    ("model", "reference", "sensor_model", "stats", "storage", "trajectory", "victoria_park"),
    {
        "Calibration": "teamslam.datasets.model",
        "DatasetError": "teamslam.datasets.model",
        "FrameObservations": "teamslam.datasets.model",
        "RobotSequence": "teamslam.datasets.model",
        "TeamDataset": "teamslam.datasets.model",
        "UnsafePickleError": "teamslam.datasets.reference",
        "export_reference": "teamslam.datasets.reference",
        "import_reference": "teamslam.datasets.reference",
        "read_reference_params": "teamslam.datasets.reference",
        "safe_unpickle": "teamslam.datasets.reference",
        "SensorModel": "teamslam.datasets.sensor_model",
        "SensorNoise": "teamslam.datasets.sensor_model",
        "dataset_info": "teamslam.datasets.stats",
        "format_info": "teamslam.datasets.stats",
        "ground_truth_noise": "teamslam.datasets.stats",
        "FORMAT_VERSION": "teamslam.datasets.storage",
        "load_dataset": "teamslam.datasets.storage",
        "save_dataset": "teamslam.datasets.storage",
        "read_kitti": "teamslam.datasets.trajectory",
        "read_tum": "teamslam.datasets.trajectory",
        "write_kitti": "teamslam.datasets.trajectory",
        "write_tum": "teamslam.datasets.trajectory",
    },
)


if TYPE_CHECKING:  # what a type checker and an IDE see; nothing is imported at run time
    from teamslam.datasets.model import (
        Calibration,
        DatasetError,
        FrameObservations,
        RobotSequence,
        TeamDataset,
    )
    from teamslam.datasets.reference import (
        UnsafePickleError,
        export_reference,
        import_reference,
        read_reference_params,
        safe_unpickle,
    )
    from teamslam.datasets.sensor_model import SensorModel, SensorNoise
    from teamslam.datasets.stats import dataset_info, format_info, ground_truth_noise
    from teamslam.datasets.storage import FORMAT_VERSION, load_dataset, save_dataset
    from teamslam.datasets.trajectory import read_kitti, read_tum, write_kitti, write_tum
