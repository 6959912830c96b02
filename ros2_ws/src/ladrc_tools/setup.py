from setuptools import find_packages, setup

package_name = 'ladrc_tools'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    # the HTML report's page: its script and style, and uPlot vendored (read with
    # importlib.resources, so an installed package must carry them)
    package_data={'ladrc_tools.offline': ['html_report.js', 'html_report.css',
                                          'vendor/uplot/*']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    extras_require={'test': ['pytest']},
    zip_safe=True,
    maintainer='LADRC follow maintainers',
    maintainer_email='maintainers@ladrc-follow.org',
    description='Offline analysis, commissioning, CAM post, live view and the ladrc command '
                'of the LADRC height follow.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'ladrc = ladrc_tools.cli:main',
            'view_node = ladrc_tools.node.view_node:main',
        ],
    },
)
