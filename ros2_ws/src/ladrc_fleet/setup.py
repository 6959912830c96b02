from setuptools import find_packages, setup

package_name = 'ladrc_fleet'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=True,
    maintainer='LADRC follow maintainers',
    maintainer_email='maintainers@ladrc-follow.org',
    description="The LADRC height follow's fleet tools: many machines' bags on a Dask cluster.",
    license='Apache-2.0',
    entry_points={
        'ladrc.commands': [
            'fleet = ladrc_fleet.cli:FLEET',
            'fleet-gen = ladrc_fleet.cli:FLEET_GEN',
        ],
    },
)
