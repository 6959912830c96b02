from glob import glob

from setuptools import find_packages, setup

package_name = 'ladrc_sim'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    # The scenario library ships inside the Python package (importlib.resources finds it) and
    # under share/ for users who look for it the ROS way.
    package_data={'ladrc_sim.headless': ['scenarios/*.yaml'],
                  'ladrc_sim.job': ['jobs/*.yaml', 'jobs/*.dxf', 'jobs/*.LICENSE'],
                  'ladrc_sim.cia402': ['*.eds', '*.yaml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/scenarios', glob('ladrc_sim/headless/scenarios/*.yaml')),
        ('share/' + package_name + '/jobs', glob('ladrc_sim/job/jobs/*')),
        ('share/' + package_name + '/cia402',
         glob('ladrc_sim/cia402/*.eds') + glob('ladrc_sim/cia402/*.yaml')),
    ],
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=True,
    maintainer='LADRC follow maintainers',
    maintainer_email='maintainers@ladrc-follow.org',
    description='Simulated velocity-mode Z axis, sheet and capacitive sensor.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'sim_node = ladrc_sim.node.sim_node:main',
            'cnc_node = ladrc_sim.node.cnc_node:main',
        ],
    },
)
