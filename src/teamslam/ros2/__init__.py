"""teamslam in a ROS 2 world, without a ROS 2 installation.

:mod:`~teamslam.ros2.messages` (message types, CDR, type hashes, builders),
:mod:`~teamslam.ros2.mcap_export` (a run as MCAP), :mod:`~teamslam.ros2.bags` and
:mod:`~teamslam.ros2.image_bags` (team and stereo image bags in and out),
:mod:`~teamslam.ros2.detection_bags` (a detector's ``vision_msgs`` boxes in bags) and
:mod:`~teamslam.ros2.rmw_zenoh` (live topics for ROS 2 nodes on ``rmw_zenoh``) and
:mod:`~teamslam.ros2.live` (live topics in: a subscriber, stamp pairing, decoders).
"""
