"""Stereo front-end: from a robot's stereo images to the measurements teamslam filters.

* :mod:`~teamslam.frontend.config` — :class:`FrontendConfig`, every setting;
* :mod:`~teamslam.frontend.camera` — :func:`load_camera`, :class:`StereoRig` (rectification);
* :mod:`~teamslam.frontend.tracking` — :class:`FeatureTracker` (corners + pyramidal
  Lucas–Kanade, forward–backward check, persistent ids);
* :mod:`~teamslam.frontend.stereo` — :func:`match_stereo` (epipolar NCC, uniqueness,
  left–right check, Lucas–Kanade refinement; tracked points followed from their previous
  disparity);
* :mod:`~teamslam.frontend.markers` — :class:`MarkerDetector` (ArUco / AprilTag objects);
* :mod:`~teamslam.frontend.odometry` — :func:`stereo_motion` (PnP + RANSAC);
* :mod:`~teamslam.frontend.pipeline` — :class:`StereoFrontend`, all of it per frame.

OpenCV is the optional ``images`` extra (``pip install teamslam[images]``), imported only
when a function needs it.
"""

from teamslam.frontend.camera import StereoRig, load_camera, rig_from_camera_info
from teamslam.frontend.config import FrontendConfig
from teamslam.frontend.markers import MarkerDetector, Markers, diagonal_centre
from teamslam.frontend.odometry import stereo_motion, triangulate
from teamslam.frontend.pipeline import FrameMeasurements, StereoFrontend
from teamslam.frontend.stereo import StereoMatches, match_stereo
from teamslam.frontend.tracking import FeatureTracker

__all__ = [
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
