"""A filter's settings: their values (:mod:`~teamslam.msckf.settings.values`), where each came
from (:mod:`~teamslam.msckf.settings.sources`) and the health of every sensor
(:mod:`~teamslam.msckf.settings.health`), against which noise levels are calibrated."""
