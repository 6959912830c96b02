"""Bring-up: the sim, follow and recorder nodes as processes on an isolated DDS domain; demo."""
