"""Headless simulation: scenario library, closed-loop runner, follow metrics.

Plain Python + numpy + PyYAML over :mod:`ladrc_sim.models`; nothing here imports rclpy.
"""
