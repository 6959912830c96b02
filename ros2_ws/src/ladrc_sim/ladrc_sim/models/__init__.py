"""Plant models of the simulated Z axis: axis, sheet, sensor, encoder.

Plain Python + numpy; nothing here imports rclpy or ladrc_follow.
"""
