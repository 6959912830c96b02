"""CiA 402 drive over CANopen, the master side (plain Python: no rclpy in this layer)."""
