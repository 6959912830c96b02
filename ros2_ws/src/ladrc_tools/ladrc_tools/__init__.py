"""Tools around the controller and the simulator: offline analysis, commissioning, CAM post, CLI.

``offline/`` (reports, replay, export, suite, tune), ``commissioning/`` (identification,
calibration tables, the conformance rules), ``cam/`` (the LinuxCNC post-processor) never import
rclpy; ``node/`` (the live view) is the ROS side. ``cli.py`` is the ``ladrc`` command. Bags are
ladrc_bags'; the bring-up and the runs that start node processes are ladrc_bringup's; the fleet
tools are ladrc_fleet's (docs/architecture.md, "Layers").
"""
