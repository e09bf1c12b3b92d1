"""nmt_ros.study."""
