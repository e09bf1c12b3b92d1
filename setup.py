"""ament_python package definition of nmt_ros (also a plain pip-installable package)."""
from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'nmt_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(include=['nmt_ros', 'nmt_ros.*', 'msg_adapters', 'msg_adapters.*']),
    package_data={'nmt_ros': ['model/data/*.yaml', 'model/data/*.json', 'tracking/data/*.yaml',
                          'io/data/*.yaml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        (os.path.join('share', package_name, 'config'),
         glob('config/*.yaml') + glob('config/*.xml') + glob('config/*.json')),
        (os.path.join('share', package_name, 'launch'), glob('launch/*.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='nmt_ros developers',
    maintainer_email='nmt_ros@example.org',
    description='Neuromusculoskeletal tracking (Seth & Pandy 2007) as a ROS 2 node graph',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'nmt = nmt_ros.cli.main:main',
            'observation_publisher = nmt_ros.nodes.observation_publisher:main',
            'skeletal_tracker = nmt_ros.nodes.skeletal_tracker:main',
            'muscle_tracker = nmt_ros.nodes.muscle_tracker:main',
            'recorder = nmt_ros.nodes.recorder:main',
        ],
    },
)
