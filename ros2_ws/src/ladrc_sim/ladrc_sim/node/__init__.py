"""ROS layer of the simulator: the sim node (the headless runner driven in real time on DDS)."""
