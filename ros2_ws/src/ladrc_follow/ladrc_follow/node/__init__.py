"""ROS layer of the controller: the follow node, its loop thread, samples, housekeeping.

Imports rclpy and the message packages; the control itself is :mod:`ladrc_follow.control`.
"""
