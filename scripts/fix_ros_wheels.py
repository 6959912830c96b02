"""Point the ROS 2 wheels' CMake export files at this interpreter (docs/environment.md).

The ros-* wheels are built on a manylinux image; their CMake config files hard-code that
machine's Python include directory and numpy include directory
(/opt/python/cp3XX-cp3XX/...). CMake then fails with "Imported target
std_msgs::std_msgs__rosidl_generator_py includes non-existent path". This rewrites those paths
in <venv>/share/**/*.cmake to sysconfig's include path and numpy.get_include(). Idempotent.
"""

from pathlib import Path
import re
import sys
import sysconfig

import numpy


def main(venv: str) -> int:
    """Rewrite the build-machine paths under ``venv``; print how many files changed."""
    py_include = sysconfig.get_paths()['include']
    np_include = numpy.get_include()
    # Most specific first: the numpy include dir sits below the build machine's site-packages.
    patterns = [
        (re.compile(r'/opt/python/cp3\d+-cp3\d+/lib/python3\.\d+/site-packages/numpy/'
                    r'(?:_core|core)/include'), np_include),
        (re.compile(r'/opt/python/cp3\d+-cp3\d+/include/python3\.\d+'), py_include),
    ]
    changed = 0
    for path in Path(venv, 'share').rglob('*.cmake'):
        text = path.read_text(encoding='utf-8', errors='surrogateescape')
        new = text
        for pattern, replacement in patterns:
            new = pattern.sub(replacement.replace('\\', '\\\\'), new)
        if new != text:
            path.write_text(new, encoding='utf-8', errors='surrogateescape')
            changed += 1
    print(f'fix_ros_wheels: {changed} CMake files now use {py_include} and {np_include}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1]))
