"""One module per ROS 2 node; each is a thin wrapper around a core object."""
