"""CAM-side tools: the post-processor from a job's part program to LinuxCNC G-code."""
