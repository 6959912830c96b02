from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'ladrc_linuxcnc'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', [f for f in glob('config/*') if os.path.isfile(f)]),
        ('share/' + package_name + '/config/subroutines', glob('config/subroutines/*.ngc')),
    ],
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=True,
    maintainer='LADRC follow maintainers',
    maintainer_email='maintainers@ladrc-follow.org',
    description='LinuxCNC bridge: HAL component, ROS node, XY machine configuration.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'bridge_node = ladrc_linuxcnc.bridge_node:main',
        ],
    },
)
