"""Tools around the controller and the simulator: bags, offline analysis, recorder, bring-up.

``bags/`` and ``offline/`` never import rclpy; ``node/`` (the recorder) and ``bringup/`` (node
processes) are the ROS side. ``cli.py`` is the ``ladrc`` command.
"""

__version__ = '0.1.0'  # as package.xml and setup.py (bags/provenance.py)
