"""Control core: TD, ESO, Kalman, control laws, PID, interpolation, follow state machine.

Plain Python + numpy. Nothing in this package imports rclpy: the follow node,
the headless simulator and offline replay all run this one implementation.
"""
