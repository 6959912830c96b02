"""Bag tests: pure rosbags, no DDS (the live recorder tests are tests/ros/test_recorder.py)."""
