from glob import glob

from setuptools import find_packages, setup

package_name = 'ladrc_cia402'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/examples',
         glob('examples/*.eds') + glob('examples/*.yaml')),
    ],
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=True,
    entry_points={'console_scripts': ['driver_node = ladrc_cia402.driver_node:main']},
    maintainer='LADRC follow maintainers',
    maintainer_email='maintainers@ladrc-follow.org',
    description='CiA 402 drive over CANopen: driver node, master, state machine, EMCY, units.',
    license='Apache-2.0',
)
