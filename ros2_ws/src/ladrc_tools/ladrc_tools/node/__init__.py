"""ROS layer of the tools: the bag recorder node."""
