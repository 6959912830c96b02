"""Shared pytest set-up: test the source tree of the pure-Python packages.

The ROS integration tests start the installed console scripts as real processes;
everything else imports ``ladrc_follow`` and ``ladrc_sim`` straight from
``ros2_ws/src`` so a test always sees the code under review.
"""

from pathlib import Path
import sys

ROOT = Path(__file__).resolve().parents[1]
# tests/support: helpers shared by test modules (pytest runs with --import-mode=importlib,
# which does not put test folders on sys.path).
for path in (ROOT / 'ros2_ws' / 'src' / 'ladrc_follow', ROOT / 'ros2_ws' / 'src' / 'ladrc_sim',
             ROOT / 'tests' / 'support'):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))
