"""A rosbags typestore that knows the ``ladrc_msgs`` interfaces, from the package's own files.

The recorder, the headless bag writer and every offline tool serialize and read bags with the
pure-Python ``rosbags`` library (rosbag2 is not installable from PyPI). Registering the types
from the installed ``.msg`` files, rather than from a hand-written copy, keeps the bags' message
definitions identical to what rclpy publishes (checked byte for byte in tests/ros).
"""

from __future__ import annotations

from functools import lru_cache
import os
from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

PACKAGE = 'ladrc_msgs'


def msg_dir() -> Path:
    """Return the folder holding ladrc_msgs' .msg files (install space, else the source tree)."""
    try:
        from ament_index_python.packages import get_package_share_directory

        share = Path(get_package_share_directory(PACKAGE)) / 'msg'
        if share.is_dir():
            return share
    except (ImportError, LookupError, ValueError, OSError):
        pass
    env_root = os.environ.get('LADRC_ROOT')
    roots = [Path(env_root)] if env_root else []
    roots.append(Path(__file__).resolve().parents[4])  # <root>/ros2_ws/src/<pkg>/<pkg>/
    for root in roots:
        src = root / 'ros2_ws' / 'src' / PACKAGE / 'msg'
        if src.is_dir():
            return src
    raise FileNotFoundError(f'cannot find the {PACKAGE} .msg files (is the workspace built?)')


def msg_definitions() -> dict[str, str]:
    """Map ``ladrc_msgs/msg/Name`` to the text of its .msg file."""
    return {f'{PACKAGE}/msg/{path.stem}': path.read_text(encoding='utf-8')
            for path in sorted(msg_dir().glob('*.msg'))}


@lru_cache(maxsize=1)
def ladrc_typestore() -> Typestore:
    """Return a Jazzy typestore with every ladrc_msgs message registered."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for name, text in msg_definitions().items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store
