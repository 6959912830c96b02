"""Commissioning a real axis (no rclpy): excitation, identification, calibration, conformance."""
