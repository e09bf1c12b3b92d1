"""nmt_ros.tracking."""
