"""nmt_ros: neuromusculoskeletal tracking (Seth & Pandy 2007) with a ROS 2 node graph.

Layers (imports point downward only): ``cli`` and ``nodes`` (ROS) on top of ``study``,
``tracking`` and ``io``, which sit on ``model``. Nothing below ``nodes`` imports rclpy.
"""

__version__ = '0.1.0'
