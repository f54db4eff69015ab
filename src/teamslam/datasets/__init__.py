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
