"""nmt_ros.cli."""
