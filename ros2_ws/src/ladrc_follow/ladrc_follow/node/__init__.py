"""ROS layer of the controller: the 2 kHz follow node, its QoS profiles, the fast CDR packer.

Imports rclpy and the message packages; the control itself is :mod:`ladrc_follow.control`.
"""
