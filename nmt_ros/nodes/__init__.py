"""nmt_ros.nodes."""
