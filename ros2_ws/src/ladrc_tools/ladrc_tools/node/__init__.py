"""ROS layer of the tools: the live view node (Foxglove WebSocket)."""
