"""Shared pytest set-up: test the source tree of the pure-Python packages.

The ROS integration tests start the installed console scripts as real processes;
everything else imports ``ladrc_follow``, ``ladrc_sim``, ``ladrc_bags``, ``ladrc_tools``, ...
straight from ``ros2_ws/src`` so a test always sees the code under review.
"""

from pathlib import Path
import sys

ROOT = Path(__file__).resolve().parents[1]
# tests/support: helpers shared by test modules (pytest runs with --import-mode=importlib,
# which does not put test folders on sys.path).
SRC = ROOT / 'ros2_ws' / 'src'
# bench/: the real-time tests take their bounds from bench/stalls.py (STALL_MAX_S), the script
# that measures the host's scheduling stalls.
for path in (SRC / 'ladrc_cia402', SRC / 'ladrc_linuxcnc', SRC / 'ladrc_follow', SRC / 'ladrc_sim',
             SRC / 'ladrc_bags', SRC / 'ladrc_tools', SRC / 'ladrc_bringup', SRC / 'ladrc_fleet',
             ROOT / 'tests' / 'support', ROOT / 'bench'):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))
