"""``nmt run NODE [--ros-args ...]``: one node of the graph in this process (like ``ros2 run``).

NODE is one of observation_publisher, skeletal_tracker, muscle_tracker, recorder; everything
after it goes to ``rclpy.init`` (``--ros-args --params-file config/<node>.yaml -p k:=v``).
The exit code is the node's (0 on success or Ctrl-C). The environment gets the defaults of
``nmt launch`` (loopback only, ``config/fastdds_profile.xml``, single-threaded BLAS) where the
user set nothing; they are set before the node's module (and numpy) is imported, since
OpenBLAS reads its thread count when it loads.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys

ACCEPTS_EXTRA_ARGS = True  # --ros-args ... goes to rclpy.init
NODES = ('observation_publisher', 'skeletal_tracker', 'muscle_tracker', 'recorder')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('node', choices=NODES, help='which node')


def run(args: argparse.Namespace) -> int:
    from nmt_ros.cli.launch import SINGLE_THREADED_MATH, ros_environment

    unset = [key for key in SINGLE_THREADED_MATH if key not in os.environ]
    # the same settings as `nmt launch` (loopback, Fast DDS profile, BLAS threads) unless set
    for key, value in ros_environment().items():
        os.environ.setdefault(key, value)
    if unset and 'numpy' in sys.modules:
        print('warning: numpy was loaded before the node environment was set; its BLAS '
              'keeps the thread count it started with', file=sys.stderr)
    module = importlib.import_module(f'nmt_ros.nodes.{args.node}')
    return int(module.main([f'nmt-{args.node}'] + list(getattr(args, 'extra', []))) or 0)
