"""Stereo front-end: from a robot's stereo images to the measurements teamslam filters.

:mod:`~teamslam.frontend.config` (settings), :mod:`~teamslam.frontend.camera` (camera files,
rectification), :mod:`~teamslam.frontend.tracking` (feature tracks),
:mod:`~teamslam.frontend.stereo` (stereo matching), :mod:`~teamslam.frontend.markers`
(fiducial objects), :mod:`~teamslam.frontend.boxes` (a detector's boxes in stereo),
:mod:`~teamslam.frontend.appearance` (their appearance descriptors),
:mod:`~teamslam.frontend.odometry` (stereo visual odometry) and
:mod:`~teamslam.frontend.pipeline` (all of it per frame). OpenCV is the optional ``images``
extra, imported only when a function needs it.
"""

from teamslam.frontend.boxes import BoxMeasurements, BoxStereo
from teamslam.frontend.camera import StereoRig, load_camera, rig_from_camera_info
from teamslam.frontend.config import FrontendConfig
from teamslam.frontend.markers import MarkerDetector, Markers, diagonal_centre
from teamslam.frontend.odometry import stereo_motion, triangulate
from teamslam.frontend.pipeline import FrameMeasurements, StereoFrontend
from teamslam.frontend.stereo import StereoMatches, match_stereo
from teamslam.frontend.tracking import FeatureTracker

__all__ = [
    "BoxMeasurements",
    "BoxStereo",
    "FeatureTracker",
    "FrameMeasurements",
    "FrontendConfig",
    "MarkerDetector",
    "Markers",
    "StereoFrontend",
    "StereoMatches",
    "StereoRig",
    "diagonal_centre",
    "load_camera",
    "match_stereo",
    "rig_from_camera_info",
    "stereo_motion",
    "triangulate",
]
