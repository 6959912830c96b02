"""rosbag2 bags with the pure-Python ``rosbags`` library: layout, writer, reader, typestore."""
