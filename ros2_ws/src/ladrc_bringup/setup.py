from glob import glob

from setuptools import find_packages, setup

package_name = 'ladrc_bringup'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml') + glob('config/*.xml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=True,
    maintainer='LADRC follow maintainers',
    maintainer_email='maintainers@ladrc-follow.org',
    description='Bring-up of the LADRC height follow: node processes, launch files, shipped '
                'configuration, and the commissioning runs that start nodes.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'bringup = ladrc_bringup.bringup:main',
            'cia402_stack = ladrc_bringup.cia402_stack:main',
            'calibrate_node = ladrc_bringup.calibrate_node:main',
        ],
        'ladrc.commands': [
            'conform = ladrc_bringup.cli:CONFORM',
            'calibrate = ladrc_bringup.cli:CALIBRATE',
        ],
    },
)
