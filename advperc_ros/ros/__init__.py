"""ROS 2 messages and rosbag2 MCAP bags, built on the rosbags Jazzy typestore."""
