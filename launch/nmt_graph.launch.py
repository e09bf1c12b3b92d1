"""The live graph for a full ROS 2 Jazzy install: ``ros2 launch nmt_ros nmt_graph.launch.py
bag:=/path/to/bag [rate:=1.0] [record:=out_bag]`` (after ``colcon build``).

Not runnable in this project's pip-only environment (no ``launch``/``launch_ros`` wheels):
there, ``nmt launch`` does the same with one process per node. Parameters come from
``config/nmt_graph.yaml``; the readiness chain (``wait_for``, ``expected_subscribers``) is set
here as ``nmt launch`` sets it, so no message is published before its consumers exist.
Unlike ``nmt launch``, ``ros2 launch`` keeps running after the replay (Ctrl-C ends it and the
recorder finalises the bag). The recorder and the muscle tracker run niced as there
(``NODE_NICE``: the skeletal tracker gets the cores first).
"""
import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, SetEnvironmentVariable
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription
from nmt_ros.cli.launch import NODE_NICE
from nmt_ros.topics import MUSCLE_OUTPUTS, SKELETAL_OUTPUTS


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory('nmt_ros')
    params = os.path.join(share, 'config', 'nmt_graph.yaml')
    profile = os.path.join(share, 'config', 'fastdds_profile.xml')
    return LaunchDescription([
        DeclareLaunchArgument('bag', description='bag folder with the observation topics'),
        DeclareLaunchArgument('rate', default_value='1.0', description='replay speed factor'),
        DeclareLaunchArgument('record', default_value='nmt_recording',
                              description='new bag folder for the recording'),
        SetEnvironmentVariable('FASTRTPS_DEFAULT_PROFILES_FILE', profile),
        Node(package='nmt_ros', executable='recorder', name='recorder', output='screen',
             prefix=f"nice -n {NODE_NICE['recorder']}",
             parameters=[params, {'output': LaunchConfiguration('record')}]),
        Node(package='nmt_ros', executable='muscle_tracker', name='muscle_tracker',
             output='screen', prefix=f"nice -n {NODE_NICE['muscle_tracker']}",
             parameters=[params, {'wait_for': [f'{t}=1' for t in MUSCLE_OUTPUTS]}]),
        Node(package='nmt_ros', executable='skeletal_tracker', name='skeletal_tracker',
             output='screen', parameters=[params, {'wait_for': [f'{SKELETAL_OUTPUTS[0]}=2'] + [
                 f'{t}=1' for t in SKELETAL_OUTPUTS[1:]]}]),
        Node(package='nmt_ros', executable='observation_publisher',
             name='observation_publisher', output='screen',
             parameters=[params, {'bag': LaunchConfiguration('bag'),
                                  'rate': LaunchConfiguration('rate'),
                                  'expected_subscribers': 2}]),
    ])
