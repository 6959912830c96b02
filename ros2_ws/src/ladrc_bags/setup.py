from glob import glob

from setuptools import find_packages, setup

package_name = 'ladrc_bags'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.xml') + glob('config/*.json')),
    ],
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=True,
    maintainer='LADRC follow maintainers',
    maintainer_email='maintainers@ladrc-follow.org',
    description='rosbag2 bags of the LADRC height follow: writer, reader, provenance, recorder.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'recorder = ladrc_bags.recorder_node:main',
        ],
    },
)
