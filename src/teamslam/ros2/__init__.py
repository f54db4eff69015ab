"""teamslam in a ROS 2 world, without a ROS 2 installation.

* :mod:`~teamslam.ros2.messages` — the ROS 2 message types (Jazzy definitions plus
  ``teamslam_msgs/msg/StereoObservations``, whose ``.msg`` ships in ``teamslam/ros2/msg``),
  CDR serialisation and RIHS01 type hashes (through ``rosbags``), and builders from poses and
  Gaussians to PoseStamped, Path, TF and MarkerArray messages;
* :mod:`~teamslam.ros2.mcap_export` — a run as an MCAP file for Foxglove, RViz and rosbag2;
* :mod:`~teamslam.ros2.bags` — team bags (rosbag2 directories or MCAP files) in and out;
* :mod:`~teamslam.ros2.image_bags` — stereo image bags in and out (through the image front-end);
* :mod:`~teamslam.ros2.rmw_zenoh` — live topics that ROS 2 nodes on ``rmw_zenoh`` receive;
* :mod:`~teamslam.cli.ros2` — the ``teamslam export`` / ``data import-bag`` / ``data
  export-bag`` commands and the ``--mcap`` / ``--ros2`` flags.
"""
