"""``nmt run NODE [--ros-args ...]``: one node of the graph in this process (like ``ros2 run``).

NODE is one of observation_publisher, skeletal_tracker, muscle_tracker, recorder; everything
after it goes to ``rclpy.init`` (``--ros-args --params-file config/<node>.yaml -p k:=v``).
The exit code is the node's (0 on success or Ctrl-C). The environment gets the defaults of
``nmt launch`` (loopback only, ``config/fastdds_profile.xml``) where the user set nothing.
"""
from __future__ import annotations

import argparse
import importlib
import os

ACCEPTS_EXTRA_ARGS = True  # --ros-args ... goes to rclpy.init
NODES = ('observation_publisher', 'skeletal_tracker', 'muscle_tracker', 'recorder')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('node', choices=NODES, help='which node')


def run(args: argparse.Namespace) -> int:
    from nmt_ros.cli.launch import ros_environment

    # the same middleware settings as `nmt launch` (loopback, Fast DDS profile) unless set
    for key, value in ros_environment().items():
        os.environ.setdefault(key, value)
    module = importlib.import_module(f'nmt_ros.nodes.{args.node}')
    return int(module.main([f'nmt-{args.node}'] + list(getattr(args, 'extra', []))) or 0)
