"""On a stock Jazzy machine, check that apt gave the Python modules the project uses."""

import importlib
import sys

NEEDED = {'numpy': 'python3-numpy', 'scipy': 'python3-scipy',
          'matplotlib': 'python3-matplotlib', 'yaml': 'python3-yaml', 'rclpy': 'ros-jazzy-rclpy'}

missing = []
for module, package in NEEDED.items():
    try:
        importlib.import_module(module)
    except ImportError:
        missing.append(package)
if missing:
    sys.exit('setup-env: missing prerequisite: apt-get install ' + ' '.join(missing))
