"""nmt_ros.io."""
